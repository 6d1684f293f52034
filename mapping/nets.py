"""Small torch networks and the one training loop every network of the mapping uses.

Every network is a regressor from audio features to MUPs, trained on CPU with Adam on the
mean squared error of standardised targets, with early stopping on a validation part of the
training frames (the weights of the best validation epoch are kept).

Frame models take ``(n_frames, n_in)`` and return ``(n_frames, n_out)``. Sequence models take
``(n_utt, T, n_in)`` and return ``(n_utt, T, n_out)``; they are trained on padded batches with a
mask, so a split that draws single frames (the paper's ``random_frames``) still trains them on
whole utterances while only the training frames count in the loss.
"""
from __future__ import annotations

import copy
import time
from contextlib import contextmanager

import numpy as np
import torch
from torch import nn

from groundwork.errors import NotFittedError, ParameterError
from mapping.batched import fit_mlps
from mapping.config import TrainSettings
from mapping.state import ArrayGroup, settings_from_params, settings_to_params


class MLP(nn.Module):
    """The paper's three-layer perceptron: input, one tanh hidden layer, linear output."""

    def __init__(self, n_in: int, n_hidden: int, n_out: int):
        super().__init__()
        self.arguments = {"n_in": n_in, "n_hidden": n_hidden, "n_out": n_out}
        self.net = nn.Sequential(nn.Linear(n_in, n_hidden), nn.Tanh(), nn.Linear(n_hidden, n_out))

    def forward(self, x):
        return self.net(x)


class TDNN(nn.Module):
    """Time-delay network (Lavagetto [49], Curinga et al. [50]): stacked 1-D convolutions over
    frames, each layer seeing ``±width`` frames of the layer below (centred, so the look-ahead
    is ``layers · width`` frames)."""

    def __init__(self, n_in: int, n_hidden: int, n_out: int, *, layers: int = 2, width: int = 2):
        super().__init__()
        self.arguments = {"n_in": n_in, "n_hidden": n_hidden, "n_out": n_out, "layers": layers,
                          "width": width}
        mods, c = [], n_in
        for _ in range(layers):
            mods += [nn.Conv1d(c, n_hidden, 2 * width + 1, padding=width, padding_mode="replicate"),
                     nn.Tanh()]
            c = n_hidden
        self.body = nn.Sequential(*mods)
        self.out = nn.Conv1d(c, n_out, 1)

    def forward(self, x):  # (B, T, n_in) → (B, T, n_out)
        return self.out(self.body(x.transpose(1, 2))).transpose(1, 2)


class GRUNet(nn.Module):
    """A small unidirectional GRU over context-stacked frames (its look-ahead is the stacked
    forward context, so it stays usable in real time)."""

    def __init__(self, n_in: int, n_hidden: int, n_out: int):
        super().__init__()
        self.arguments = {"n_in": n_in, "n_hidden": n_hidden, "n_out": n_out}
        self.gru = nn.GRU(n_in, n_hidden, batch_first=True)
        self.out = nn.Linear(n_hidden, n_out)

    def forward(self, x):
        return self.out(self.gru(x)[0])


# The networks a saved model may name (its ``module``), each rebuilt from its ``arguments``.
NETWORKS = {"MLP": MLP, "TDNN": TDNN, "GRUNet": GRUNet}


def _check_xy(X, Y, mask):
    X = np.asarray(X, dtype=np.float32)
    Y = np.asarray(Y, dtype=np.float32)
    if X.shape[:-1] != Y.shape[:-1]:
        raise ParameterError(f"features and MUPs must have the same frames, got features "
                             f"{X.shape} and MUPs {Y.shape}")
    if not np.all(np.isfinite(X)):
        raise ParameterError("features hold NaN or inf values")
    if not np.all(np.isfinite(Y)):
        raise ParameterError("MUPs hold NaN or inf values")
    mask = np.ones(X.shape[:-1], bool) if mask is None else np.asarray(mask, bool)
    if mask.shape != X.shape[:-1]:
        raise ParameterError(f"mask must have shape {X.shape[:-1]}, got {mask.shape}")
    if mask.sum() < 2:
        raise ParameterError(f"a network needs at least 2 training frames, got {int(mask.sum())}")
    return X, Y, mask


def _safe_std(a: np.ndarray) -> np.ndarray:
    s = a.std(0)
    return np.where(s > 1e-8, s, 1.0).astype(np.float32)


