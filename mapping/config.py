"""The mapping's settings (paper §VI) and its evaluation's (§VII-A), owned by ``mapping``.

``MappingConfig`` is the ``mapping`` section of the run config; the optimisation settings every
network shares are nested in it as ``mapping.train`` (:class:`TrainSettings`), and the
training-time audio augmentation as ``mapping.augment`` (:class:`AugmentSettings`).

Speaker and channel robustness (issue 12), every part off by default so the paper's Tables I–II
are unchanged:

* ``cmvn`` — causal per-utterance cepstral mean ("mean") or mean and variance ("meanvar")
  normalisation, offline and streaming alike, with a prior (the training frames' statistics,
  saved in the model) weighing ``cmvn_warmup_frames`` frames (:mod:`mapping.normalize`);
* ``vtlp_range`` — the VTLP speaker warp (Jaitly & Hinton 2013) of the training copies: each
  copy's mel filterbank is warped by α ~ U(lo, hi); [1, 1] is off, inference is never warped;
* ``augment.copies`` — augmented copies of every training utterance (:mod:`mapping.augment`);
* ``gate_front_end`` — "mfcc", the paper's mixtures on the MFCC, or "recogniser", the phones that
  pocketsphinx's en-US model (trained on real speech) hears, decided with the context look-ahead
  (:mod:`mapping.recogniser`): the recogniser front end; or "labels", the corpus's own phone
  labels — an oracle for the ceiling of any audio model on the corpus, which cannot animate
  audio;
* ``recogniser`` — with the recogniser gate, which recogniser hears the phones: "pocketsphinx"
  (its en-US allphone decoder), "hama" (a multilingual CTC phoneme model; issue 29,
  :mod:`mapping.hama_front`) or "causal" (our small causal front end taught by hama; issue 40,
  :mod:`mapping.causal_front`, its model file ``front_model``), one interface
  (:func:`mapping.recogniser.phone_stream`);
* ``mlp_input`` — what the MLP bank reads: "mfcc", the paper's MFCC context, or "phones", the
  recogniser's window of phones around the frame (one-hot; the phone-posterior front end, the
  route Rhubarb Lip Sync takes), which needs the recogniser gate;
* ``phone_training`` — with the recogniser gate, whether training reads the phones the
  recogniser heard in the training audio ("recognised") or the corpus's labels ("labels": the
  phone-input MLPs learn the mouth of the labelled phones, and each training frame goes to the
  MLP of its labelled phone).

The features' band (issue 37): ``mel_fmax_hz`` is the mel filterbank's upper edge in Hz (0:
sr/2), saved with the model, so audio of any rate resampled to the model's rate is read in the
band the model was trained on (:func:`mapping.filterbank.check_mel_fmax`).

The training set gains ``augment.copies`` copies of each training utterance (its training
frames only; test utterances never), or one warped copy each when only the warp is on
(``augment.copies`` 0 and ``vtlp_range`` not [1, 1]). Every copy is drawn from the seed, the
utterance and the copy number.
:func:`mapping.experiment.make_mapper` turns a section into the estimators' explicit
hyper-parameters, so no estimator reads a config object. Every value is checked when the config
is made (:mod:`groundwork.settings`).

The names below are those of :data:`mapping.experiment.METHODS`, :data:`mapping.dataset.SPLITS`,
:data:`mapping.phone_gate.N_CLASS_CHOICES` and ``MFCC_SETTINGS["n_mels"] - 1``, written out so loading
a config imports neither torch nor librosa (a test keeps them equal).
"""
from __future__ import annotations

from dataclasses import dataclass, field

from groundwork.settings import (check_fields, check_order, choice, fraction, integer, number,
                                 numbers, require, span, subset)

METHOD_NAMES = ("gated_mlp", "vq", "linear", "gmm_regression", "mlp_large", "tdnn", "gru")
SPLIT_NAMES = ("random_frames", "utterance")
MAX_MFCC = 25  # MFCCs of 26 mel bands
CMVN_NAMES = ("none", "mean", "meanvar")  # mapping.normalize.CMVN_MODES
NOISE_COLOURS = ("white", "pink", "brown")  # mapping.augment.NOISE_BETA
GATE_FRONT_END_NAMES = ("mfcc", "recogniser", "labels")  # mapping.gated_mlp.GATE_FRONT_ENDS
MLP_INPUT_NAMES = ("mfcc", "phones")  # mapping.gated_mlp.MLP_INPUTS
WINDOW_ALIGN_NAMES = ("centre", "right")  # mapping.features.WINDOW_ALIGNS
PHONE_TRAINING_NAMES = ("recognised", "labels")  # mapping.gated_mlp.PHONE_TRAINING
RECOGNISER_NAMES = ("pocketsphinx", "hama", "causal")  # mapping.recogniser.RECOGNISERS
MEL_FMAX_HZ = 4000.0  # the pick of tools/choose_feature_band.py (its --check keeps them equal)


