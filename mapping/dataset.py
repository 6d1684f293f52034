"""The audio-visual training database of the mapping (paper §VI-A, §VII-A) and its splits.

One :class:`UttData` per utterance: raw audio features per frame, the true MUPs of the same
frames (the tracked MUP sequence of the paper), and the phone class of each frame (the gate's
labels). Splits give, per utterance, a boolean mask of its training frames:

* ``random_frames`` — the paper's split: ``train_fraction`` of all frames drawn at random, so
  neighbouring frames of one sentence fall on both sides;
* ``utterance`` — by sentence: ``train_fraction`` of the distinct sentence texts are training
  sentences, and every utterance of a sentence (in every expression and by every speaker) is on
  the side of its sentence, so no sentence is on both sides.
"""
from __future__ import annotations

import zlib
from contextlib import nullcontext
from dataclasses import dataclass, field, replace

import numpy as np
from tqdm import tqdm

from face_model.alignment import corpus_deformations
from face_model.corpus import corpus_hash
from groundwork.cache import content_key
from groundwork.errors import ParameterError
from mapping.augment import augment, retime_labels, retime_targets, rir_bank
from mapping.config import AugmentSettings
from mapping.features import FEATURES_VERSION, audio_features, hop_samples
from mapping.filterbank import check_mel_fmax
from mapping.recogniser import (fit_length, hearing_cache, recognise_windows,
                                recogniser_name)

SPLITS = ("random_frames", "utterance")


@dataclass
class UttData:
    """One utterance of the database; arrays are frame-major and of one length."""

    utt_id: str
    speaker: str
    expression: str
    text: str
    features: np.ndarray = field(repr=False)  # (n_frames, n_features) raw MFCC (+ deltas)
    mups: np.ndarray = field(repr=False)  # (n_frames, A0 + Ak) true MUPs
    phones: np.ndarray = field(repr=False)  # (n_frames,) phone-class indices
    # the utterance's audio (for augmented training copies; None: features only)
    audio: np.ndarray | None = field(default=None, repr=False)  # (n_samples,) float
    sample_rate: int = 0  # Hz, of ``audio``
    fps: int = 30
    # the mel filterbank's upper edge of ``features``, Hz (0: sr/2); training copies use it too
    mel_fmax_hz: float = 0.0
    # the phones a recogniser heard: per frame its window of phone indices (the recogniser
    # gate's input, mapping.recogniser.recognise_windows; None: not needed)
    recognised: np.ndarray | None = field(default=None, repr=False)  # (n_frames, window)

    def __post_init__(self):
        n = len(self.features)
        if len(self.mups) != n or len(self.phones) != n:
            raise ParameterError(
                f"utterance {self.utt_id}: features ({n} frames), MUPs ({len(self.mups)} frames) "
                f"and phone labels ({len(self.phones)} frames) must have the same length")
        if self.recognised is not None and len(self.recognised) != n:
            raise ParameterError(f"utterance {self.utt_id}: {n} frames but "
                                 f"{len(self.recognised)} recognised phones")
        if not np.all(np.isfinite(self.features)):
            raise ParameterError(f"utterance {self.utt_id}: features hold NaN or inf values")
        if not np.all(np.isfinite(self.mups)):
            raise ParameterError(f"utterance {self.utt_id}: MUPs hold NaN or inf values")

    @property
    def n_frames(self) -> int:
        return len(self.features)


