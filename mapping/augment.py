"""Training-time audio augmentation of the mapping (issue 12): noise, babble, reverberation,
telephone band, gain and clipping, tempo and pitch.

Pure functions on mono float audio ``y`` at ``sr`` Hz. Every random choice comes from an explicit
``numpy.random.Generator``; nothing touches global random state, so a copy drawn from
``default_rng([seed, utterance, copy])`` is the same in any process and any order.

Every function keeps ``len(y)`` and the sample rate, except :func:`tempo`, which changes the
duration on purpose and returns the time scale ``len(out) / len(y)``; per-frame targets and
labels follow with :func:`retime_targets` and :func:`retime_labels`.

Only numpy, scipy and librosa (already required): the maintained augmentation packages either
cannot be installed beside the pinned soxr (audiomentations) or need torchaudio, and the room
simulator of pyroomacoustics is slower than the image method below and not reproducible with
ray tracing. The research notes behind these choices are summarised in issue 12.
"""
from __future__ import annotations

import functools
import math

import librosa
import numpy as np
import scipy.signal as sps

from groundwork.audio import seconds_to_samples
from groundwork.errors import ParameterError
from mapping.config import AugmentSettings

NOISE_BETA = {"white": 0.0, "pink": 1.0, "brown": 2.0}  # power spectrum ∝ 1 / f^β
TELEPHONE_BAND_HZ = (300.0, 3400.0)
SPEED_OF_SOUND = 343.0  # m/s
RIR_BANK_SIZE = 16
STAGES = ("tempo", "pitch", "reverb", "noise", "babble", "telephone", "gain", "clip")


def _power(y: np.ndarray) -> float:
    return float(np.mean(np.square(y, dtype=np.float64)))


def _audio(y) -> np.ndarray:
    y = np.asarray(y)
    if y.ndim != 1 or len(y) == 0:
        raise ParameterError(f"audio must be mono and non-empty, shape (n_samples,), got "
                             f"{y.shape}")
    return y


# -- noise ----------------------------------------------------------------------------------
def mix_at_snr(y: np.ndarray, noise: np.ndarray, snr_db: float) -> np.ndarray:
    """``y + g·noise`` with g such that 10·log10(P_y / P_{g·noise}) = ``snr_db`` (powers over
    the whole signal). Silent input (or noise) returns ``y`` unchanged.

    Parameters
    ----------
    y : ndarray, shape (n_samples,)
    noise : ndarray, shape (n_samples,)
    snr_db : float
        Signal-to-noise ratio, in dB.

    Returns
    -------
    ndarray, shape (n_samples,), ``y``'s dtype
    """
    y = _audio(y)
    if len(noise) != len(y):
        raise ParameterError(f"noise has {len(noise)} samples, the signal {len(y)}")
    py, pn = _power(y), _power(noise)
    if py == 0.0 or pn == 0.0:
        return y.copy()
    g = math.sqrt(py / (pn * 10.0 ** (snr_db / 10.0)))
    return (y + g * noise).astype(y.dtype, copy=False)


def coloured_noise(n: int, rng: np.random.Generator, *, beta: float = 0.0) -> np.ndarray:
    """Gaussian noise of unit variance with power spectrum ∝ 1/f^β (0 white, 1 pink, 2 brown)."""
    w = rng.standard_normal(n)
    if beta == 0.0 or n < 2:
        return w
    spec = np.fft.rfft(w)
    f = np.fft.rfftfreq(n)
    f[0] = f[1]
    spec *= f ** (-beta / 2.0)
    out = np.fft.irfft(spec, n)
    return out / (np.std(out) + 1e-12)