class NetRegressor:
    """A torch module trained by :func:`fit_module` on standardised inputs and targets (means
    and standard deviations of the training frames).

    Parameters
    ----------
    module : nn.Module
        Untrained network (frame or sequence model).
    settings : TrainSettings
    seed : int
        Seeds the weights, the validation draw and the batch order.
    """

    def __init__(self, module: nn.Module, settings: TrainSettings = TrainSettings(), seed: int = 0):
        self.module = module
        self.settings = settings
        self.seed = seed

    def fit(self, X, Y, mask=None) -> "NetRegressor":
        X, Y, mask = self._standardise(X, Y, mask)
        self.history_ = fit_module(self.module, X, Y, mask, self.settings, self.seed)
        return self

    def _standardise(self, X, Y, mask):
        """Check the data, keep the training frames' means and SDs; the standardised data."""
        X, Y, mask = _check_xy(X, Y, mask)
        x, y = X[mask], Y[mask]
        self.x_mean_, self.x_std_ = x.mean(0), _safe_std(x)
        self.y_mean_, self.y_std_ = y.mean(0), _safe_std(y)
        self._np_weights = None
        return (X - self.x_mean_) / self.x_std_, (Y - self.y_mean_) / self.y_std_, mask

    def predict(self, X) -> np.ndarray:
        if not hasattr(self, "y_mean_"):
            raise NotFittedError("the network is not trained yet: call fit() first")
        X = np.asarray(X, dtype=np.float32)
        if not np.all(np.isfinite(X)):
            raise ParameterError("features hold NaN or inf values")
        if isinstance(self.module, MLP):  # the real-time path: two small matrix products
            # float64: a row alone and a block of rows then agree far below float32 precision
            w1, b1, w2, b2 = self._mlp_weights()
            h = np.tanh(((X.astype(np.float64) - self.x_mean_) / self.x_std_) @ w1 + b1)
            return ((h @ w2 + b2) * self.y_std_ + self.y_mean_).astype(np.float32)
        self.module.eval()
        with torch.no_grad():
            out = self.module(torch.from_numpy((X - self.x_mean_) / self.x_std_)).numpy()
        return out * self.y_std_ + self.y_mean_

    def _mlp_weights(self):
        if getattr(self, "_np_weights", None) is None:
            first, last = self.module.net[0], self.module.net[2]
            self._np_weights = tuple(t.detach().numpy().astype(np.float64) for t in (
                first.weight.T, first.bias, last.weight.T, last.bias))
        return self._np_weights

    # -- persistence (see mapping.state) -----------------------------------------------------
    def to_arrays(self) -> tuple[dict, dict]:
        """The network as data: the standardisation (``x_mean``, ``x_std`` (n_in,), ``y_mean``,
        ``y_std`` (n_out,)) and every tensor of the module's ``state_dict`` as ``state/<key>``;
        parameters: the module's class and constructor ``arguments``, the training settings,
        the seed and the training history."""
        if not hasattr(self, "y_mean_"):
            raise NotFittedError("the network is not trained yet: call fit() first")
        kind = type(self.module).__name__
        if NETWORKS.get(kind) is not type(self.module):
            raise ParameterError(f"network {kind} cannot be saved; savable: "
                                 f"{', '.join(NETWORKS)}")
        arrays = {"x_mean": self.x_mean_, "x_std": self.x_std_, "y_mean": self.y_mean_,
                  "y_std": self.y_std_}
        for key, t in self.module.state_dict().items():
            arrays[f"state/{key}"] = t.detach().cpu().numpy().copy()
        params = {"module": kind, "arguments": dict(self.module.arguments),
                  "settings": settings_to_params(self.settings), "seed": self.seed,
                  "history": dict(getattr(self, "history_", {}))}
        return arrays, params

    @classmethod
    def from_arrays(cls, arrays, params: dict) -> "NetRegressor":
        """The trained network of :meth:`to_arrays`: the module is rebuilt from its class and
        arguments and given the stored tensors (``load_state_dict``)."""
        g = ArrayGroup.of(arrays)
        kind = params["module"]
        if kind not in NETWORKS:
            raise ParameterError(f"unknown network {kind!r}; allowed: {', '.join(NETWORKS)}")
        args = params["arguments"]
        if not isinstance(args, dict) or not all(
                isinstance(v, int) and not isinstance(v, bool) and v > 0 for v in args.values()):
            raise ParameterError(f"the arguments of network {kind} must be positive integers, "
                                 f"got {args!r}")
        with torch.device("meta"):  # the tensors' shapes, without allocating them
            expected = NETWORKS[kind](**args).state_dict()
        state = {key: torch.from_numpy(g.take(f"state/{key}", tuple(t.shape),
                                              dtype=np.float32).copy())
                 for key, t in expected.items()}
        module = NETWORKS[kind](**args)
        module.load_state_dict(state)
        net = cls(module, settings_from_params(params["settings"]), params["seed"])
        n_in, n_out = args["n_in"], args["n_out"]
        net.x_mean_ = g.take("x_mean", (n_in,), dtype=np.float32)  # as fit leaves them
        net.x_std_ = g.take("x_std", (n_in,), dtype=np.float32)
        net.y_mean_ = g.take("y_mean", (n_out,), dtype=np.float32)
        net.y_std_ = g.take("y_std", (n_out,), dtype=np.float32)
        net.history_ = dict(params.get("history", {}))
        net._np_weights = None
        return net


