"""The judgments table every study analysis takes, and how a judgment is scored (paper §VII-C).

:func:`check_frame` refuses a table that lacks a needed column or holds an unknown code;
:func:`correct` scores each judgment. A response is *correct* when it equals the emotion of the
face's expression (``EMOTION_OF``) in visual-only and bimodal trials — "face-consistent" — and
the sentence's emotion (``AUDIO_EMOTION``) in audio-only trials. "Not sure" is never correct.

The statistics (:mod:`analysis.stats`) and the crossover tests (:mod:`analysis.crossover`) both
build on these two functions.
"""
from __future__ import annotations

import numpy as np
import pandas as pd

from groundwork.errors import ParameterError
from study.design import AUDIO, AUDIO_EMOTION, EMOTION_OF, EXPRESSIONS, FACES, RESPONSES, SEQUENCES

NEEDED = ("participant_id", "sequence", "block", "period", "face", "expression", "audio",
          "response")
_CODES = {"block": ("visual", "audio", "bimodal"), "face": (*FACES, "none"),
          "expression": (*EXPRESSIONS, "none"), "audio": (*AUDIO, "none"),
          "response": RESPONSES, "sequence": SEQUENCES}


def check_frame(df: pd.DataFrame) -> pd.DataFrame:
    """Refuse a table without the needed columns or with an unknown code (naming both)."""
    missing = [c for c in NEEDED if c not in df.columns]
    if missing:
        raise ParameterError(f"study data lack columns {missing}; needed: {', '.join(NEEDED)}")
    for col, allowed in _CODES.items():
        bad = sorted(set(df[col].astype(str)) - set(allowed))
        if bad:
            raise ParameterError(f"column {col} has unknown codes {bad}; allowed: "
                                 f"{', '.join(allowed)}")
    seqs = df.groupby("participant_id")["sequence"].nunique()
    if (seqs > 1).any():
        raise ParameterError(f"participant {seqs[seqs > 1].index[0]!r} has two sequences")
    return df


def correct(df: pd.DataFrame) -> pd.Series:
    """Boolean per judgment: face-consistent (visual, bimodal) or sentence-consistent (audio)."""
    check_frame(df)
    target = np.where(df["block"] == "audio", df["audio"].map(AUDIO_EMOTION),
                      df["expression"].map(EMOTION_OF))
    return pd.Series(df["response"].to_numpy() == target, index=df.index, name="correct")