def build_dataset(corpus, units, *, n_mfcc: int = 10, deltas: bool = False,
                  alignment: str | None = None, recognise_context: tuple | None = None,
                  window_align: str = "centre", mel_fmax_hz: float = 0.0,
                  progress: bool = False, cache=None) -> list[UttData]:
    """Features, true MUPs and phone labels of every utterance of ``corpus``.

    The MUPs are the Motion Units' projection of the aligned deformations (the alignment model
    recorded in the units' metadata unless given). ``recognise_context`` (back, forward) frames:
    also the phones the recogniser hears, per frame the window of ``back`` past to ``forward``
    future frames decided with ``forward`` frames of look-ahead
    (:func:`mapping.recogniser.recognise_windows`; the recogniser gate's input), fitted to the
    utterance's frames. ``window_align``: the MFCC window's alignment
    (:func:`mapping.features.aligned`). ``mel_fmax_hz``: the mel filterbank's upper edge, Hz
    (0: sr/2; :func:`mapping.filterbank.check_mel_fmax`), kept in each utterance. ``cache``: a
    :class:`groundwork.cache.ArrayCache` that keeps the features of a corpus (one entry, by
    its content and the settings) and the recognised phones of each recording (one entry per
    recording, by its audio and the settings: :func:`mapping.recogniser.windows_key`; filled
    on every core beforehand by :func:`mapping.hearing.hear_all`) for every later call (a
    grid's tasks, later runs).
    """
    alignment = alignment or units.metadata_.get("alignment", "similarity")
    defs = corpus_deformations(corpus, model=alignment, neutrals=_fitted_neutrals(corpus, units))
    for u in corpus.utterances[:1]:  # a bad edge is refused before any feature is made
        check_mel_fmax(mel_fmax_hz, u.sample_rate)
    what = ("features", FEATURES_VERSION, n_mfcc, deltas, window_align)
    if mel_fmax_hz:  # sr/2 keeps the key of the features made before the setting existed
        what += (float(mel_fmax_hz),)
    feats = _per_utterance(corpus, cache, what,
                           lambda u: audio_features(u.audio, sr=u.sample_rate, fps=u.fps,
                                                    n_mfcc=n_mfcc, deltas=deltas,
                                                    n_frames=u.n_frames, align=window_align,
                                                    mel_fmax_hz=mel_fmax_hz))
    heard = {}
    if recognise_context is not None:
        recogniser_name(*recognise_context[2:])  # an unknown recogniser is refused first
        # one entry per recording (mapping.hearing fills them); no cache: the caller's, if any
        with nullcontext() if cache is None else hearing_cache(cache):
            heard = {u.utt_id: recognised_windows(u.audio, u.sample_rate, u.fps,
                                                  recognise_context, u.n_frames)
                     for u in tqdm(corpus.utterances, desc="recognising phones", unit="utt",
                                   disable=not progress)}
    out = []
    for u in corpus.utterances:
        out.append(UttData(u.utt_id, u.speaker, u.expression, u.text, feats[u.utt_id],
                           units.transform(defs[u.utt_id], u.expression).astype(np.float32),
                           u.phone_per_frame(), audio=u.audio, sample_rate=u.sample_rate,
                           fps=u.fps, mel_fmax_hz=float(mel_fmax_hz),
                           recognised=heard.get(u.utt_id)))
    return out


def _per_utterance(corpus, cache, what: tuple, make, desc: str | None = None) -> dict:
    """``{utt_id: make(u)}`` for every utterance of ``corpus``; with ``cache`` (a
    :class:`groundwork.cache.ArrayCache`) read from, or made once into, the entry keyed by the
    corpus's content hash and ``what`` (the kind first, then every setting and version the
    arrays depend on)."""
    def build() -> dict:
        return {u.utt_id: make(u) for u in tqdm(corpus.utterances, desc=desc, unit="utt",
                                                disable=desc is None)}

    if cache is None:
        return build()
    key = content_key(corpus_hash(corpus.root), *what)
    arrays = cache.get_or_make(what[0], key, build)
    missing = [u.utt_id for u in corpus.utterances if u.utt_id not in arrays]
    if missing:  # a hash collision cannot happen; a damaged entry can: make it again
        raise ParameterError(f"cache entry {cache.path(what[0], key)} lacks utterances "
                             f"{missing[:3]}; remove it (talkingface cache clean)")
    return arrays


