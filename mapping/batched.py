"""Many small MLPs trained as one batched module (the MLP bank, the expression nets).

:func:`fit_mlps` trains ``B`` three-layer perceptrons of one input and output width (hidden
widths may differ) as :func:`mapping.nets.fit_module` trains each alone — the same initial
weights from each member's seed, the same validation draw, full-batch Adam on the MSE with the
same hyper-parameters, early stopping with each member's own patience and its own best weights
kept — but every epoch is a handful of batched tensor operations for all members still training,
not ``B`` rounds of tiny ones. Per-call overhead, not arithmetic, dominates networks this small,
so this is several times faster (``bench/bench_profile.py`` prints the ratio to the arithmetic
floor).

How it is laid out:

* **Blocks of rows.** Every member's training rows (and, apart, its validation rows) are cut into
  blocks of equal rows (:func:`block_rows`), each block of one member; one batched product
  (``torch.baddbmm``) over the blocks, with each block's member's weights gathered, computes
  every member at once. The padding is at most one part-block per member, whatever the sizes
  (a bank's classes range from 40 to over 1,000 frames: padding every member to the largest
  would multiply the work several times).
* **Gradients by hand.** The forward pass, the MSE's gradient and the backward pass of a tanh
  layer are a few products and element-wise operations, written out on the blocks and summed
  per member (``index_add_``); no autograd graph is built each epoch.
* **Independent members.** Weights are padded to the widest hidden layer with zeros; a padded
  unit has zero weights in and out, so its gradient is zero and Adam (with L2 weight decay)
  keeps it exactly zero. Each member's loss is its own mean over its own frames, so its
  gradient is that of its loss alone; Adam is element-wise (torch's ``Adam`` formula below).
* **Early stopping.** A member whose validation loss has not improved for ``patience`` epochs
  stops with its best weights; stopped members leave the batch when half of it has stopped.

The sums run in another order than the single network's, so a member equals its network
trained alone to float32 rounding, not bit for bit; early stopping may then pick a neighbouring
epoch on a flat validation curve (``tests/mapping/test_batched.py`` states the tolerance). Only
full-batch training is batched (``batch_size`` 0, the default); with mini-batches each network
trains alone.
"""
from __future__ import annotations

import numpy as np
import torch

from mapping.config import TrainSettings

BETAS = (0.9, 0.999)  # torch.optim.Adam's defaults, as fit_module uses them
EPS = 1e-8
IMPROVEMENT = 1e-6  # a validation loss counts as better when lower by more than this
BLOCK_ROWS = 32  # the fewest rows of a block


def validation_draw(n_rows: int, fraction: float, rng: np.random.Generator) -> np.ndarray:
    """Boolean (n_rows,) mask of the validation rows of a network trained on every row: a
    random ``fraction`` of them, none when fewer than 10 (as :func:`mapping.nets.fit_module`)."""
    idx = np.arange(n_rows)
    n_val = int(round(fraction * n_rows)) if n_rows >= 10 else 0  # nets.validation_rows
    val = np.zeros(n_rows, bool)
    val[rng.permutation(idx)[:n_val]] = True
    return val


def block_rows(sizes: list) -> int:
    """Rows per block for members of ``sizes`` rows: a power of two between
    :data:`BLOCK_ROWS` and 1024 near a quarter of the mean size, so that padding stays small
    (at most one part-block per member) and the blocks few (each is one small product)."""
    mean = sum(sizes) / max(len(sizes), 1)
    return int(np.clip(2 ** round(np.log2(max(mean / 4, 1))), BLOCK_ROWS, 1024))


