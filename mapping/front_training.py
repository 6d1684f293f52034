"""Teaching the causal phone front end (:mod:`mapping.causal_front`) from hama (issue 40).

Teacher. hama (:mod:`mapping.hama_front`) decodes each training utterance *whole* (every phone
sees all the audio: its strongest reading, one decode per clip). Its posteriors are CTC spikes
among blanks, so a frame-wise copy of them would teach "blank"; the target of a 10-ms step is
instead read with hama's own timing rule (:func:`teacher_rows`): the step's instant s · 10 ms
reads output frame ⌊50 · s / 100⌋ + SPIKE_LAG (the edge rule past the decode's end, as
:func:`mapping.hama_front.read_frame`); the spike that :func:`mapping.hama_front.output_classes`
gives that frame (BOUNDARY between two spikes, REACH on each side; :func:`mapping.hama_front.assigned_spikes`) is
the one read, and the target row is that spike frame's posterior mass summed per phone class
over the tokens that map to a class, renormalised; a step no spike reaches is silence (one-hot
``sil``), so the student learns hama's silence rule too. :class:`Teacher` is the job of
:mod:`mapping.hearing` that keeps a recording's targets in the content-keyed cache (kind
:data:`mapping.recogniser.HEARD_KIND`), so a corpus is taught once on every core.

Student (:func:`train_front`). Log-mel features by :func:`mapping.front_net.log_mel` (the
stream's arithmetic), normalised by the training utterances' mean and std; the net of
:mod:`mapping.causal_front` in PyTorch, head l at step s trained towards the target of step
s − l (silence before the audio): loss per head = KL(target ‖ student) + ``label_weight`` ·
cross-entropy with the true phone where the corpus has one (−1: none), averaged over steps and
heads. Adam on minibatches of segments (utterances cut at a seeded offset every epoch into
``segment_s`` pieces, each started from a zero state), every random choice from ``seed``;
``holdout_fraction`` of the training utterances (a seeded split) are held out, the weights of
the epoch with the lowest held-out loss are kept, and training stops after ``patience`` epochs
without a better one (0: runs every epoch). One torch thread by default; a bar of the epochs
with the losses on stderr.
"""
from __future__ import annotations

import sys
from dataclasses import asdict, dataclass, field

import numpy as np
import soxr
from tqdm import tqdm

from face_model.phones import PHONES
from groundwork.cache import content_key
from groundwork.errors import ParameterError
from mapping import front_net, hama_front
from mapping.config import FrontSettings
from mapping.recogniser import audio_digest, heard_entry

N_CLASSES = len(PHONES)
SILENCE = front_net.SILENCE
TEACHER_VERSION = 1  # bump when the targets of the same audio change


# -- the teacher -----------------------------------------------------------------------------------

def class_mass(log_probs: np.ndarray, classes: np.ndarray) -> np.ndarray:
    """Posterior mass per phone class (n, 44) float64 of log posteriors (n, n_tokens): each
    row's probabilities summed over the tokens of each class (``classes``, −1: none),
    renormalised to sum to 1."""
    p = np.exp(np.asarray(log_probs, np.float64))
    mapped = np.nonzero(classes >= 0)[0]
    out = np.zeros((len(p), N_CLASSES))
    np.add.at(out.T, classes[mapped], p[:, mapped].T)
    return out / out.sum(axis=1, keepdims=True)


def teacher_rows(log_probs: np.ndarray | None, pad: int, n: int, classes: np.ndarray,
                 blank: int, timing: hama_front.Timing | None = None) -> np.ndarray:
    """The targets (n, 44) float32 of n steps from whole-utterance log posteriors
    (:func:`mapping.hama_front.whole_posteriors`: ``pad`` rows of silence first) — see the
    module docstring; every row sums to 1."""
    timing = hama_front.Timing() if timing is None else timing
    out = np.zeros((n, N_CLASSES), np.float32)
    out[:, SILENCE] = 1.0
    if log_probs is None or len(log_probs) <= pad:
        return out
    spike = hama_front.assigned_spikes(log_probs, classes, blank, reach=timing.reach,
                            boundary=timing.boundary)[pad:]
    n_out = len(spike)
    g0 = np.arange(n) * hama_front.OUTPUT_FPS // front_net.STEPS_PER_S
    g = g0 + timing.lag
    frame = np.where(g < n_out, g, np.where(timing.edge & (g0 < n_out), n_out - 1, -1))
    read = np.where(frame >= 0, spike[np.maximum(frame, 0)], -1)
    hit = np.nonzero(read >= 0)[0]
    if len(hit):
        rows = np.unique(read[hit])
        mass = class_mass(log_probs[rows], classes)  # spikes index the padded rows
        out[hit] = mass[np.searchsorted(rows, read[hit])]
    return out