FRONT_MAX_LOOKAHEAD_MS = 100  # mapping.front_net.MAX_LOOKAHEAD_MS (a test keeps them equal)


@dataclass(frozen=True)
class FrontSettings:
    """The causal front end's network and training (config section ``front_end.train``;
    :mod:`mapping.front_training`; a refused value names its key)."""

    hidden: int = integer(128, ge=1)  # GRU and convolution width H
    n_mels: int = integer(40, ge=1, le=128)  # mel bands
    lookahead_ms: int = 100  # the longest head: a multiple of 10 from 0 to 100
    mel_fmax_hz: float = number(8000.0, ge=1000.0, le=8000.0)  # the filterbank's upper edge
    epochs: int = integer(8, ge=1)  # at most
    batch: int = integer(32, ge=1)  # segments per minibatch
    learning_rate: float = number(1e-3, gt=0)
    label_weight: float = number(0.5, ge=0)  # weight of the true-label cross-entropy
    segment_s: float = number(4.0, gt=0)  # seconds per training segment
    holdout_fraction: float = number(0.1, ge=0, lt=1)  # training utterances held out
    patience: int = integer(3, ge=0)  # epochs without a better held-out loss (0: no stop)

    def __post_init__(self):
        check_fields(self)
        v = self.lookahead_ms
        require(self, "lookahead_ms", not isinstance(v, bool) and isinstance(v, int)
                and 0 <= v <= FRONT_MAX_LOOKAHEAD_MS and v % 10 == 0,
                f"a multiple of 10 from 0 to {FRONT_MAX_LOOKAHEAD_MS} (ms)")


@dataclass(frozen=True)
class TrainSettings:
    """Optimisation settings shared by every network (Adam, early stopping)."""

    validation_fraction: float = fraction(0.15)
    max_epochs: int = integer(600, ge=1)
    patience: int = integer(40, ge=1)  # epochs without a better validation loss
    learning_rate: float = number(0.01, gt=0)
    weight_decay: float = number(1e-4, ge=0)
    batch_size: int = integer(0, ge=0)  # 0: full batch

    def __post_init__(self):
        check_fields(self)


def probability(default: float):
    """A probability in [0, 1]."""
    return number(default, ge=0, le=1)


@dataclass(frozen=True)
class AugmentSettings:
    """Training-time audio augmentation of the mapping's training utterances (issue 12).

    ``copies`` augmented copies per training utterance (0: none, the default). In each copy every
    stage fires with its own probability, in this order: tempo, pitch, reverberation, noise,
    babble, telephone band, gain, clipping (:func:`mapping.augment.augment`).
    """

    copies: int = integer(0, ge=0)
    # tempo (librosa time_stretch, pitch kept): rate ~ U(range); targets and labels re-timed
    tempo_prob: float = probability(0.3)
    tempo_range: tuple = span((0.9, 1.1), ge=0.5, le=2.0)
    # pitch (librosa pitch_shift: F0 and formants) by U(range) semitones; length kept
    pitch_prob: float = probability(0.2)
    pitch_semitones: tuple = span((-2.0, 2.0), ge=-12, le=12)
    # reverberation: a synthetic shoebox room (image method), RT60 ~ U(range) seconds
    reverb_prob: float = probability(0.3)
    rt60_range: tuple = span((0.2, 0.6), gt=0, le=1.5)
    # generated noise of one of the colours at one of the SNRs (dB, whole-utterance power)
    noise_prob: float = probability(0.5)
    noise_colours: tuple = subset(("white", "pink"), NOISE_COLOURS)
    snr_db: tuple = numbers((0.0, 5.0, 10.0, 20.0), ge=-20, le=60)
    # babble: the sum of babble_talkers other training utterances, at one of babble_snr_db
    babble_prob: float = probability(0.2)
    babble_talkers: int = integer(4, ge=1)
    babble_snr_db: tuple = numbers((5.0, 10.0, 15.0), ge=-20, le=60)
    # telephone band: 300–3400 Hz Butterworth band-pass, zero phase (sosfiltfilt)
    telephone_prob: float = probability(0.1)
    # gain in dB ~ U(range), then hard clipping at full scale (±1)
    gain_prob: float = probability(0.5)
    gain_db: tuple = span((-12.0, 12.0), ge=-60, le=40)
    # clipping so that clip_fraction of the samples saturate
    clip_prob: float = probability(0.1)
    clip_fraction: float = number(0.01, gt=0, lt=0.5)

    def __post_init__(self):
        check_fields(self)


