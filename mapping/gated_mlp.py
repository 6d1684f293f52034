"""The paper's mapping (§VI): a phone-class gate choosing one of a bank of small MLPs, and the
expression cascade Υ_k (§VI-B).

Training, as in the paper:

1. The gate's mixtures are fitted on the neutral training frames (Ψ_0), labelled with their
   phone class (after the small-class rule of :mod:`mapping.phone_gate`).
2. The neutral training frames are divided into subsets by the gate's decision (the paper
   classifies every sample with the mixtures); one three-layer MLP Ξ_0i per subset maps the
   7-frame audio context to the utterance MUPs. A subset smaller than ``min_class_frames`` is
   joined by the frames labelled with its class, so each MLP sees at least that many frames.
   Hidden units grow with the subset size (:func:`hidden_units`), from ``hidden_min`` for the
   smallest subset to ``hidden_max`` for the largest.
3. ``cascade``: for each expression k, the bank estimates the utterance MUPs of the training
   frames of Ψ_k, and Υ_k (one hidden layer, ``cascade_hidden`` units) maps those estimates to
   the true utterance + expression MUPs. ``bank``: the paper's "straightforward" alternative,
   a bank retrained on Ψ_k with the full MUPs as targets (the gate is shared).

Estimation: features → context → gate → the chosen MLP → utterance MUPs → Υ_k (or bank_k).
Neutral speech has zero expression MUPs.

The recogniser gate (``gate_front_end="recogniser"``, issue 12 part 6): the class of each frame
is the phone a recogniser trained on real speech heard there (:mod:`mapping.recogniser`), in
place of the mixtures on our MFCC; no mixture is fitted. As the paper divides the training
frames by the gate's decision, each training frame goes to the MLP of the phone the recogniser
heard (an augmented copy that was not recognised, to the MLP of its label) — or, with
``phone_training="labels"``, to the MLP of its labelled phone, the training windows then being
the labelled phones around it (:func:`mapping.recogniser.label_windows`: what a perfect
recogniser would hear). The recognised phones are not a function of the features, so every
estimate takes them beside the features (``phones``: per frame the recogniser's window of
phones, ``context_back + 1 + context_forward`` of them,
:func:`mapping.recogniser.recognise_windows`; column ``context_back`` is the frame's own).

The oracle (``gate_front_end="labels"``, issue 13's ceiling): the gate and the phone-input MLPs
read the corpus's own phone labels, in training and in estimation — what any audio model of
this corpus could at best know. It cannot animate audio; it measures the ceiling.

The phone input (``mlp_input="phones"``, with the recogniser gate or the oracle): the MLPs read that window of
phones, one-hot (:func:`phone_inputs`), in place of the MFCC context — the phone-posterior front
end. The MFCC are then not used by any network.
"""
from __future__ import annotations

import numpy as np

from groundwork.errors import NotFittedError, ParameterError
from mapping.bank import MLPBank, fit_banks, hidden_units  # noqa: F401 (hidden_units: API)
from mapping.config import TrainSettings
from mapping.features import ContextFeatures, check_context, check_seed
from mapping.nets import MLP, NetRegressor, fit_many
from mapping.normalize import check_cmvn
from mapping.phone_gate import COVARIANCE_TYPES, PhoneGate, class_groups, merge_small_classes
from mapping.recogniser import N_PHONES, label_windows, phone_inputs, split_recogniser
from mapping.state import (ArrayGroup, nest, part_name, settings_from_params,
                           settings_to_params)

EXPRESSION_MODELS = ("cascade", "bank")
GATE_COVARIANCES = COVARIANCE_TYPES
# GatedMLP's hyper-parameters, as its constructor takes them (``train`` apart: a TrainSettings).
_HYPER_PARAMETERS = ("n_utterance", "context_back", "context_forward", "n_classes",
                     "gate_components", "gate_covariance", "min_class_frames", "hidden_min",
                     "hidden_max", "expression_model", "cascade_hidden", "random_state")
# added later: a model saved without them has these values
_LATER_HYPER_PARAMETERS = {"cmvn": "none", "cmvn_warmup_frames": 30,
                           "gate_front_end": "mfcc", "mlp_input": "mfcc",
                           "phone_training": "recognised", "recogniser": "pocketsphinx"}
GATE_FRONT_ENDS = ("mfcc", "recogniser", "labels")  # mapping.config.GATE_FRONT_END_NAMES
MLP_INPUTS = ("mfcc", "phones")  # mapping.config.MLP_INPUT_NAMES
PHONE_TRAINING = ("recognised", "labels")  # mapping.config.PHONE_TRAINING_NAMES