def fit_length(x: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """A random ``n``-sample crop of ``x``, or ``x`` looped from a random offset."""
    if len(x) >= n:
        start = int(rng.integers(0, len(x) - n + 1))
        return x[start:start + n]
    start = int(rng.integers(0, len(x)))
    return np.tile(x, math.ceil(n / len(x)) + 1)[start:start + n]


def babble(others: list, n: int, rng: np.random.Generator, *, n_talkers: int = 4
           ) -> np.ndarray:
    """The sum of ``n_talkers`` utterances drawn from ``others``, each cropped or looped to
    ``n`` samples at a random offset and scaled to unit RMS.

    Parameters
    ----------
    others : list of ndarray, each (n_samples_i,)
        Audio of other utterances, at the rate of the signal it is mixed into.
    n : int
        Samples of the result.
    rng : numpy.random.Generator
    n_talkers : int

    Returns
    -------
    ndarray, shape (n,), float64
    """
    if not others:
        raise ParameterError("babble needs the audio of other utterances")
    idx = rng.choice(len(others), size=n_talkers, replace=len(others) < n_talkers)
    out = np.zeros(n)
    for i in idx:
        seg = fit_length(np.asarray(others[i], dtype=np.float64), n, rng)
        out += seg / (math.sqrt(_power(seg)) + 1e-12)
    return out


# -- reverberation --------------------------------------------------------------------------
def image_method_rir(room, source, mic, *, rt60: float, sr: int, half_taps: int = 16,
                     early_s: float = 0.05) -> np.ndarray:
    """Room impulse response of a shoebox room by the image method (Allen & Berkley 1979).

    Parameters
    ----------
    room : (3,) room size in metres; source, mic : (3,) positions in metres.
    rt60 : float
        Reverberation time (s): one wall absorption for all six walls from Sabine's formula,
        pressure reflection coefficient sqrt(1 − absorption); images up to c·rt60 metres.
    sr : int
        Sample rate (Hz).

    Returns
    -------
    ndarray (round(rt60·sr),): the direct path at its true delay. Images of the first
    ``early_s`` seconds are placed with a Hann-windowed sinc (2·half_taps taps), the dense tail
    by linear interpolation. Deterministic.
    """
    size, s, m = (np.asarray(v, dtype=np.float64) for v in (room, source, mic))
    volume = float(np.prod(size))
    surface = 2.0 * (size[0] * size[1] + size[0] * size[2] + size[1] * size[2])
    absorption = 0.161 * volume / (surface * rt60)  # Sabine
    if not 0.0 < absorption < 1.0:
        raise ParameterError(f"rt60 {rt60} s is impossible in a {size.tolist()} m room by "
                             f"Sabine's formula (absorption {absorption:.2f})")
    beta = math.sqrt(1.0 - absorption)
    n_out = seconds_to_samples(rt60, sr)
    dmax = SPEED_OF_SOUND * n_out / sr

    def axis(k):
        n_img = int(math.ceil(dmax / (2 * size[k]))) + 1
        j = np.arange(-n_img, n_img + 1)
        pos = np.concatenate([s[k] + 2 * j * size[k], -s[k] + 2 * j * size[k]])
        hits = np.concatenate([np.abs(2 * j), np.abs(2 * j - 1)])  # wall reflections
        return pos - m[k], hits

    (dx, hx), (dy, hy), (dz, hz) = axis(0), axis(1), axis(2)
    d2 = dx[:, None, None] ** 2 + dy[None, :, None] ** 2 + dz[None, None, :] ** 2
    hits = hx[:, None, None] + hy[None, :, None] + hz[None, None, :]
    keep = d2 < dmax ** 2
    d = np.sqrt(d2[keep])
    amp = beta ** hits[keep] / (4 * np.pi * d)
    delay = d / SPEED_OF_SOUND * sr
    base = np.floor(delay).astype(np.int64)
    frac = delay - base
    h = np.zeros(n_out)
    early = delay < early_s * sr
    taps = np.arange(-half_taps + 1, half_taps + 1)
    t = taps[None, :] - frac[early][:, None]
    kern = np.sinc(t) * 0.5 * (1 + np.cos(np.pi * t / (half_taps + 1))) * amp[early][:, None]
    where = base[early][:, None] + taps[None, :]
    ok = (where >= 0) & (where < n_out)
    h += np.bincount(where[ok], weights=kern[ok], minlength=n_out)
    late = ~early
    for off, weight in ((0, 1.0 - frac[late]), (1, frac[late])):
        idx = base[late] + off
        ok = idx < n_out
        h += np.bincount(idx[ok], weights=(amp[late] * weight)[ok], minlength=n_out)
    return h


def random_room_rir(rng: np.random.Generator, *, sr: int, rt60_range=(0.2, 0.6)) -> np.ndarray:
    """A random room (3–8 × 3–6 × 2.4–3.5 m), source, microphone and RT60 ~ U(rt60_range)
    (seconds), by :func:`image_method_rir` at ``sr`` Hz; shape (round(rt60·sr),)."""
    for _ in range(1000):
        room = rng.uniform([3.0, 3.0, 2.4], [8.0, 6.0, 3.5])
        rt60 = float(rng.uniform(*rt60_range))
        source, mic = rng.uniform(0.5, room - 0.5), rng.uniform(0.5, room - 0.5)
        try:
            return image_method_rir(room, source, mic, rt60=rt60, sr=sr)
        except ParameterError:  # too short an RT60 for this room: draw again
            continue
    raise ParameterError(f"no room has an RT60 in {list(rt60_range)} s")


@functools.lru_cache(maxsize=4)
def rir_bank(sr: int, seed: int, rt60_range: tuple = (0.2, 0.6), size: int = RIR_BANK_SIZE
             ) -> tuple:
    """``size`` random room responses drawn from ``seed`` (cached: a long RT60 costs ~0.1 s)."""
    rng = np.random.default_rng([seed, sr])
    return tuple(random_room_rir(rng, sr=sr, rt60_range=tuple(rt60_range)) for _ in range(size))


def reverberate(y: np.ndarray, rir: np.ndarray) -> np.ndarray:
    """``y`` convolved with ``rir``, same length and RMS, and not delayed against its frame
    labels: the direct-path peak of the response lands on time zero (the 16 samples of sinc
    pre-ringing before it are kept, so the output starts with them)."""
    y = _audio(y)
    h = np.asarray(rir, dtype=np.float64)
    peak = int(np.argmax(np.abs(h)))
    start = max(peak - 16, 0)
    lead = peak - start
    out = sps.fftconvolve(y.astype(np.float64), h[start:])[lead:lead + len(y)]
    out *= math.sqrt(_power(y) / (_power(out) + 1e-20))
    return out.astype(y.dtype, copy=False)


# -- channel --------------------------------------------------------------------------------
def telephone_band(y: np.ndarray, *, sr: int, band_hz=TELEPHONE_BAND_HZ, order: int = 4
                   ) -> np.ndarray:
    """Band-pass (Butterworth, ``band_hz``), zero phase (``sosfiltfilt``: no delay, same length)."""
    y = _audio(y)
    sos = sps.butter(order, list(band_hz), btype="bandpass", fs=sr, output="sos")
    return sps.sosfiltfilt(sos, y).astype(y.dtype, copy=False)


def gain_clip(y: np.ndarray, gain_db: float, *, level: float = 1.0) -> np.ndarray:
    """Gain in dB, then hard clipping at ±``level`` (full scale)."""
    y = _audio(y)
    return np.clip(y * 10.0 ** (gain_db / 20.0), -level, level).astype(y.dtype, copy=False)


def clip_fraction(y: np.ndarray, fraction: float) -> np.ndarray:
    """Hard clipping at the level that about ``fraction`` of the samples exceed."""
    y = _audio(y)
    level = float(np.quantile(np.abs(y), 1.0 - fraction))
    return np.clip(y, -level, level) if level > 0 else y.copy()


# -- tempo and pitch ------------------------------------------------------------------------
def tempo(y: np.ndarray, rate: float) -> tuple[np.ndarray, float]:
    """Tempo × ``rate`` with the pitch kept (librosa phase vocoder; > 1 is faster).

    Returns ``(out, time_scale)`` with ``time_scale = len(out) / len(y)`` (≈ 1 / rate), the
    factor that maps a time in ``y`` to the same sound in ``out``.
    """
    y = _audio(y)
    out = librosa.effects.time_stretch(y, rate=rate)
    return out.astype(y.dtype, copy=False), len(out) / len(y)


def pitch_shift(y: np.ndarray, *, sr: int, semitones: float) -> np.ndarray:
    """F0 and the spectral envelope shifted by ``semitones`` (librosa), same length."""
    y = _audio(y)
    out = librosa.effects.pitch_shift(y, sr=sr, n_steps=semitones, res_type="soxr_hq")
    return out.astype(y.dtype, copy=False)


def retime_targets(targets: np.ndarray, time_scale: float, n_frames: int) -> np.ndarray:
    """Per-frame targets (n, d) after a tempo change: output frame k shows input frame
    k / time_scale, linearly interpolated (ends held). Shape (n_frames, d), input dtype."""
    targets = np.asarray(targets)
    pos = np.arange(n_frames) / time_scale
    grid = np.arange(len(targets))
    out = np.stack([np.interp(pos, grid, targets[:, j].astype(np.float64))
                    for j in range(targets.shape[1])], axis=1)
    return out.astype(targets.dtype)


def retime_labels(labels: np.ndarray, time_scale: float, n_frames: int) -> np.ndarray:
    """Per-frame labels (n,) after a tempo change: output frame k takes the label of the input
    frame nearest to k / time_scale. Shape (n_frames,)."""
    labels = np.asarray(labels)
    src = np.clip(np.rint(np.arange(n_frames) / time_scale).astype(np.int64), 0, len(labels) - 1)
    return labels[src]


# -- the pipeline ---------------------------------------------------------------------------
def augment(y: np.ndarray, *, sr: int, settings: AugmentSettings, rng: np.random.Generator,
            others: list | None = None, rirs: tuple | None = None
            ) -> tuple[np.ndarray, float, dict]:
    """One augmented copy of ``y``: the stages of :data:`STAGES` in that order, each firing
    with its probability in ``settings``.

    All decisions and one sub-generator per stage are drawn first, in a fixed order, so whether
    one stage fires never shifts another stage's random numbers.

    Parameters
    ----------
    y : ndarray, shape (n_samples,)
        Mono audio.
    sr : int
        Sample rate, in Hz.
    settings : AugmentSettings
        Each stage's probability and ranges (dB, semitones, seconds of RT60 …).
    rng : numpy.random.Generator
        The copy's generator (e.g. ``default_rng([seed, utterance, copy])``).
    others : list of ndarray, optional
        Audio of other training utterances for babble (no babble without them).
    rirs : tuple of ndarray, optional
        Room responses to pick from (default: drawn fresh from the stage's generator).

    Returns
    -------
    out : ndarray, shape (n_out,), float32
        The augmented audio (``n_out`` differs from ``n_samples`` only after a tempo change).
    time_scale : float
        ``n_out / n_samples``, for :func:`retime_targets` and :func:`retime_labels`.
    params : dict
        What was applied (for logs and tests).
    """
    y = _audio(y)
    s = settings
    probs = [s.tempo_prob, s.pitch_prob, s.reverb_prob, s.noise_prob, s.babble_prob,
             s.telephone_prob, s.gain_prob, s.clip_prob]
    fires = dict(zip(STAGES, rng.random(len(STAGES)) < np.array(probs)))
    sub = dict(zip(STAGES, (np.random.default_rng(int(k))
                            for k in rng.integers(0, 2**63, size=len(STAGES)))))
    out, scale, params = y.astype(np.float32), 1.0, {}
    if fires["tempo"]:
        rate = float(sub["tempo"].uniform(*s.tempo_range))
        out, scale = tempo(out, rate)
        params["tempo_rate"] = rate
    if fires["pitch"]:
        steps = float(sub["pitch"].uniform(*s.pitch_semitones))
        out = pitch_shift(out, sr=sr, semitones=steps)
        params["pitch_semitones"] = steps
    if fires["reverb"]:
        g = sub["reverb"]
        rir = (rirs[int(g.integers(len(rirs)))] if rirs
               else random_room_rir(g, sr=sr, rt60_range=s.rt60_range))
        out = reverberate(out, rir)
        params["reverb"] = True
    if fires["noise"]:  # after reverberation: sensor noise is not reverberated
        g = sub["noise"]
        colour = str(g.choice(s.noise_colours))
        snr = float(g.choice(s.snr_db))
        out = mix_at_snr(out, coloured_noise(len(out), g, beta=NOISE_BETA[colour]), snr)
        params["noise"] = (colour, snr)
    if fires["babble"] and others:
        g = sub["babble"]
        snr = float(g.choice(s.babble_snr_db))
        out = mix_at_snr(out, babble(others, len(out), g, n_talkers=s.babble_talkers), snr)
        params["babble_snr_db"] = snr
    if fires["telephone"]:
        out = telephone_band(out, sr=sr)
        params["telephone"] = True
    if fires["gain"]:
        gain = float(sub["gain"].uniform(*s.gain_db))
        out = gain_clip(out, gain)
        params["gain_db"] = gain
    if fires["clip"]:  # last: clipping after gain and noise, as a saturated input stage does
        out = clip_fraction(out, s.clip_fraction)
        params["clip_fraction"] = s.clip_fraction
    return out.astype(np.float32, copy=False), scale, params
