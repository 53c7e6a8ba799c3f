"""The generic rollout trainer: windows, loader, validation flights, early stopping with best-epoch restore."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from quad_modelling.core.training.rollout import (
    RolloutConfig,
    RolloutWindows,
    hold_back_flights,
    rollout_loader,
    traced_step,
    train_rollout,
)
from quad_modelling.errors import ConfigError


def _segments():
    a = {"u": np.arange(10.0)[:, None], "y": np.arange(10.0)[:, None] * 10}
    b = {"u": 100 + np.arange(7.0)[:, None], "y": 1000 + np.arange(7.0)[:, None] * 10}
    return [a, b]


def test_windows_are_rows_of_one_segment_and_never_cross_a_boundary():
    data = RolloutWindows(_segments(), history=2, horizon=3, stride=1)
    assert len(data) == (10 - 5 + 1) + (7 - 5 + 1)  # 6 + 3 windows
    first = data[0]
    np.testing.assert_array_equal(first["u"][:, 0].numpy(), [0, 1, 2, 3, 4])
    np.testing.assert_array_equal(first["y"][:, 0].numpy(), [0, 10, 20, 30, 40])
    batch = data[[5, 6, 8]]
    assert batch["u"].shape == (3, 5, 1)
    np.testing.assert_array_equal(batch["u"][:, :, 0].numpy(), [[5, 6, 7, 8, 9], [100, 101, 102, 103, 104], [102, 103, 104, 105, 106]])
    assert len(RolloutWindows(_segments(), history=2, horizon=3, stride=2)) == 3 + 2


def test_loader_is_seeded_and_covers_every_window_once():
    data = RolloutWindows(_segments(), history=1, horizon=2)
    def order(seed):
        return np.concatenate([b["u"][:, 0, 0].numpy() for b in rollout_loader(data, 4, True, seed)])
    assert sorted(order(3).tolist()) == sorted(data[list(range(len(data)))]["u"][:, 0, 0].tolist())
    np.testing.assert_array_equal(order(3), order(3))
    assert not np.array_equal(order(3), order(4))
    drawn = list(rollout_loader(data, 4, True, 0, windows_per_epoch=5))
    assert sum(len(b["u"]) for b in drawn) == 5


def test_hold_back_whole_flights():
    train, val = hold_back_flights(list("abcdefghij"), 0.2, seed=1)
    assert len(val) == 2 and len(train) == 8 and set(train) | set(val) == set("abcdefghij")
    assert hold_back_flights(list("abcdefghij"), 0.2, seed=1) == (train, val)
    assert hold_back_flights(["only"], 0.2) == (["only"], [])
    assert hold_back_flights(list("abc"), chosen=[2]) == (["a", "b"], ["c"])
    with pytest.raises(ConfigError, match="validation flights"):
        hold_back_flights(list("ab"), chosen=[0, 1])


class _Clipped(torch.nn.Module):
    """y = where(|W x| > 1, W x / |W x|, W x) row by row: a branch on values, written with where."""

    def __init__(self):
        super().__init__()
        self.linear = torch.nn.Linear(3, 3)

    def forward(self, x, scale):
        y = self.linear(x) * scale[:, None]
        norm = torch.linalg.vector_norm(y, dim=1, keepdim=True)
        return torch.where(norm > 1.0, y / norm, y), norm[:, 0]


def test_a_traced_step_serves_every_batch_size_and_trains_the_modules_parameters():
    torch.manual_seed(0)
    module = _Clipped()
    traced = traced_step(module, (torch.randn(8, 3), torch.ones(8)))
    x, scale = torch.randn(50, 3), torch.linspace(0.1, 5.0, 50)  # some rows clipped, some not
    for rows in (slice(0, 50), slice(3, 4), slice(10, 27)):
        with torch.no_grad():
            for a, b in zip(traced(x[rows], scale[rows]), module(x[rows], scale[rows])):
                assert torch.equal(a, b)
    assert (module(x, scale)[1] > 1.0).any() and (module(x, scale)[1] < 1.0).any()
    gradients = []
    for step in (traced, module):  # the trace's gradients are autograd's own: equal bit for bit
        module.zero_grad()
        (step(x, scale)[0] ** 2).sum().backward()
        gradients.append([p.grad.clone() for p in module.parameters()])
    assert all(torch.equal(a, b) for a, b in zip(*gradients)) and gradients[0][0].abs().max() > 0
    optimiser = torch.optim.SGD(module.parameters(), lr=0.1)  # the module's optimiser trains the trace
    before = traced(x, scale)[0].detach()
    optimiser.step()
    with torch.no_grad():
        assert torch.equal(traced(x, scale)[0], module(x, scale)[0]) and not torch.equal(traced(x, scale)[0], before)


class _Scalar(torch.nn.Module):
    def __init__(self):
        super().__init__()
        self.w = torch.nn.Parameter(torch.zeros(()))


def _loss(module, batch):
    """Mean squared error of y ≈ w·u over the window (u = 1 everywhere, so the optimum is w = y)."""
    return ((module.w * batch["u"] - batch["y"]) ** 2).mean()


def test_early_stopping_restores_the_best_validation_epoch():
    # training data pulls w to 2, validation data is best at w = 1: the validation loss falls, then rises
    train = RolloutWindows([{"u": np.ones((40, 1)), "y": np.full((40, 1), 2.0)}], history=1, horizon=4)
    val = RolloutWindows([{"u": np.ones((20, 1)), "y": np.full((20, 1), 1.0)}], history=1, horizon=4)
    module = _Scalar()
    config = RolloutConfig(horizon=4, batch_size=8, max_epochs=60, patience=3, learning_rate=0.05)
    history = train_rollout(module, _loss, train, val, config, seed=0)
    assert history.stopped_early and history.epochs_run == history.best_epoch + config.patience
    assert history.val_loss[history.best_epoch] == min(history.val_loss)
    assert history.val_loss[-1] > history.val_loss[history.best_epoch]  # it had gone past the optimum
    w = float(module.w.detach())
    assert abs((w - 1.0) ** 2 - history.val_loss[history.best_epoch]) < 1e-6  # the restored weights are the best epoch's
    assert abs(w - 1.0) < 0.1


def test_training_is_deterministic_for_a_seed():
    data = RolloutWindows([{"u": np.linspace(0, 1, 50)[:, None], "y": 3 * np.linspace(0, 1, 50)[:, None]}], history=1, horizon=5)
    results = []
    for seed in (7, 7, 8):
        module = _Scalar()
        train_rollout(module, _loss, data, None, RolloutConfig(horizon=5, batch_size=4, max_epochs=3, windows_per_epoch=12), seed)
        results.append(float(module.w.detach()))
    assert results[0] == results[1] and results[0] != results[2]


def test_the_validation_batch_size_changes_no_validation_loss():
    train = RolloutWindows([{"u": np.ones((40, 1)), "y": np.full((40, 1), 2.0)}], history=1, horizon=4)
    val = RolloutWindows([{"u": np.ones((23, 1)), "y": np.full((23, 1), 1.0)}], history=1, horizon=4)
    losses = []
    for val_batch in (None, 3, 1000):
        config = RolloutConfig(horizon=4, batch_size=8, max_epochs=5, learning_rate=0.05, val_batch_size=val_batch)
        history = train_rollout(_Scalar(), _loss, train, val, config, seed=0)
        assert history.validation_seconds > 0
        losses.append(history.val_loss)
    np.testing.assert_allclose(losses[1], losses[0], rtol=1e-6)
    np.testing.assert_allclose(losses[2], losses[0], rtol=1e-6)
    with pytest.raises(ConfigError, match="val_batch_size"):
        RolloutConfig(val_batch_size=0)