def recognised_windows(y: np.ndarray, sr: int, fps: int, context: tuple, n_frames: int
                       ) -> np.ndarray:
    """The recogniser's windows (n_frames, back + 1 + forward) of audio ``y`` for the context
    ``(back, forward[, recogniser])`` (pocketsphinx unless named), fitted to ``n_frames``."""
    back, forward, *which = context
    return fit_length(recognise_windows(y, sr, fps=fps, delay_frames=forward, back=back,
                                        recogniser=which[0] if which else "pocketsphinx"),
                      n_frames)


def copies_per_utterance(settings: AugmentSettings, vtlp_range) -> int:
    """``settings.copies``, or 1 when only the VTLP warp is on, else 0."""
    if settings.copies:
        return settings.copies
    return int(vtlp_range[0] != 1.0 or vtlp_range[1] != 1.0)


def utterance_key(utt_id: str) -> int:
    """A stable integer of an utterance id (the same in every process, unlike ``hash``)."""
    return zlib.crc32(utt_id.encode("utf-8"))


def _fitted_neutrals(corpus, units) -> dict | None:
    """The neutral faces the Motion Units were fitted with, when they were fitted on part of
    ``corpus`` (held-out sentences: their ``held_out_utterances`` and ``neutrals`` metadata), so
    the training targets of the mapping never read a held-out sentence either; None otherwise
    (the corpus's own :func:`face_model.alignment.speaker_neutrals`)."""
    meta = units.metadata_
    held = set(meta.get("held_out_utterances") or ())
    neutrals = meta.get("neutrals") or {}
    ids = {u.utt_id for u in corpus.utterances}
    if not held or not held <= ids or not {u.speaker for u in corpus.utterances} <= set(neutrals):
        return None
    return {k: np.asarray(v, dtype=np.float64) for k, v in neutrals.items()}


def training_copies(data: list[UttData], masks: list, *, settings: AugmentSettings,
                    vtlp_range=(1.0, 1.0), n_mfcc: int = 10, deltas: bool = False,
                    seed: int = 0, recognise_context: tuple | None = None,
                    window_align: str = "centre") -> tuple[list[UttData], list[np.ndarray]]:
    """Augmented copies of the training utterances and their training-frame masks.

    Copy c of an utterance with training frames (:func:`copies_per_utterance` of them) is drawn
    from ``default_rng([seed, utterance_key(utt_id), c])``: first its VTLP warp α ~ U(vtlp_range)
    (the mel filterbank of its features), then, when ``settings.copies`` > 0, its audio
    (:func:`mapping.augment.augment`; babble from other training utterances, preferably of
    other speakers); its features read its utterance's band (``mel_fmax_hz``). A tempo change
    re-times the copy's MUPs (linear interpolation), phone labels and mask (nearest frame), so
    features and targets stay aligned. With
    ``recognise_context`` the recogniser hears each copy's audio too (the phone-input MLPs read
    it); otherwise a copy carries no recognised phones. Utterances without training frames
    (test utterances) are never copied.
    """
    n_copies = copies_per_utterance(settings, vtlp_range)
    train = [i for i, m in enumerate(masks) if np.any(m)]
    if n_copies == 0 or not train:
        return [], []
    for i in train:
        if data[i].audio is None or data[i].sample_rate <= 0:
            raise ParameterError(f"utterance {data[i].utt_id} has no audio to augment; build "
                                 "the data with mapping.dataset.build_dataset")
    out, out_masks = [], []
    for i in train:
        d = data[i]
        others = [data[j].audio for j in train if j != i
                  and data[j].sample_rate == d.sample_rate and data[j].speaker != d.speaker]
        others = others or [data[j].audio for j in train
                            if j != i and data[j].sample_rate == d.sample_rate]
        rirs = (rir_bank(d.sample_rate, seed, tuple(settings.rt60_range))
                if settings.copies and settings.reverb_prob > 0 else None)
        for c in range(n_copies):
            rng = np.random.default_rng([seed, utterance_key(d.utt_id), c])
            alpha = float(rng.uniform(*vtlp_range))
            y, scale = d.audio, 1.0
            if settings.copies:
                y, scale, _ = augment(d.audio, sr=d.sample_rate, settings=settings, rng=rng,
                                      others=others, rirs=rirs)
            n = (d.n_frames if scale == 1.0
                 else int(np.ceil(len(y) / hop_samples(d.sample_rate, d.fps))))
            feats = audio_features(y, sr=d.sample_rate, fps=d.fps, n_mfcc=n_mfcc, deltas=deltas,
                                   n_frames=n, vtlp_alpha=alpha, align=window_align,
                                   mel_fmax_hz=d.mel_fmax_hz)
            if scale == 1.0:
                mups, phones, mask = d.mups, d.phones, np.asarray(masks[i])
            else:
                mups = retime_targets(d.mups, scale, n)
                phones = retime_labels(d.phones, scale, n)
                mask = retime_labels(np.asarray(masks[i]), scale, n)
            heard = (None if recognise_context is None else
                     recognised_windows(y, d.sample_rate, d.fps, recognise_context, n))
            out.append(replace(d, utt_id=f"{d.utt_id}+copy{c}", features=feats, mups=mups,
                               phones=phones, audio=None,  # features suffice: no copy kept
                               recognised=heard))
            out_masks.append(mask)
    return out, out_masks


