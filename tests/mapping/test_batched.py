"""Fast training paths against the plain ones: many MLPs as one batched module
(:mod:`mapping.batched`) against each trained alone, and the one-pass full-batch loop against
the plain epoch loop of :func:`mapping.nets.fit_module`.

The tolerance of a batched member (stated in the README): its estimates within 1 % of the target
SD of its network trained alone, its best validation MSE within 1 % and its best epoch within
10 epochs. The batched sums run in another order than the single network's, and early stopping
may then pick a neighbouring epoch on a flat validation curve; the weights are otherwise the
same optimisation.
"""
from __future__ import annotations

import copy

import numpy as np
import pytest
import torch

from mapping import nets
from mapping.batched import fit_mlps
from mapping.config import TrainSettings
from mapping.gated_mlp import MLPBank
from mapping.nets import GRUNet, MLP, TDNN, NetRegressor, fit_many


def _problems(rng, sizes, n_in=12, n_out=4):
    W = rng.normal(size=(n_in, n_out))
    out = []
    for n in sizes:
        X = rng.normal(size=(n, n_in)).astype(np.float32)
        Y = (np.tanh(0.4 * X @ W) + 0.1 * rng.normal(size=(n, n_out))).astype(np.float32)
        out.append((X, Y))
    return out


def _close_to_alone(alone: NetRegressor, batched: NetRegressor, X, Y):
    scale = Y.std(0).max()
    assert np.abs(alone.predict(X) - batched.predict(X)).max() <= 0.01 * scale
    ha, hb = alone.history_, batched.history_
    assert abs(ha["best_epoch"] - hb["best_epoch"]) <= 10
    assert hb["best_validation_mse"] == pytest.approx(ha["best_validation_mse"], rel=0.01,
                                                      nan_ok=True)


def test_batched_members_equal_each_network_trained_alone(rng):
    # members of different sizes (one too small for a validation part), widths and seeds
    problems = _problems(rng, [8, 45, 120, 300, 61])
    hidden = [5, 9, 15, 25, 12]
    settings = TrainSettings(max_epochs=150, patience=15)
    alone = [NetRegressor(MLP(12, h, 4), settings, 3 + 101 * i).fit(X, Y)
             for i, (h, (X, Y)) in enumerate(zip(hidden, problems))]
    batched = fit_many([NetRegressor(MLP(12, h, 4), settings, 3 + 101 * i)
                        for i, h in enumerate(hidden)],
                       [X for X, _ in problems], [Y for _, Y in problems])
    for a, b, (X, Y) in zip(alone, batched, problems):
        _close_to_alone(a, b, X, Y)
    # a member without a validation part runs every epoch and keeps its last weights
    assert batched[0].history_["epochs"] == settings.max_epochs
    assert np.isnan(batched[0].history_["best_validation_mse"])
    # members stopped early at different epochs
    assert len({b.history_["epochs"] for b in batched[1:]}) > 1


def test_padded_hidden_units_stay_zero(rng):
    (X, Y), (X2, Y2) = _problems(rng, [80, 90])
    small, wide = MLP(12, 3, 4), MLP(12, 20, 4)
    seen = {}
    real_baddbmm = torch.baddbmm

    def spy(bias, a, b, **kw):  # the batched weights of the first layer, every epoch
        if b.shape[1] == 12 and b.shape[2] == 20:
            seen.setdefault("w1", []).append(b.detach().clone())
        return real_baddbmm(bias, a, b, **kw)

    torch.baddbmm = spy
    try:
        fit_mlps([small, wide], [X, X2], [Y, Y2], TrainSettings(max_epochs=30), [1, 2])
    finally:
        torch.baddbmm = real_baddbmm
    assert seen["w1"] and all(float(w[0, :, 3:].abs().max()) == 0.0 for w in seen["w1"])
    assert small.net[0].weight.shape == (3, 12)


