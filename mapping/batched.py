"""Many small MLPs trained as one batched module (the MLP bank, the expression nets).

:func:`fit_mlps` trains ``B`` three-layer perceptrons of one input and output width (hidden
widths may differ) exactly as :func:`mapping.nets.fit_module` trains each alone — the same
initial weights from each member's seed, the same validation draw, full-batch Adam on the
masked MSE with the same hyper-parameters, early stopping with the member's own patience and its
own best weights kept — but every epoch is one batched step (``torch.baddbmm``) for all members
still training, not ``B`` steps of tiny tensors. Per-call overhead, not arithmetic, dominates
tiny networks, so this is several times faster (``bench/bench_profile.py`` prints the ratio).

How the members stay independent:

* weights are padded to the widest hidden layer with zeros; a padded unit has zero weights in and
  out, so its gradient is zero and Adam (with L2 weight decay) keeps it exactly zero;
* rows are padded to the member with most frames and weighted 0 in that member's loss;
* the loss is the sum of the members' own losses, so each member's gradient is the gradient of
  its own loss alone; Adam is element-wise (the update below is torch's ``Adam`` formula);
* a member whose validation loss has not improved for ``patience`` epochs stops: its best
  weights are kept and it leaves the batch when the batch is next compacted (when half the
  members have stopped), so finished members cost nothing.

The training and validation frames of each member are separate tensors (the single-network loop
runs both passes over all frames with a mask), so the sums run in another order: a member equals
its network trained alone to float32 rounding, not bit for bit (``tests/mapping/test_batched.py``
states the tolerance). Only full-batch training is batched (``batch_size`` 0, the default);
with mini-batches each network trains alone.
"""
from __future__ import annotations

import numpy as np
import torch

from mapping.config import TrainSettings

BETAS = (0.9, 0.999)  # torch.optim.Adam's defaults, as fit_module uses them
EPS = 1e-8
IMPROVEMENT = 1e-6  # a validation loss counts as better when lower by more than this


def validation_draw(n_rows: int, fraction: float, rng: np.random.Generator) -> np.ndarray:
    """Boolean (n_rows,) mask of the validation rows of a network trained on every row: a
    random ``fraction`` of them, none when fewer than 10 (as :func:`mapping.nets.fit_module`)."""
    idx = np.arange(n_rows)
    n_val = int(round(fraction * n_rows)) if n_rows >= 10 else 0
    val = np.zeros(n_rows, bool)
    val[rng.permutation(idx)[:n_val]] = True
    return val


def _pad_rows(arrays: list, rows: list, width: int) -> tuple[torch.Tensor, torch.Tensor]:
    """``(B, n_max, width)`` tensor of each member's ``arrays[b][rows[b]]`` and the (B, n_max, 1)
    weights (1 on real rows)."""
    n_max = max(1, max(int(r.sum()) for r in rows))
    out = np.zeros((len(arrays), n_max, width), np.float32)
    w = np.zeros((len(arrays), n_max, 1), np.float32)
    for b, (a, r) in enumerate(zip(arrays, rows)):
        k = int(r.sum())
        out[b, :k] = a[r]
        w[b, :k] = 1
    return torch.from_numpy(out), torch.from_numpy(w)


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
    W1 = torch.zeros(B, n_in, H)
    b1 = torch.zeros(B, 1, H)
    W2 = torch.zeros(B, H, n_out)
    b2 = torch.zeros(B, 1, n_out)
    vals = []
    for b, (m, seed) in enumerate(zip(modules, seeds)):
        rng = np.random.default_rng(seed)
        torch.manual_seed(seed)
        for sub in m.modules():
            if hasattr(sub, "reset_parameters"):
                sub.reset_parameters()
        first, last = m.net[0], m.net[2]
        h = hidden[b]
        with torch.no_grad():
            W1[b, :, :h] = first.weight.T
            b1[b, 0, :h] = first.bias
            W2[b, :h] = last.weight.T
            b2[b, 0] = last.bias
        vals.append(validation_draw(len(X[b]), settings.validation_fraction, rng))
    trains = [~v for v in vals]
    x_tr, w_tr = _pad_rows(X, trains, n_in)
    y_tr, _ = _pad_rows(Y, trains, n_out)
    x_va, w_va = _pad_rows(X, vals, n_in)
    y_va, _ = _pad_rows(Y, vals, n_out)
    d_tr = (w_tr.sum((1, 2)) * n_out).clamp_min(1)[:, None, None]
    d_va = (w_va.sum((1, 2)) * n_out).clamp_min(1)[:, None, None]
    has_val = np.array([v.any() for v in vals])

    params = [W1, b1, W2, b2]
    avg = [torch.zeros_like(p) for p in params]
    avg_sq = [torch.zeros_like(p) for p in params]
    best_params = [p.clone() for p in params]
    best = np.full(B, np.inf)
    best_epoch = np.zeros(B, int)
    n_losses = np.zeros(B, int)
    active = np.arange(B)  # members in the batch (indices into the original order)
    running = np.ones(B, bool)  # members not yet stopped
    lr, wd = settings.learning_rate, settings.weight_decay
    beta1, beta2 = BETAS
    tensors = [x_tr, w_tr, y_tr, d_tr, x_va, w_va, y_va, d_va]
    for p in params:
        p.requires_grad_(True)
    for epoch in range(settings.max_epochs):
        step = epoch + 1
        x, w, y, d = tensors[:4]
        W1, b1, W2, b2 = params
        out = torch.baddbmm(b2, torch.tanh(torch.baddbmm(b1, x, W1)), W2)
        loss = ((((out - y) ** 2) * w).sum((1, 2), keepdim=True) / d).sum()
        grads = torch.autograd.grad(loss, params)
        with torch.no_grad():
            c1 = 1 - beta1 ** step
            c2_sqrt = (1 - beta2 ** step) ** 0.5
            for p, g, m, v in zip(params, grads, avg, avg_sq):
                if wd:
                    g = g.add(p, alpha=wd)
                m.lerp_(g, 1 - beta1)
                v.mul_(beta2).addcmul_(g, g, value=1 - beta2)
                p.addcdiv_(m, (v.sqrt() / c2_sqrt).add_(EPS), value=-lr / c1)
            xv, wv, yv, dv = tensors[4:]
            out = torch.baddbmm(b2, torch.tanh(torch.baddbmm(b1, xv, W1)), W2)
            v_loss = ((((out - yv) ** 2) * wv).sum((1, 2)) / dv[:, 0, 0]).numpy()
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
            with torch.no_grad():
                for bp, p in zip(best_params, params):
                    bp[tgt] = p[sel]
        alive = running[active]
        if not alive.any():
            break
        if alive.sum() * 2 <= len(active):  # compact: stopped members leave the batch
            sel = torch.from_numpy(np.flatnonzero(alive))
            active = active[alive]
            params = [p.detach()[sel].clone().requires_grad_(True) for p in params]
            avg = [a[sel].clone() for a in avg]
            avg_sq = [a[sel].clone() for a in avg_sq]
            tensors = [t[sel] for t in tensors]
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