# -- what training costs (bench/bench_profile.py) ----------------------------------------------
_FIT_LOG: list | None = None


@contextmanager
def record_fits():
    """Within the block, every training appends one record to the yielded list: ``network``
    (MLP, TDNN, GRUNet), ``members`` (networks trained together), ``epochs`` (summed over
    members), ``seconds`` and ``flops`` — the arithmetic it could not do without: per epoch a
    forward and backward pass (3 forward passes' worth) over the training frames and a forward
    pass over the validation frames (:func:`forward_flops`). Blocks nest: a training inside an
    inner block is recorded in the enclosing blocks too."""
    global _FIT_LOG
    saved, _FIT_LOG = _FIT_LOG, []
    try:
        yield _FIT_LOG
    finally:
        if saved is not None:
            saved.extend(_FIT_LOG)
        _FIT_LOG = saved


def forward_flops(module: nn.Module) -> float:
    """Floating-point operations of one frame's forward pass (multiply-adds count two)."""
    a = module.arguments
    n_in, h, n_out = a["n_in"], a["n_hidden"], a["n_out"]
    if isinstance(module, MLP):
        return 2.0 * (n_in * h + h * n_out)
    if isinstance(module, TDNN):
        k = 2 * a["width"] + 1
        return 2.0 * k * (n_in * h + (a["layers"] - 1) * h * h) + 2.0 * h * n_out
    return 2.0 * 3 * (n_in * h + h * h) + 2.0 * h * n_out  # GRU: three gates


def _record(module, members: int, histories: list, seconds: float, frames: list) -> None:
    """Append a record of one training to the active :func:`record_fits` (``frames``: per
    member ``(training, validation)`` frames)."""
    if _FIT_LOG is None:
        return
    f = forward_flops(module)
    flops = sum(h["epochs"] * f * (3 * n_tr + n_va) for h, (n_tr, n_va) in zip(histories, frames))
    _FIT_LOG.append({"network": type(module).__name__, "members": members,
                     "epochs": sum(h["epochs"] for h in histories), "seconds": seconds,
                     "flops": flops})


def fit_many(nets: list, X: list, Y: list) -> list:
    """Fit every :class:`NetRegressor` ``nets[i]`` on ``X[i]``, ``Y[i]`` (all rows training
    rows); returns ``nets``. MLPs of one input and output width trained full-batch under the
    same settings are trained together as one batched module (:mod:`mapping.batched`: each
    ends where it would alone, to float32 rounding); any other network alone."""
    groups: dict = {}
    for i, net in enumerate(nets):
        key = (net.settings, np.shape(X[i])[-1], np.shape(Y[i])[-1])
        if isinstance(net.module, MLP) and net.settings.batch_size == 0:
            groups.setdefault(key, []).append(i)
        else:
            net.fit(X[i], Y[i])
    for key, members in groups.items():
        data = [nets[i]._standardise(X[i], Y[i], None)[:2] for i in members]
        t0 = time.perf_counter()
        histories = fit_mlps([nets[i].module for i in members], [x for x, _ in data],
                             [y for _, y in data], key[0], [nets[i].seed for i in members])
        n_val = [validation_rows(len(x), key[0].validation_fraction) for x, _ in data]
        _record(nets[members[0]].module, len(members), histories, time.perf_counter() - t0,
                [(len(x) - v, v) for (x, _), v in zip(data, n_val)])
        for i, h in zip(members, histories):
            nets[i].history_ = h
    return nets


def fit_module(module: nn.Module, X: np.ndarray, Y: np.ndarray, mask: np.ndarray,
               settings: TrainSettings, seed: int) -> dict:
    """Adam on the masked MSE with early stopping; returns the training history.

    A random ``validation_fraction`` of the masked (training) entries is held out for early
    stopping when there are at least 10 of them; otherwise every epoch up to ``max_epochs`` runs
    on all of them and the last weights are kept.
    """
    t0 = time.perf_counter()
    history = _fit_module(module, X, Y, mask, settings, seed)
    n_val = validation_rows(int(mask.sum()), settings.validation_fraction)
    _record(module, 1, [history], time.perf_counter() - t0, [(int(mask.sum()) - n_val, n_val)])
    return history