def test_bank_trains_its_networks_as_one_batch(rng, monkeypatch):
    X = rng.normal(size=(400, 12)).astype(np.float32)
    Y = np.tanh(X[:, :4]).astype(np.float32)
    subsets = {0: np.arange(0, 150), 3: np.arange(150, 330), 7: np.arange(330, 400)}
    calls = []
    real = nets.fit_mlps
    monkeypatch.setattr(nets, "fit_mlps", lambda m, *a: calls.append(len(m)) or real(m, *a))
    settings = TrainSettings(max_epochs=80)
    bank = MLPBank(5, 9, settings, seed=4).fit(X, Y, subsets)
    assert calls == [3]
    for i, (c, rows) in enumerate(sorted(subsets.items())):
        alone = NetRegressor(MLP(12, bank.hidden_[c], 4), settings, 4 + 101 * i).fit(X[rows],
                                                                                      Y[rows])
        _close_to_alone(alone, bank.nets_[c], X[rows], Y[rows])


def test_minibatch_networks_train_alone(rng, monkeypatch):
    (X, Y), = _problems(rng, [60])
    monkeypatch.setattr(nets, "fit_mlps", lambda *a: pytest.fail("mini-batches are not batched"))
    settings = TrainSettings(max_epochs=20, batch_size=16)
    net, = fit_many([NetRegressor(MLP(12, 5, 4), settings, 0)], [X], [Y])
    alone = NetRegressor(MLP(12, 5, 4), settings, 0).fit(X, Y)
    np.testing.assert_array_equal(net.predict(X), alone.predict(X))


@pytest.mark.parametrize("make", [lambda: GRUNet(6, 8, 3), lambda: TDNN(6, 8, 3),
                                  lambda: MLP(6, 8, 3)], ids=["gru", "tdnn", "mlp"])
def test_one_pass_loop_equals_the_plain_loop_exactly(rng, make):
    X = rng.normal(size=(12, 25, 6)).astype(np.float32)
    Y = np.tanh(np.cumsum(X[..., :3], 1) * 0.3).astype(np.float32)
    mask = rng.random((12, 25)) < 0.8
    module = make()
    if isinstance(module, MLP):
        X, Y, mask = X.reshape(-1, 6), Y.reshape(-1, 3), mask.ravel()
    settings = TrainSettings(max_epochs=60, patience=10)
    torch.manual_seed(0)
    module.apply(lambda m: m.reset_parameters() if hasattr(m, "reset_parameters") else None)
    twin = copy.deepcopy(module)
    val = mask & (rng.random(mask.shape) < 0.2)
    w_tr = torch.from_numpy((mask & ~val).astype(np.float32))[..., None]
    w_va = torch.from_numpy(val.astype(np.float32))[..., None]
    x, y = torch.from_numpy(X), torch.from_numpy(Y)

    def adam(m):
        return torch.optim.Adam(m.parameters(), lr=settings.learning_rate,
                                weight_decay=settings.weight_decay)

    fast = nets._fit_full_batch(module, adam(module), x, y, w_tr, w_va, settings)
    plain = nets._fit_epochs(twin, adam(twin), x, y, w_tr, w_va, settings,
                             np.random.default_rng(0), int(val.sum()))
    assert fast == plain
    for key, t in module.state_dict().items():
        assert torch.equal(t, twin.state_dict()[key]), key


def test_fit_mlps_refuses_mismatched_members(rng):
    (X, Y), = _problems(rng, [20])
    with pytest.raises(ValueError, match="one module, input, target and seed per member"):
        fit_mlps([MLP(12, 4, 4)], [X, X], [Y], TrainSettings(), [0])


def test_nested_records_reach_the_enclosing_block(rng):
    # a method's training records its fits in its own block (mapping.experiment.train_method);
    # a profile around it (bench/bench_profile.py) must see them too
    (X, Y), = _problems(rng, [80])
    settings = TrainSettings(max_epochs=20, patience=5)
    with nets.record_fits() as outer:
        NetRegressor(MLP(12, 6, 4), settings, 1).fit(X, Y)
        with nets.record_fits() as inner:
            NetRegressor(MLP(12, 7, 4), settings, 2).fit(X, Y)
        assert [r["network"] for r in inner] == ["MLP"]
    assert len(outer) == 2 and outer[1] == inner[0]
    assert outer[0]["epochs"] <= 20 and outer[0]["flops"] > 0