@dataclass(frozen=True)
class MappingConfig:
    """The audio-to-MUP mapping (paper §VI) and its evaluation (§VII-A)."""

    # the mapping trained and logged as the model (or a baseline)
    method: str = choice(*METHOD_NAMES)
    baselines: tuple = subset(METHOD_NAMES[1:], METHOD_NAMES, empty_ok=True)  # every baseline
    splits: tuple = subset(SPLIT_NAMES, SPLIT_NAMES)
    train_fraction: float = fraction(0.8)
    # features
    n_mfcc: int = integer(10, ge=1, le=MAX_MFCC)
    deltas: bool = False
    context_back: int = integer(3, ge=0)
    context_forward: int = integer(3, ge=0)  # the look-ahead, frames
    # the analysis window centred on the frame instant (the paper; 12.5 ms of audio after it) or
    # ending there (no sample after the instant: the look-ahead is the only latency)
    window_align: str = choice(*WINDOW_ALIGN_NAMES)
    # the mel filterbank's upper edge, Hz (0: sr/2, the paper's); chosen on development data by
    # tools/choose_feature_band.py so a 16 kHz recording reads the band the model was trained on
    # (issue 37); at most the training audio's Nyquist frequency (checked where features are made)
    mel_fmax_hz: float = number(MEL_FMAX_HZ, ge=0)
    # speaker and channel normalisation (issue 12; see the module docstring)
    cmvn: str = choice(*CMVN_NAMES)
    cmvn_warmup_frames: int = integer(30, ge=1)
    vtlp_range: tuple = span((1.0, 1.0), ge=0.8, le=1.2)
    # gate: one Gaussian mixture per phone class on the MFCC ("mfcc", the paper), or the phones
    # of a recogniser trained on real speech ("recogniser", mapping.recogniser)
    gate_front_end: str = choice(*GATE_FRONT_END_NAMES)
    # with the recogniser gate, which recogniser: pocketsphinx's en-US allphone decoder, or
    # hama's multilingual CTC phoneme model (issue 29; mapping.hama_front), or our own causal
    # front end taught by hama (issue 40; mapping.causal_front)
    recogniser: str = choice(*RECOGNISER_NAMES)
    # with recogniser "causal": its model file (empty: the run's front_end stage's model in a
    # run, the shipped file mapping/models/causal_front.npz elsewhere)
    front_model: str = ""
    # what the MLPs read: the MFCC context (the paper) or the recogniser's window of phones
    mlp_input: str = choice(*MLP_INPUT_NAMES)
    # with the recogniser gate, what training reads: the phones the recogniser heard in the
    # training audio, or the corpus's phone labels (what a perfect recogniser would hear)
    phone_training: str = choice(*PHONE_TRAINING_NAMES)
    n_classes: int = choice(44, 8, 1)  # 44 phone classes | 8 viseme groups | 1 (a single MLP)
    gate_components: int = integer(4, ge=1)
    gate_covariance: str = choice("diag", "full", "tied", "spherical")
    # smaller classes merge into their viseme group (mapping.phone_gate)
    min_class_frames: int = integer(40, ge=1)
    # MLP bank: hidden units grow with the subset size, between these bounds
    hidden_min: int = integer(15, ge=1)
    hidden_max: int = integer(25, ge=1)
    # expressions: cascade (Υ_k on the bank's estimates) or a bank retrained per expression
    expression_model: str = choice("cascade", "bank")
    cascade_hidden: int = integer(30, ge=1)
    # the MUPs the mapping learns: from the corpus markers, or from the MU-constrained tracker
    # run on the corpus rendered as marker video (§V: how the paper collected its data)
    visual_source: str = choice("markers", "tracked")
    # optimisation of every network
    train: TrainSettings = field(default_factory=TrainSettings)
    # training-time audio augmentation (off: copies = 0)
    augment: AugmentSettings = field(default_factory=AugmentSettings)
    # processes training the methods × splits at once (0: one per core); the speed only
    workers: int = integer(0, ge=0)

    def __post_init__(self):
        check_fields(self)
        check_order(self, "hidden_min", "hidden_max")
        require(self, "mlp_input", self.mlp_input == "mfcc" or self.gate_front_end != "mfcc",
                "'mfcc' unless gate_front_end is 'recogniser' (the phones are the recogniser's)",
                ("gate_front_end",))
        require(self, "front_model", not self.front_model or (
            self.recogniser == "causal" and self.front_model.strip() == self.front_model
            and self.front_model.isprintable()),
            "empty, or with recogniser 'causal' the path of a front-end model file (without "
            "leading or trailing spaces or control characters)", ("recogniser",))