def validation_rows(n: int, fraction: float) -> int:
    """Validation frames held out of ``n`` training frames (none when fewer than 10)."""
    return int(round(fraction * n)) if n >= 10 else 0


def _fit_module(module, X, Y, mask, settings, seed) -> dict:
    rng = np.random.default_rng(seed)
    torch.manual_seed(seed)
    for m in module.modules():  # deterministic initial weights from the seed
        if hasattr(m, "reset_parameters"):
            m.reset_parameters()
    idx = np.flatnonzero(mask.ravel())
    n_val = validation_rows(len(idx), settings.validation_fraction)
    val = np.zeros(mask.size, bool)
    val[rng.permutation(idx)[:n_val]] = True
    val = val.reshape(mask.shape)
    train = mask & ~val
    x, y = torch.from_numpy(X), torch.from_numpy(Y)
    w_tr = torch.from_numpy(train.astype(np.float32))[..., None]
    w_va = torch.from_numpy(val.astype(np.float32))[..., None]
    opt = torch.optim.Adam(module.parameters(), lr=settings.learning_rate,
                           weight_decay=settings.weight_decay)
    n_units = len(X)
    batch = settings.batch_size or n_units
    if batch >= n_units and n_val:
        return _fit_full_batch(module, opt, x, y, w_tr, w_va, settings)
    return _fit_epochs(module, opt, x, y, w_tr, w_va, settings, rng, n_val)


def _fit_epochs(module, opt, x, y, w_tr, w_va, settings, rng, n_val) -> dict:
    """:func:`fit_module`'s plain loop: mini-batches (or the full batch), then a validation
    pass, every epoch."""
    n_units = len(x)
    batch = settings.batch_size or n_units
    best, best_state, best_epoch, losses = np.inf, None, 0, []
    for epoch in range(settings.max_epochs):
        module.train()
        order = rng.permutation(n_units) if batch < n_units else np.arange(n_units)
        for s in range(0, n_units, batch):
            b = torch.from_numpy(order[s:s + batch])
            wb = w_tr[b]
            denom = wb.sum() * y.shape[-1]
            if denom == 0:
                continue
            opt.zero_grad()
            loss = (((module(x[b]) - y[b]) ** 2) * wb).sum() / denom
            loss.backward()
            opt.step()
        if n_val == 0:
            continue
        module.eval()
        with torch.no_grad():
            v = float((((module(x) - y) ** 2) * w_va).sum() / (w_va.sum() * y.shape[-1]))
        losses.append(v)
        if v < best - 1e-6:
            best, best_state, best_epoch = v, copy.deepcopy(module.state_dict()), epoch
        elif epoch - best_epoch >= settings.patience:
            break
    if best_state is not None:
        module.load_state_dict(best_state)
    return {"epochs": len(losses) if n_val else settings.max_epochs, "best_epoch": best_epoch,
            "best_validation_mse": float(best) if n_val else float("nan")}


def _fit_full_batch(module, opt, x, y, w_tr, w_va, settings) -> dict:
    """:func:`fit_module`'s loop for full-batch training with a validation part, one forward
    pass per epoch: the pass that follows a step gives both that step's validation loss and
    the next step's training loss (none of the networks behaves differently in training and
    evaluation), so the same epochs and weights cost one pass less each."""
    denom_tr = w_tr.sum() * y.shape[-1]
    denom_va = w_va.sum() * y.shape[-1]
    best, best_state, best_epoch, n_epochs = np.inf, None, 0, 0
    module.train()
    out = module(x)
    for epoch in range(settings.max_epochs):
        if denom_tr > 0:
            opt.zero_grad()
            loss = (((out - y) ** 2) * w_tr).sum() / denom_tr
            loss.backward()
            opt.step()
            out = module(x)
        n_epochs += 1
        with torch.no_grad():
            v = float((((out.detach() - y) ** 2) * w_va).sum() / denom_va)
        if v < best - 1e-6:
            best, best_state, best_epoch = v, copy.deepcopy(module.state_dict()), epoch
        elif epoch - best_epoch >= settings.patience:
            break
    module.load_state_dict(best_state)
    module.eval()
    return {"epochs": n_epochs, "best_epoch": best_epoch, "best_validation_mse": float(best)}