class GatedMLP:
    """The paper's audio-to-MUP mapping: gate + MLP bank + expression cascade.

    Parameters (scikit-learn style: stored as given, checked in ``fit``)
    ----------
    n_utterance : int
        A0: the first ``n_utterance`` MUPs are the utterance part the bank estimates.
    context_back, context_forward : int
        Frames of audio context before and after the frame (paper: 3 + 1 + 3).
    cmvn, cmvn_warmup_frames :
        Causal cepstral normalisation of the features (:class:`~mapping.features.ContextFeatures`,
        :mod:`mapping.normalize`): "none" (the paper), "mean" or "meanvar".
    n_classes : int
        Gate classes: 44 phone classes, 8 viseme groups or 1 (a single MLP).
    gate_front_end : {"mfcc", "recogniser"}
        The paper's mixtures on the MFCC context, or the phones of a recogniser trained on
        real speech (:mod:`mapping.recogniser`; see the module docstring).
    mlp_input : {"mfcc", "phones"}
        What the MLPs read: the MFCC context (the paper) or the recogniser's window of phones
        (needs the recogniser gate).
    recogniser : {"pocketsphinx", "hama", "causal"} or "causal:<model file>"
        With the recogniser gate, which recogniser hears the phones
        (:data:`mapping.recogniser.RECOGNISERS`, :func:`mapping.recogniser.split_recogniser`).
    phone_training : {"recognised", "labels"}
        With the recogniser gate, the phones training reads: those the recogniser heard in the
        training audio, or the corpus's labels (see the module docstring).
    gate_components : int
        Mixture components per class; ``gate_covariance`` their covariance type.
    min_class_frames : int
        A class with fewer training frames joins its viseme group (:mod:`mapping.phone_gate`).
    hidden_min, hidden_max : int
        Hidden units of the smallest and the largest subset's MLP.
    expression_model : {"cascade", "bank"}
        Υ_k on the bank's estimates, or a bank retrained per expression.
    cascade_hidden : int
        Hidden units of each Υ_k.
    train : TrainSettings
        Optimisation of every network.
    random_state : int
        Seeds the gate, the bank and the expression networks.
    """

    name = "gated_mlp"
    reference = "Hong, Wen & Huang (2002), §VI"

    def __init__(self, *, n_utterance: int = 7, context_back: int = 3, context_forward: int = 3,
                 n_classes: int = 44, gate_components: int = 4, gate_covariance: str = "diag",
                 min_class_frames: int = 40, hidden_min: int = 15, hidden_max: int = 25,
                 expression_model: str = "cascade", cascade_hidden: int = 30,
                 cmvn: str = "none", cmvn_warmup_frames: int = 30,
                 gate_front_end: str = "mfcc", mlp_input: str = "mfcc",
                 phone_training: str = "recognised", recogniser: str = "pocketsphinx",
                 train: TrainSettings = TrainSettings(), random_state: int = 0):
        self.n_utterance = n_utterance
        self.context_back = context_back
        self.context_forward = context_forward
        self.n_classes = n_classes
        self.gate_components = gate_components
        self.gate_covariance = gate_covariance
        self.min_class_frames = min_class_frames
        self.hidden_min = hidden_min
        self.hidden_max = hidden_max
        self.expression_model = expression_model
        self.cascade_hidden = cascade_hidden
        self.cmvn = cmvn
        self.cmvn_warmup_frames = cmvn_warmup_frames
        self.gate_front_end = gate_front_end
        self.mlp_input = mlp_input
        self.phone_training = phone_training
        self.recogniser = recogniser
        self.train = train
        self.random_state = random_state

    def _validate(self) -> None:
        if self.expression_model not in EXPRESSION_MODELS:
            raise ParameterError(f"expression_model must be one of {EXPRESSION_MODELS}, got "
                                 f"{self.expression_model!r}")
        for name in ("n_utterance", "gate_components", "min_class_frames", "hidden_min",
                     "hidden_max", "cascade_hidden"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
                raise ParameterError(f"{name} must be a positive integer, got {value!r}")
        if self.hidden_min > self.hidden_max:
            raise ParameterError(f"hidden_min ({self.hidden_min}) must not exceed hidden_max "
                                 f"({self.hidden_max})")
        if self.gate_front_end not in GATE_FRONT_ENDS:
            raise ParameterError(f"gate_front_end must be one of {GATE_FRONT_ENDS}, got "
                                 f"{self.gate_front_end!r}")
        if self.mlp_input not in MLP_INPUTS:
            raise ParameterError(f"mlp_input must be one of {MLP_INPUTS}, got "
                                 f"{self.mlp_input!r}")
        split_recogniser(self.recogniser)  # an unknown one is refused in one line
        if self.phone_training not in PHONE_TRAINING:
            raise ParameterError(f"phone_training must be one of {PHONE_TRAINING}, got "
                                 f"{self.phone_training!r}")
        if self.mlp_input == "phones" and self.gate_front_end == "mfcc":
            raise ParameterError("mlp_input 'phones' needs gate_front_end 'recogniser' (the "
                                 f"phones are the recogniser's), got {self.gate_front_end!r}")
        if self.gate_covariance not in GATE_COVARIANCES:
            raise ParameterError(f"gate_covariance must be one of {GATE_COVARIANCES}, got "
                                 f"{self.gate_covariance!r}")
        check_context(self.context_back, self.context_forward)
        check_cmvn(self.cmvn, self.cmvn_warmup_frames)
        check_seed(self.random_state)

    # -- training --------------------------------------------------------------------------
    def fit(self, data: list, masks: list) -> "GatedMLP":
        self._validate()
        seed = self.random_state
        self.context_ = ContextFeatures(self.context_back, self.context_forward, self.cmvn,
                                        self.cmvn_warmup_frames).fit([d.features for d in data],
                                                                     masks)
        group_of_phone, names, visemes = class_groups(self.n_classes)
        X, Y, labels, expr, heard = self._stack(data, masks, group_of_phone)
        neutral = expr == "neutral"
        if not neutral.any():
            raise ParameterError("the mapping needs neutral training frames (Ψ_0) for the gate "
                                 "and the MLP bank; the training set has none")
        target, self.merges_ = merge_small_classes(labels[neutral], names, visemes,
                                                   self.min_class_frames)
        self.group_of_phone_ = target[group_of_phone]
        self.class_names_ = names
        labels = target[labels]
        classes = np.unique(labels[neutral])
        self.classes_ = classes
        if self.gate_front_end == "mfcc":
            self.gate_ = PhoneGate(self.gate_components, self.gate_covariance, seed).fit(
                X[neutral], labels[neutral], classes)
            gated = self.gate_.predict(X)
        else:  # the recogniser decides: the class it heard, or the label where none was heard
            self.gate_ = None
            gated = np.where(heard >= 0, target[np.maximum(heard, 0)], labels)
            gated = np.where(np.isin(gated, classes), gated, labels)
        self.bank_ = MLPBank(self.hidden_min, self.hidden_max, self.train, seed + 1).fit(
            X, Y[:, :self.n_utterance], self._subsets(gated, labels, neutral, classes))
        self.expressions_ = tuple(sorted({e for e in expr if e != "neutral"}))
        self.n_mups_ = Y.shape[1]
        # the expression networks of every expression train together (one batch)
        self.experts_, inputs, banks = {}, [], []
        for j, k in enumerate(self.expressions_):
            rows = expr == k
            if self.expression_model == "cascade":
                c0 = self.bank_.predict(X[rows], gated[rows])
                self.experts_[k] = NetRegressor(MLP(c0.shape[1], self.cascade_hidden,
                                                    Y.shape[1]), self.train,
                                                seed + 7919 * (j + 1))
                inputs.append((c0, Y[rows]))
            else:
                sub = self._subsets(gated[rows], labels[rows], np.ones(rows.sum(), bool), classes)
                banks.append(MLPBank(self.hidden_min, self.hidden_max, self.train,
                                     seed + 7919 * (j + 1)).prepare(X[rows], Y[rows], sub))
                self.experts_[k] = banks[-1][0]
        if inputs:
            fit_many(list(self.experts_.values()), [x for x, _ in inputs],
                     [y for _, y in inputs])
        fit_banks(banks)
        return self

    def _stack(self, data, masks, group_of_phone):
        """Training rows: inputs, MUPs, labelled class, expression, and the class the
        recogniser heard (−1 where none was heard, or training reads the labels)."""
        xs, ys, ls, es, hs = [], [], [], [], []
        for d, mk in zip(data, masks):
            windows, heard = self._training_windows(d)
            xs.append(self._inputs(d.features, windows)[mk])
            ys.append(d.mups[mk])
            ls.append(group_of_phone[d.phones[mk]])
            es.append(np.full(int(mk.sum()), d.expression))
            hs.append(group_of_phone[windows[mk, self.context_back]] if heard
                      else np.full(int(mk.sum()), -1))
        return (np.concatenate(xs), np.concatenate(ys).astype(np.float32), np.concatenate(ls),
                np.concatenate(es), np.concatenate(hs))

    def _training_windows(self, d) -> tuple:
        """``(windows, heard)`` of one training utterance: the recognised windows (heard), the
        labelled windows (``phone_training="labels"``), or None when no window is read."""
        if self.gate_front_end == "labels" or (self.gate_front_end == "recogniser"
                                               and self.phone_training == "labels"):
            return label_windows(d.phones, self.context_back, self.context_forward), False
        windows = getattr(d, "recognised", None)
        if windows is None:
            if self.mlp_input == "phones":
                raise ParameterError(f"utterance {d.utt_id} carries no recognised phones; the "
                                     "phone-input MLPs need them (build_dataset with "
                                     "recognise_context)")
            return None, False
        return self._check_windows(windows, d.n_frames), True

    def _inputs(self, features: np.ndarray, windows) -> np.ndarray:
        """The MLPs' inputs of one utterance: its normalised MFCC context, or its one-hot
        windows of recognised phones (``mlp_input="phones"``)."""
        if self.mlp_input == "phones":
            return phone_inputs(windows)
        return self.context_.transform(features)

    def _subsets(self, gated, labels, use, classes) -> dict:
        subsets = {}
        for c in classes:
            rows = np.flatnonzero(use & (gated == c))
            if len(rows) < self.min_class_frames:
                rows = np.union1d(rows, np.flatnonzero(use & (labels == c)))
            subsets[c] = rows
        return subsets

    # -- estimation ------------------------------------------------------------------------
    def _check_fitted(self):
        if not hasattr(self, "bank_"):
            raise NotFittedError("GatedMLP is not trained yet: call fit() first")

    @property
    def needs_phones(self) -> bool:
        """True when every estimate needs windows of phones (the recogniser gate, the oracle)."""
        return self.gate_front_end != "mfcc"

    def utterance_phones(self, d):
        """The windows of phones an estimate of the corpus utterance ``d`` (a
        :class:`mapping.dataset.UttData`) reads: the recognised ones, the labelled ones for the
        oracle, or None for the paper's gate."""
        if self.gate_front_end == "labels":
            return label_windows(d.phones, self.context_back, self.context_forward)
        return d.recognised if self.gate_front_end == "recogniser" else None

    @property
    def window(self) -> int:
        """Phones in each frame's recognised window: ``context_back + 1 + context_forward``."""
        return self.context_back + 1 + self.context_forward

    def _check_windows(self, phones, n_frames: int) -> np.ndarray:
        if phones is None:
            raise ParameterError("this mapping's gate is the phone recogniser: give the "
                                 "recognised phones of the audio "
                                 "(mapping.recogniser.recognise_windows)")
        p = np.asarray(phones)
        if p.shape != (n_frames, self.window) or p.dtype.kind not in "iu" \
                or p.min(initial=0) < 0 or p.max(initial=0) >= N_PHONES:
            raise ParameterError(f"recognised phones must be {n_frames} windows of "
                                 f"{self.window} class indices in 0..{N_PHONES - 1}, got shape "
                                 f"{p.shape}")
        return p

    def phone_classes(self, phones, n_frames: int) -> np.ndarray:
        """The gate classes of the recognised phones: windows (``n_frames``, :attr:`window`)
        of phone indices, each frame's own in column ``context_back``."""
        return self.group_of_phone_[self._check_windows(phones, n_frames)[:, self.context_back]]

    def gate_classes(self, features: np.ndarray, phones=None) -> np.ndarray:
        """The class chosen by the gate for each frame of one utterance's raw features
        (``phones``: the recognised phones, for the recogniser gate)."""
        self._check_fitted()
        if self.gate_ is None:
            return self.phone_classes(phones, len(features))
        return self.gate_.predict(self.context_.transform(features))

    def predict(self, features: np.ndarray, expression: str = "neutral",
                phones=None) -> np.ndarray:
        """MUPs (n_frames, A0 + Ak) of one utterance from its raw features (n_frames, n_feat)
        (``phones``: the recognised phones, for the recogniser gate)."""
        self._check_fitted()
        # the phone-input MLPs read no MFCC: their context is not built
        X = (np.zeros((len(features), 0), np.float32) if self.mlp_input == "phones"
             else self.context_.transform(features))
        return self.predict_stacked(X, expression, phones)

    def predict_stacked(self, X: np.ndarray, expression: str = "neutral",
                        phones=None) -> np.ndarray:
        """MUPs from normalised, context-stacked features (n_frames, n_inputs); each row is
        estimated on its own, which is what the streaming animator needs. ``phones``: the
        recognised window of each row, for the recogniser gate (:meth:`phone_classes`)."""
        self._check_fitted()
        if expression != "neutral" and expression not in self.experts_:
            raise ParameterError(f"expression {expression!r} was not trained; allowed: neutral, "
                                 f"{', '.join(self.expressions_)}")
        if self.gate_ is None:
            gated = self.phone_classes(phones, len(X))
            if self.mlp_input == "phones":
                X = phone_inputs(phones)
        else:
            gated = self.gate_.predict(X)
        c0 = self.bank_.predict(X, gated)
        if expression == "neutral":
            return np.concatenate([c0, np.zeros((len(X), self.n_mups_ - c0.shape[1]),
                                                np.float32)], axis=1)
        if self.expression_model == "cascade":
            return self.experts_[expression].predict(c0)
        return self.experts_[expression].predict(X, gated)

    # -- persistence (see mapping.state) ---------------------------------------------------
    def to_arrays(self) -> tuple[dict, dict]:
        """The trained mapping as data.

        Arrays: ``group_of_phone`` (44,), and the arrays of the parts under ``context/``
        (:class:`~mapping.features.ContextFeatures`), ``gate/``
        (:class:`~mapping.phone_gate.PhoneGate`), ``bank/`` (:class:`MLPBank`) and ``experts/<k>/``
        (expression k's Υ_k, a :class:`~mapping.nets.NetRegressor`, or its
        :class:`MLPBank`). Parameters: the
        constructor's hyper-parameters (``train`` as a record), ``merges``, ``class_names``,
        ``expressions``, ``n_mups`` and the parameters of each part under the same keys.
        """
        self._check_fitted()
        params = {name: getattr(self, name) for name in (*_HYPER_PARAMETERS,
                                                          *_LATER_HYPER_PARAMETERS)}
        params["train"] = settings_to_params(self.train)
        params.update(merges=dict(self.merges_), class_names=list(self.class_names_),
                      expressions=list(self.expressions_), n_mups=int(self.n_mups_))
        arrays = {"group_of_phone": self.group_of_phone_}
        parts = (("context", self.context_), ("gate", self.gate_), ("bank", self.bank_))
        for key, part in parts:
            if part is None:  # the recogniser gate has nothing to save
                continue
            a, params[key] = part.to_arrays()
            arrays.update(nest(key, a))
        params["experts"] = []
        for k in self.expressions_:
            a, p = self.experts_[k].to_arrays()
            arrays.update(nest(f"experts/{part_name(k)}", a))
            params["experts"].append(p)
        return arrays, params

    @classmethod
    def from_arrays(cls, arrays, params: dict) -> "GatedMLP":
        """The trained mapping of :meth:`to_arrays` (hyper-parameters checked as in ``fit``)."""
        g = ArrayGroup.of(arrays)
        m = cls(**{name: params[name] for name in _HYPER_PARAMETERS},
                **{name: params.get(name, default)
                   for name, default in _LATER_HYPER_PARAMETERS.items()},
                train=settings_from_params(params["train"]))
        m._validate()
        m.context_ = ContextFeatures.from_arrays(g.group("context"), params["context"])
        if (m.context_.back, m.context_.forward) != (m.context_back, m.context_forward):
            raise ParameterError(f"the context window ({m.context_.back}, "
                                 f"{m.context_.forward}) differs from the hyper-parameters "
                                 f"({m.context_back}, {m.context_forward})")
        m.gate_ = (PhoneGate.from_arrays(g.group("gate"), params["gate"])
                   if m.gate_front_end == "mfcc" else None)
        m.bank_ = MLPBank.from_arrays(g.group("bank"), params["bank"])
        group_of_phone, _, _ = class_groups(m.n_classes)
        m.group_of_phone_ = g.take("group_of_phone", group_of_phone.shape, kinds="iu")
        m.classes_ = (m.gate_.classes_ if m.gate_ is not None
                      else np.unique(m.group_of_phone_))
        if set(m.bank_.nets_) != set(m.classes_.tolist()):
            raise ParameterError(f"the MLP bank's classes {sorted(m.bank_.nets_)} are not the "
                                 f"gate's {m.classes_.tolist()}")
        m.merges_ = dict(params["merges"])
        m.class_names_ = tuple(params["class_names"])
        m.expressions_ = tuple(params["expressions"])
        m.n_mups_ = int(params["n_mups"])
        if len(params["experts"]) != len(m.expressions_):
            raise ParameterError(f"{len(m.expressions_)} expressions but "
                                 f"{len(params['experts'])} expression models")
        expert = NetRegressor if m.expression_model == "cascade" else MLPBank
        m.experts_ = {k: expert.from_arrays(g.group("experts").group(k), p)
                      for k, p in zip(m.expressions_, params["experts"])}
        return m