def split_masks(data: list[UttData], split: str, *, train_fraction: float = 0.8,
                seed: int = 0) -> list[np.ndarray]:
    """Per utterance, the boolean mask of its training frames (the rest are test frames)."""
    if split not in SPLITS:
        raise ParameterError(f"unknown split {split!r}; allowed: {', '.join(SPLITS)}")
    if not 0 < train_fraction < 1:
        raise ParameterError(f"train_fraction must be in (0, 1), got {train_fraction}")
    rng = np.random.default_rng(seed)
    lengths = [d.n_frames for d in data]
    if split == "random_frames":
        total = sum(lengths)
        n_train = int(round(train_fraction * total))
        if not 0 < n_train < total:
            raise ParameterError(f"{total} frames cannot be split {train_fraction:.0%} / rest")
        flat = np.zeros(total, bool)
        flat[rng.permutation(total)[:n_train]] = True
        return np.split(flat, np.cumsum(lengths)[:-1])
    train_texts = training_sentences([d.text for d in data], train_fraction=train_fraction,
                                     seed=seed)
    return [np.full(d.n_frames, d.text in train_texts) for d in data]


def training_sentences(texts, *, train_fraction: float = 0.8, seed: int = 0) -> frozenset:
    """The training sentence texts of the ``utterance`` split: ``train_fraction`` of the
    distinct ``texts`` (sorted), drawn by ``default_rng(seed).permutation`` — a pure function
    of the texts and the seed, so the held-out sentences are known before anything is fitted
    (:func:`held_out_utterances`; the run draws with ``seed + SPLIT_SEED_OFFSET``).

    Raises
    ------
    ParameterError
        ``train_fraction`` outside (0, 1), or too few distinct sentences for both sides.
    """
    if not 0 < train_fraction < 1:
        raise ParameterError(f"train_fraction must be in (0, 1), got {train_fraction}")
    texts = sorted(set(texts))
    n_train = int(round(train_fraction * len(texts)))
    if not 0 < n_train < len(texts):
        raise ParameterError(f"{len(texts)} distinct sentences cannot be split "
                             f"{train_fraction:.0%} / rest by sentence; need at least 2 on each "
                             "side's scale (use more sentences or the random_frames split)")
    rng = np.random.default_rng(seed)
    return frozenset(np.array(texts)[rng.permutation(len(texts))[:n_train]].tolist())


def held_out_utterances(utterances, *, train_fraction: float = 0.8, seed: int = 0) -> list:
    """The ids of the ``utterance`` split's test utterances, in the given order, of items with
    ``utt_id`` and ``text`` (corpus utterances or :class:`UttData`): those whose sentence is not
    among :func:`training_sentences`."""
    utterances = list(utterances)
    train = training_sentences([u.text for u in utterances], train_fraction=train_fraction,
                               seed=seed)
    return [u.utt_id for u in utterances if u.text not in train]