def teacher_targets(y16: np.ndarray, n_steps: int | None = None) -> np.ndarray:
    """hama's targets (n_steps, 44) float32 of a 16 kHz utterance decoded whole (default
    ``n_steps``: :func:`mapping.front_net.n_steps` of its length)."""
    y16 = np.asarray(y16, np.float32)
    n = front_net.n_steps(len(y16)) if n_steps is None else int(n_steps)
    _, classes, blank = hama_front.model()
    return teacher_rows(*hama_front.whole_posteriors(y16), n, classes, blank)


@dataclass(frozen=True, eq=False)
class Teacher:
    """One 16 kHz recording ``y`` for :func:`mapping.hearing.hear_all`: its hama targets per
    step, ``{"targets": (n_steps, 44) float16}``."""

    y: np.ndarray = field(repr=False)
    names = ("targets",)

    @property
    def seconds(self) -> float:
        return len(self.y) / front_net.RATE

    def key(self) -> str:
        t = hama_front.Timing()
        return content_key("teacher", TEACHER_VERSION, hama_front.RECOGNISER_NAME,
                           audio_digest(self.y, front_net.RATE),
                           {"step_ms": 1000 // front_net.STEPS_PER_S, "lag": t.lag,
                            "reach": t.reach, "boundary": t.boundary, "edge": t.edge})

    def compute(self) -> dict:
        return {"targets": teacher_targets(self.y).astype(np.float16)}


def cached_targets(y16: np.ndarray) -> np.ndarray:
    """:func:`teacher_targets` (float32, rows renormalised) read from the active hearing cache
    (:func:`mapping.recogniser.hearing_cache`) or made into it."""
    job = Teacher(np.ascontiguousarray(y16, np.float32))
    t = heard_entry(job.key(), job.compute, job.names)["targets"].astype(np.float32)
    return t / t.sum(axis=1, keepdims=True)


def step_labels(frame_labels: np.ndarray, fps: int, n: int) -> np.ndarray:
    """Per-video-frame phone classes (n_frames,) as per-step ones (n,): step s (instant
    s · 10 ms) takes frame ⌊s · fps / 100⌋'s, −1 past the last frame."""
    frame_labels = np.asarray(frame_labels, np.int64)
    f = np.arange(n) * int(fps) // front_net.STEPS_PER_S
    return np.where(f < len(frame_labels), frame_labels[np.minimum(f, len(frame_labels) - 1)],
                    -1) if len(frame_labels) else np.full(n, -1, np.int64)


# -- the student -----------------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class FrontExample:
    """One training utterance: mono audio ``y`` at ``sample_rate`` Hz, its ``targets``
    (n_steps, 44) per step of its 16 kHz audio (:func:`teacher_targets`) and optionally the true
    phone class per step ``labels`` (n_steps,) int, −1 where unknown."""

    y: np.ndarray = field(repr=False)
    targets: np.ndarray = field(repr=False)
    labels: np.ndarray | None = field(default=None, repr=False)
    sample_rate: int = front_net.RATE


def _net(n_mels: int, hidden: int, heads: int):
    """The net of :mod:`mapping.causal_front` as a torch module (input (B, T, n_mels), output
    (B, T, heads, 44) scores)."""
    import torch
    from torch import nn
    from torch.nn import functional as F

    class CausalNet(nn.Module):
        def __init__(self):
            super().__init__()
            self.conv1 = nn.Conv1d(n_mels, hidden, front_net.K1)
            self.conv2 = nn.Conv1d(hidden, hidden, front_net.K2,
                                   dilation=front_net.DILATION2)
            self.gru = nn.GRU(hidden, hidden, batch_first=True)
            self.head = nn.Linear(hidden, N_CLASSES * heads)

        def forward(self, x: torch.Tensor) -> torch.Tensor:
            a = F.pad(x.transpose(1, 2), (front_net.CONTEXT, 0))
            a = F.pad(torch.relu(self.conv1(a)), (front_net.CONTEXT, 0))
            a = torch.relu(self.conv2(a)).transpose(1, 2)
            h, _ = self.gru(a)
            return self.head(h).reshape(x.shape[0], x.shape[1], heads, N_CLASSES)

    return CausalNet()


TORCH_NAMES = {"conv1_w": "conv1.weight", "conv1_b": "conv1.bias", "conv2_w": "conv2.weight",
               "conv2_b": "conv2.bias", "gru_w_ih": "gru.weight_ih_l0",
               "gru_w_hh": "gru.weight_hh_l0", "gru_b_ih": "gru.bias_ih_l0",
               "gru_b_hh": "gru.bias_hh_l0", "head_w": "head.weight", "head_b": "head.bias"}


