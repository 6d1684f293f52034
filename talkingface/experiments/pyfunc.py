"""The trained mapping as an MLflow pyfunc model: audio in, MUPs per frame out.

Input (``model.predict(x, params={"expression": "smile"})``):

* a WAV path (``str`` or ``Path``), or a list of them;
* ``{"audio": array (n_samples,), "sr": int}``, or a list of such dicts;
* a pandas DataFrame with a ``path`` column (one WAV per row), as the MLflow scoring server sends.

Output: one ``(n_frames, A0 + Ak)`` float32 array per input (a single array for a single input);
frame k is centred at k / 30 s. ``expression`` is ``neutral`` by default. The MUPs are those of
:meth:`mapping.checkpoint.AudioMapping.predict_audio`, silence rule included, exactly what
``talkingface animate`` draws.
"""
from __future__ import annotations

import warnings
from importlib.metadata import version
from pathlib import Path

import mlflow.pyfunc
import numpy as np
from mlflow.models import ModelSignature
from mlflow.types.schema import ParamSchema, ParamSpec

from groundwork.errors import ParameterError
from mapping.checkpoint import AudioMapping

REPO = Path(__file__).resolve().parents[2]
MODEL_CODE = Path(__file__).with_name("pyfunc_model.py")  # models from code: nothing pickled
CODE_PATHS = [str(REPO / p) for p in ("groundwork", "face_model", "mapping", "talkingface")]


class MappingModel(mlflow.pyfunc.PythonModel):
    """Wraps :class:`mapping.checkpoint.AudioMapping` (artifact ``mapping``)."""

    def load_context(self, context):
        self.mapping = AudioMapping.load(context.artifacts["mapping"])

    def predict(self, context, model_input, params=None):
        expression = (params or {}).get("expression", "neutral")
        items, single = _as_items(model_input)
        out = []
        for it in items:
            if isinstance(it, dict):
                out.append(self.mapping.predict_audio(np.asarray(it["audio"]), it["sr"],
                                                      expression))
            else:
                out.append(self.mapping.predict_wav(it, expression))
        return out[0] if single else out


def _as_items(model_input) -> tuple[list, bool]:
    if isinstance(model_input, (str, Path)):
        return [model_input], True
    if isinstance(model_input, dict):
        if "audio" in model_input and "sr" in model_input:
            return [model_input], True
        if "path" in model_input:
            paths = model_input["path"]
            return ([paths], True) if isinstance(paths, (str, Path)) else (list(paths), False)
    if hasattr(model_input, "columns"):  # pandas DataFrame
        if "path" in model_input.columns:
            return list(model_input["path"]), False
        if len(model_input.columns) == 1:
            return list(model_input.iloc[:, 0]), False
    if isinstance(model_input, (list, tuple)):
        return list(model_input), False
    raise ParameterError(f"the mapping model takes a WAV path, a dict with 'audio' and 'sr', a "
                         f"list of these, or a DataFrame with a 'path' column; got "
                         f"{type(model_input).__name__}")


def log_mapping_model(mlf, model_path: Path, *, name: str = "mapping"):
    """Log ``model_path`` (an ``AudioMapping`` file) as a pyfunc model of the active run, from
    code (:mod:`talkingface.experiments.pyfunc_model`): the logged model holds source and data, no pickle."""
    # No input schema: the input is a path, a dict or a list, which a column schema would turn
    # into a DataFrame; the params schema carries the expression.
    signature = ModelSignature(inputs=None,
                               params=ParamSchema([ParamSpec("expression", "string", "neutral")]))
    with warnings.catch_warnings():
        # The input is free-form on purpose (path, dict or list), so MLflow's advice to add type
        # hints or an input example does not apply; every other warning still shows.
        warnings.filterwarnings("ignore", message=".*type hints.*", category=UserWarning)
        warnings.filterwarnings("ignore", message=".*input example.*", category=UserWarning)
        return mlf.pyfunc.log_model(name=name, python_model=str(MODEL_CODE),
                                    artifacts={"mapping": str(model_path)},
                                    code_paths=CODE_PATHS, signature=signature,
                                    pip_requirements=_requirements())


def _requirements() -> list[str]:
    return [f"{p}=={version(p)}" for p in ("numpy", "scipy", "scikit-learn", "torch", "librosa",
                                           "mlflow")]