class _Blocks:
    """Rows of several members in blocks of :func:`block_rows` rows, each block of one member:
    inputs ``x`` (n_blocks, R, n_in), targets ``y`` (n_blocks, R, n_out), row weights ``w``
    (n_blocks, R, 1: 1 / (the member's rows × n_out), 0 on padding) and each block's member
    ``member`` (n_blocks,), an index into the members in the batch."""

    def __init__(self, xs: list, ys: list):
        n_in, n_out = xs[0].shape[1], ys[0].shape[1]
        R = block_rows([len(x) for x in xs])
        counts = [-(-len(x) // R) for x in xs]
        n = sum(counts)
        x = np.zeros((n * R, n_in), np.float32)
        y = np.zeros((n * R, n_out), np.float32)
        w = np.zeros((n * R, 1), np.float32)
        start = 0
        for xi, yi, c in zip(xs, ys, counts):
            k = len(xi)
            x[start:start + k], y[start:start + k] = xi, yi
            w[start:start + k] = 1.0 / (max(k, 1) * n_out)
            start += c * R
        self.x = torch.from_numpy(x).view(n, R, n_in)
        self.y = torch.from_numpy(y).view(n, R, n_out)
        self.w = torch.from_numpy(w).view(n, R, 1)
        self.member = torch.from_numpy(np.repeat(np.arange(len(xs)), counts))

    def keep(self, alive: np.ndarray) -> None:
        """Keep the blocks of the members where ``alive`` (over the members in the batch) and
        number those members afresh."""
        new = torch.from_numpy(np.cumsum(alive) - 1)
        sel = torch.from_numpy(alive)[self.member]
        self.x, self.y, self.w = self.x[sel], self.y[sel], self.w[sel]
        self.member = new[self.member[sel]]


def _forward(blocks: _Blocks, params: list):
    W1, b1, W2, b2 = (p[blocks.member] for p in params)
    # tanh(z) = 2 sigmoid(2z) - 1: torch's sigmoid is ~3x faster than its tanh on this CPU
    # (AVX2) and the two agree to float32 rounding (~1e-7)
    h = torch.baddbmm(b1, blocks.x, W1, beta=2, alpha=2).sigmoid_().mul_(2).sub_(1)
    return h, torch.baddbmm(b2, h, W2), W2


def _per_member(values: torch.Tensor, member: torch.Tensor, n: int) -> torch.Tensor:
    """Sum per member of per-block ``values`` (n_blocks, ...)."""
    return torch.zeros((n, *values.shape[1:])).index_add_(0, member, values)


def _gradients(blocks: _Blocks, params: list) -> list:
    """Gradients of the members' own mean squared errors over their blocks."""
    n = len(params[0])
    h, out, W2 = _forward(blocks, params)
    g = out.sub_(blocks.y).mul_(blocks.w).mul_(2.0)  # dLoss/dout per row
    dz = torch.ops.aten.tanh_backward(torch.bmm(g, W2.transpose(1, 2)), h)  # (1 - h²) dh
    return [_per_member(torch.bmm(blocks.x.transpose(1, 2), dz), blocks.member, n),
            _per_member(dz.sum(1, keepdim=True), blocks.member, n),
            _per_member(torch.bmm(h.transpose(1, 2), g), blocks.member, n),
            _per_member(g.sum(1, keepdim=True), blocks.member, n)]


def _losses(blocks: _Blocks, params: list) -> np.ndarray:
    """Each member's mean squared error over its blocks."""
    _, out, _ = _forward(blocks, params)
    sq = out.sub_(blocks.y).square_().mul_(blocks.w).sum((1, 2))
    return _per_member(sq, blocks.member, len(params[0])).numpy()


def fit_mlps(modules: list, X: list, Y: list, settings: TrainSettings, seeds: list) -> list:
    """Train every ``modules[b]`` (a :class:`mapping.nets.MLP`) on the standardised
    ``X[b]`` (n_b, n_in) → ``Y[b]`` (n_b, n_out), all rows training rows, with seed
    ``seeds[b]``, as :func:`mapping.nets.fit_module` would alone; the modules are left with
    their best weights. Returns each member's training history."""
    B = len(modules)
    if not (B == len(X) == len(Y) == len(seeds)) or B == 0:
        raise ValueError("fit_mlps needs one module, input, target and seed per member")
    n_in, n_out = X[0].shape[1], Y[0].shape[1]
    hidden = [m.net[0].out_features for m in modules]
    H = max(hidden)
    # initial weights and validation draws, member by member, as fit_module makes them
    params = [torch.zeros(B, n_in, H), torch.zeros(B, 1, H), torch.zeros(B, H, n_out),
              torch.zeros(B, 1, n_out)]
    vals = []
    for b, (m, seed) in enumerate(zip(modules, seeds)):
        rng = np.random.default_rng(seed)
        torch.manual_seed(seed)
        for sub in m.modules():
            if hasattr(sub, "reset_parameters"):
                sub.reset_parameters()
        first, last, h = m.net[0], m.net[2], hidden[b]
        with torch.no_grad():
            params[0][b, :, :h] = first.weight.T
            params[1][b, 0, :h] = first.bias
            params[2][b, :h] = last.weight.T
            params[3][b, 0] = last.bias
        vals.append(validation_draw(len(X[b]), settings.validation_fraction, rng))
    has_val = np.array([v.any() for v in vals])
    train = _Blocks([x[~v] for x, v in zip(X, vals)], [y[~v] for y, v in zip(Y, vals)])
    # members without a validation part have no validation blocks (their loss is not read)
    val = _Blocks([x[v] if v.any() else x[:0] for x, v in zip(X, vals)],
                  [y[v] if v.any() else y[:0] for y, v in zip(Y, vals)])

    avg = [torch.zeros_like(p) for p in params]
    avg_sq = [torch.zeros_like(p) for p in params]
    best_params = [p.clone() for p in params]
    best = np.full(B, np.inf)
    best_epoch = np.zeros(B, int)
    n_losses = np.zeros(B, int)
    active = np.arange(B)  # the members in the batch (indices into the original order)
    running = np.ones(B, bool)  # members not yet stopped
    lr, wd = settings.learning_rate, settings.weight_decay
    beta1, beta2 = BETAS
    for epoch in range(settings.max_epochs):
        step = epoch + 1
        grads = _gradients(train, params)
        c1 = 1 - beta1 ** step
        c2_sqrt = (1 - beta2 ** step) ** 0.5
        for p, g, m, v in zip(params, grads, avg, avg_sq):  # torch.optim.Adam's update
            if wd:
                g.add_(p, alpha=wd)
            m.lerp_(g, 1 - beta1)
            v.mul_(beta2).addcmul_(g, g, value=1 - beta2)
            p.addcdiv_(m, (v.sqrt() / c2_sqrt).add_(EPS), value=-lr / c1)
        v_loss = _losses(val, params)
        better = np.zeros(len(active), bool)
        for j, b in enumerate(active):
            if not running[b] or not has_val[b]:
                continue
            n_losses[b] += 1
            if v_loss[j] < best[b] - IMPROVEMENT:
                best[b], best_epoch[b], better[j] = v_loss[j], epoch, True
            elif epoch - best_epoch[b] >= settings.patience:
                running[b] = False
        keep = better | ~has_val[active]  # members without validation keep their last weights
        if keep.any():
            sel = torch.from_numpy(np.flatnonzero(keep))
            tgt = torch.from_numpy(active[keep])
            for bp, p in zip(best_params, params):
                bp[tgt] = p[sel]
        alive = running[active]
        if not alive.any():
            break
        if alive.sum() * 2 <= len(active):  # compact: stopped members leave the batch
            sel = torch.from_numpy(np.flatnonzero(alive))
            active = active[alive]
            params = [p[sel] for p in params]
            avg = [a[sel] for a in avg]
            avg_sq = [a[sel] for a in avg_sq]
            train.keep(alive)
            val.keep(alive)
    histories = []
    for b, m in enumerate(modules):
        h = hidden[b]
        first, last = m.net[0], m.net[2]
        with torch.no_grad():
            first.weight.copy_(best_params[0][b, :, :h].T)
            first.bias.copy_(best_params[1][b, 0, :h])
            last.weight.copy_(best_params[2][b, :h].T)
            last.bias.copy_(best_params[3][b, 0])
        if has_val[b]:
            histories.append({"epochs": int(n_losses[b]), "best_epoch": int(best_epoch[b]),
                              "best_validation_mse": float(best[b])})
        else:
            histories.append({"epochs": settings.max_epochs, "best_epoch": 0,
                              "best_validation_mse": float("nan")})
    return histories