def torch_net(arrays: dict, metadata: dict):
    """A torch module holding a front end's weights (:data:`mapping.front_net.WEIGHTS`)."""
    import torch
    hidden, n_mels = np.shape(arrays["conv1_w"])[:2]
    net = _net(int(n_mels), int(hidden), int(metadata["lookahead_ms"]) // 10 + 1)
    net.load_state_dict({t: torch.from_numpy(np.asarray(arrays[k], np.float32).copy())
                         for k, t in TORCH_NAMES.items()})
    return net


def _features(examples, filters: np.ndarray) -> list:
    """Per example ``(log-mel (n, n_mels), targets (n, 44), labels (n,))``, checked."""
    out = []
    for i, ex in enumerate(examples):
        y = np.asarray(ex.y, np.float32).reshape(-1)
        if int(ex.sample_rate) != front_net.RATE:
            y = soxr.resample(y, int(ex.sample_rate), front_net.RATE,
                              quality=front_net.RESAMPLE_QUALITY).astype(np.float32)
        mel = front_net.log_mel(y, filters)
        t = np.asarray(ex.targets, np.float32)
        labels = (np.full(len(mel), -1, np.int64) if ex.labels is None
                  else np.asarray(ex.labels, np.int64))
        if t.shape != (len(mel), N_CLASSES) or labels.shape != (len(mel),):
            raise ParameterError(f"training example {i}: {len(mel)} steps of audio, targets "
                                 f"{t.shape} and labels {labels.shape}; allowed: "
                                 f"({len(mel)}, {N_CLASSES}) and ({len(mel)},)")
        if not np.all(np.isfinite(t)) or np.any(t < 0) or np.any(labels >= N_CLASSES) \
                or np.any(labels < -1):
            raise ParameterError(f"training example {i}: targets must be finite and ≥ 0, "
                                 f"labels −1 or a class index 0..{N_CLASSES - 1}")
        out.append((mel, t / np.maximum(t.sum(axis=1, keepdims=True), 1e-12), labels))
    return out


def _segments(data: list, mean, std, seg: int, heads: int, rng) -> list:
    """Training pieces ``(x (T, n_mels), targets (T + L, 44), labels (T + L,))``: each
    utterance cut at a random offset into ``seg``-step pieces; targets and labels start L
    steps earlier (silence / −1 before the audio), so head l at piece step i reads row
    L + i − l."""
    L = heads - 1
    out = []
    for mel, t, labels in data:
        x = (mel - mean) / std
        tp = np.concatenate([np.eye(N_CLASSES, dtype=np.float32)[[SILENCE] * L], t])
        lp = np.concatenate([np.full(L, -1, np.int64), labels])
        off = int(rng.integers(0, seg)) if rng is not None else 0
        cuts = [0] + list(range(off or seg, len(x), seg)) + [len(x)]
        out += [(x[a:b], tp[a:b + L], lp[a:b + L]) for a, b in zip(cuts[:-1], cuts[1:])
                if b > a]
    return out


def _batch(pieces: list, heads: int):
    import torch
    L, T = heads - 1, max(len(p[0]) for p in pieces)
    B, n_mels = len(pieces), pieces[0][0].shape[1]
    x = np.zeros((B, T, n_mels), np.float32)
    t = np.zeros((B, T + L, N_CLASSES), np.float32)
    lab = np.full((B, T + L), -1, np.int64)
    mask = np.zeros((B, T), bool)
    for i, (xi, ti, li) in enumerate(pieces):
        x[i, :len(xi)], t[i, :len(ti)], lab[i, :len(li)], mask[i, :len(xi)] = xi, ti, li, True
    return (torch.from_numpy(x), torch.from_numpy(t), torch.from_numpy(lab),
            torch.from_numpy(mask))


def _loss(net, batch, heads: int, label_weight: float):
    """Mean over heads of KL(target ‖ student) + label_weight · CE(true label), each averaged
    over the valid steps; and the KL alone (for the bar)."""
    import torch
    x, t, lab, mask = batch
    logp = torch.log_softmax(net(x), dim=3)
    L, T = heads - 1, x.shape[1]
    m = mask.float()
    total, kl_sum = 0.0, 0.0
    for h in range(heads):
        th = t[:, L - h:L - h + T]
        kl = (torch.xlogy(th, th) - th * logp[:, :, h]).sum(dim=2)
        kl = (kl * m).sum() / m.sum()
        lh = lab[:, L - h:L - h + T].masked_fill(~mask, -1)
        known = lh >= 0
        ce = (-logp[:, :, h].gather(2, lh.clamp(min=0)[..., None])[..., 0] * known).sum() \
            / known.sum().clamp(min=1)
        total = total + kl + label_weight * ce
        kl_sum = kl_sum + kl.detach()
    return total / heads, float(kl_sum) / heads


def train_front(examples, settings: FrontSettings = FrontSettings(), *, seed: int,
                progress: bool = True, info: dict | None = None,
                threads: int = 1) -> tuple[dict, dict]:
    """Train the causal front end on ``examples`` (:class:`FrontExample`); see the module
    docstring.

    Parameters
    ----------
    examples : sequence of FrontExample
        The training utterances (≥ 1).
    settings : FrontSettings
    seed : int
        Every random choice: the initial weights, the held-out split, the cuts and the order.
    progress : bool
        A bar of the epochs with the losses, on stderr.
    info : dict, optional
        Added to the record, e.g. ``training_speakers``, ``corpora``.
    threads : int
        torch threads while training (restored after).

    Returns
    -------
    arrays, metadata
        For :func:`mapping.front_net.write_front`.
    """
    import torch
    examples = list(examples)
    if not examples:
        raise ParameterError("train_front needs at least one training example, got none")
    heads = settings.lookahead_ms // 10 + 1
    filters = front_net.mel_filters(settings.n_mels, settings.mel_fmax_hz)
    data = _features(examples, filters)
    rng = np.random.default_rng([int(seed), 40])
    n_hold = (int(round(settings.holdout_fraction * len(data))) if len(data) >= 2 else 0)
    n_hold = min(max(n_hold, 1 if settings.holdout_fraction > 0 and len(data) >= 2 else 0),
                 len(data) - 1)
    order = rng.permutation(len(data))
    held = [data[i] for i in sorted(order[:n_hold])]
    train = [data[i] for i in sorted(order[n_hold:])]
    stack = np.concatenate([d[0] for d in train]).astype(np.float64)
    mean = stack.mean(axis=0).astype(np.float32)
    std = np.maximum(stack.std(axis=0), 1e-3).astype(np.float32)
    seg = max(1, int(round(settings.segment_s * front_net.STEPS_PER_S)))
    held_batches = [_batch(p, heads) for p in _chunks(_segments(held, mean, std, seg, heads,
                                                                None), settings.batch)]
    before = torch.get_num_threads()
    torch.set_num_threads(int(threads))
    try:
        torch.manual_seed(int(seed))
        net = _net(settings.n_mels, settings.hidden, heads)
        opt = torch.optim.Adam(net.parameters(), lr=settings.learning_rate)
        best, best_state, best_epoch, stale, history = np.inf, None, 0, 0, []
        bar = tqdm(range(settings.epochs), desc="front end", unit="epoch", file=sys.stderr,
                   disable=not progress)
        for epoch in bar:
            pieces = _segments(train, mean, std, seg, heads, rng)
            net.train()
            losses = []
            for idx in _chunks(list(rng.permutation(len(pieces))), settings.batch):
                loss, kl = _loss(net, _batch([pieces[i] for i in idx], heads), heads,
                                 settings.label_weight)
                opt.zero_grad()
                loss.backward()
                torch.nn.utils.clip_grad_norm_(net.parameters(), 5.0)
                opt.step()
                losses.append(float(loss.detach()))
            net.eval()
            with torch.no_grad():
                held_loss = (float(np.mean([float(_loss(net, b, heads, settings.label_weight)[0])
                                            for b in held_batches])) if held_batches else None)
            history.append({"epoch": epoch + 1, "train_loss": float(np.mean(losses)),
                            "heldout_loss": held_loss})
            bar.set_postfix_str(f"loss {np.mean(losses):.3f}"
                                + (f", held out {held_loss:.3f}" if held_batches else ""))
            if held_loss is None or held_loss < best:
                best = np.inf if held_loss is None else held_loss
                best_state = {k: v.detach().clone() for k, v in net.state_dict().items()}
                best_epoch, stale = epoch + 1, 0
            else:
                stale += 1
                if settings.patience and stale >= settings.patience:
                    break
        bar.close()
        net.load_state_dict(best_state)
    finally:
        torch.set_num_threads(before)
    state = net.state_dict()
    arrays = {"mel_filters": filters, "mel_mean": mean, "mel_std": std,
              **{k: state[t].detach().numpy().astype(np.float32).copy()
                 for k, t in TORCH_NAMES.items()}}
    metadata = {"n_mels": settings.n_mels, "hidden": settings.hidden,
                "lookahead_ms": settings.lookahead_ms, "mel_fmax_hz": settings.mel_fmax_hz,
                "settings": asdict(settings), "seed": int(seed), "trained": True,
                "teacher": hama_front.RECOGNISER_NAME, "teacher_version": TEACHER_VERSION,
                "training_speakers": [], "corpora": [],
                "utterances": {"train": len(train), "heldout": len(held)},
                "train_minutes": float(sum(len(d[0]) for d in train)
                                       / front_net.STEPS_PER_S / 60),
                "best_epoch": best_epoch, "history": history, **(info or {})}
    return arrays, metadata


def _chunks(items: list, size: int) -> list:
    return [items[i:i + size] for i in range(0, len(items), size)]
