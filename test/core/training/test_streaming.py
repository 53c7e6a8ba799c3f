"""Training streams its samples from the flights' arrays (issue #19, training on fleets).

The series-parallel rows the NARX dataset yields are exactly the rows of the stacked regressor matrix the
training used to build (same values, same order); the chunked full-batch loss and gradient equal the one-batch
ones; and nothing allocated per batch, or held by a dataset, grows with the number of flights beyond the
flights' own arrays.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
from torch.utils._python_dispatch import TorchDispatchMode

from quad_modelling.core.models.narx import NarxConfig, lagged_inputs
from quad_modelling.core.training.narx import (
    Segment,
    _make_nets,
    regressors,
    series_parallel_loss,
    series_parallel_rows,
)
from quad_modelling.core.training.rollout import RolloutWindows, mean_loss, rollout_loader

CONFIG = NarxConfig(hidden=4, output_delays=3, input_delays=(0, 1, 2, 4), epochs=1, noise_snr_db=(None,) * 6)
"""warm_samples = 4: every row t >= 4 of a segment is a training row."""


def _segments(count: int, rows: int = 23, seed: int = 0) -> list[Segment]:
    rng = np.random.default_rng(seed)
    return [Segment(rng.normal(size=(rows + 3 * k, 4)), rng.normal(size=(rows + 3 * k, 6)) * [1, 2, 3, 0.1, 0.2, 0.3])
            for k in range(count)]


def _stats(segments):
    u = np.concatenate([s.u for s in segments])
    y = np.concatenate([s.y for s in segments])
    return u.mean(axis=0), u.std(axis=0), y.mean(axis=0), y.std(axis=0)


def _stacked(segments, config, y_step):
    """The materialised form the training held before streaming: lagged inputs, sliding output windows and
    targets of every segment, stacked in float64 and cast to float32 (X_u (N, |D_u| n_u), X_y (N, 6, n_y), target)."""
    u_mean, u_std, y_mean, y_std = _stats(segments)
    parts = []
    for s in segments:
        u, y = (s.u - u_mean) / u_std, (s.y - y_mean) / y_std
        start, n_y = config.warm_samples, config.output_delays
        x_u = lagged_inputs(u, config.input_delays)[start:]
        x_y = np.lib.stride_tricks.sliding_window_view(y, n_y, axis=0)[start - n_y: len(y) - n_y]
        parts.append((x_u, x_y, y[start:]))
    x_u, x_y, target = (np.concatenate(p) for p in zip(*parts))
    if config.incremental:
        target = (target - x_y[:, :, -1]) / y_step
    return [torch.from_numpy(np.ascontiguousarray(a).astype(np.float32)) for a in (x_u, x_y, target)]


@pytest.mark.parametrize("incremental", [False, True])
def test_streamed_rows_are_the_stacked_regressors_in_order(incremental):
    import dataclasses

    config = dataclasses.replace(CONFIG, incremental=incremental)
    segments = _segments(3)
    u_mean, u_std, y_mean, y_std = _stats(segments)
    y_step = np.array([0.5, 1.0, 2.0, 1.5, 0.7, 1.1]) if incremental else np.ones(6)
    rows = series_parallel_rows(segments, [s.y for s in segments], u_mean, u_std, y_mean, y_std, y_step, config)
    expected = _stacked(segments, config, y_step)
    assert len(rows) == sum(len(s.u) - config.warm_samples for s in segments) == len(expected[0])
    streamed = [regressors(batch, config) for batch in rollout_loader(rows, 5, shuffle=False)]
    for got, want in zip(zip(*streamed), expected):
        got = torch.cat(got)
        assert got.shape == want.shape
        if incremental:  # the target is computed in float64 then cast, as before: equal to float32 rounding of the division
            np.testing.assert_allclose(got.numpy(), want.numpy(), rtol=2e-7, atol=1e-7)
        else:
            np.testing.assert_array_equal(got.numpy(), want.numpy())  # the very same float32 values


def test_chunked_full_batch_loss_and_gradient_equal_one_batch():
    segments = _segments(4)
    u_mean, u_std, y_mean, y_std = _stats(segments)
    rows = series_parallel_rows(segments, [s.y for s in segments], u_mean, u_std, y_mean, y_std, np.ones(6), CONFIG)
    torch.manual_seed(0)
    nets = _make_nets(6, CONFIG.hidden, 4 * len(CONFIG.input_delays), CONFIG.output_delays, np.ones(6), False)
    x_u, x_y, target = _stacked(segments, CONFIG, np.ones(6))
    full = ((nets(x_u, x_y) - target) ** 2).mean(dim=0).sum()  # what the L-BFGS closure minimised before
    full.backward()
    one_batch = {name: p.grad.clone() for name, p in nets.named_parameters()}
    nets.zero_grad()
    chunked = series_parallel_loss(nets, rows, CONFIG, chunk=7)  # 7 does not divide the 94 rows: a short last chunk
    assert chunked == pytest.approx(float(full.detach()), rel=1e-6)
    for name, p in nets.named_parameters():
        np.testing.assert_allclose(p.grad.numpy(), one_batch[name].numpy(), rtol=1e-5, atol=1e-7, err_msg=name)


class _LargestTensor(TorchDispatchMode):
    """Records the largest number of elements of any tensor an operator returns (forward and backward)."""

    def __init__(self):
        super().__init__()
        self.largest = 0

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        out = func(*args, **(kwargs or {}))
        for t in out if isinstance(out, (tuple, list)) else (out,):
            if isinstance(t, torch.Tensor):
                self.largest = max(self.largest, t.numel())
        return out


def _largest_in_series_parallel_step(flights: int, chunk: int) -> int:
    segments = _segments(flights, rows=200)
    u_mean, u_std, y_mean, y_std = _stats(segments)
    rows = series_parallel_rows(segments, [s.y for s in segments], u_mean, u_std, y_mean, y_std, np.ones(6), CONFIG)
    torch.manual_seed(0)
    nets = _make_nets(6, CONFIG.hidden, 4 * len(CONFIG.input_delays), CONFIG.output_delays, np.ones(6), False)
    with _LargestTensor() as mode:
        series_parallel_loss(nets, rows, CONFIG, chunk=chunk)
    return mode.largest


def test_the_largest_tensor_of_a_series_parallel_step_does_not_grow_with_flights():
    """One full-batch loss and gradient over 2 or 8 flights (400 or 1,700 rows) in chunks of 64 rows: the largest
    tensor any operation makes is the same, a chunk's windows (64 x 5 rows x 6 outputs = 1,920 elements) or
    hidden layer (64 x 6 nets x 4 units), not the stacked regressors (1,700 rows x 30 = 51,000)."""
    small, large = _largest_in_series_parallel_step(2, 64), _largest_in_series_parallel_step(8, 64)
    assert small == large
    assert large <= 64 * (CONFIG.warm_samples + 1) * 6
    # the measure sees the old form: one batch of every row grows with the flights
    assert _largest_in_series_parallel_step(8, 10**6) > 4 * _largest_in_series_parallel_step(2, 10**6) / 1.2


def test_a_dataset_holds_the_flights_rows_once_and_two_numbers_per_segment():
    """Nothing per window: 2 or 8 segments of the same length hold 4x the float32 rows and 4x the segment index,
    whatever the number of windows (stride 1: about one window per row)."""
    def held(count):
        data = RolloutWindows([{"u": np.zeros((300, 4)), "y": np.zeros((300, 6))}] * count, history=20, horizon=50)
        tensors = [v for v in vars(data).values() if isinstance(v, torch.Tensor)] + list(data.arrays.values())
        return len(data), sum(t.numel() for t in tensors)

    (windows_2, elements_2), (windows_8, elements_8) = held(2), held(8)
    assert windows_2 == 2 * (300 - 70 + 1) and windows_8 == 4 * windows_2
    steps = 70  # the window's row offsets 0..69
    assert elements_2 == 2 * 300 * 10 + (2 + 1) + 2 + steps
    assert elements_8 == 8 * 300 * 10 + (8 + 1) + 8 + steps


def test_validation_loss_is_streamed_in_batches():
    """mean_loss over 2 or 8 validation flights: every batch it scores has at most batch_size windows."""
    seen = []

    def loss_fn(module, batch):
        seen.append(len(batch["u"]))
        return (batch["u"] ** 2).mean()

    for count in (2, 8):
        data = RolloutWindows([{"u": np.ones((120, 1))}] * count, history=5, horizon=10, stride=5)
        assert mean_loss(None, loss_fn, data, 16) == pytest.approx(1.0)
    assert max(seen) == 16 and sum(seen) == 10 * len(RolloutWindows([{"u": np.ones((120, 1))}], 5, 10, 5))


def test_hybrid_input_statistics_merged_per_segment_equal_those_of_every_row():
    """The residual net's normalisation from per-segment means and squared deviations (Chan's merge) equals
    np.mean / np.std over the stacked inputs of every row of the bundled bag's segments (1e-12 relative)."""
    from quad_modelling.core.models.hybrid import net_features
    from quad_modelling.core.models.physics import Observer
    from quad_modelling.core.physics.parameters import PhysicsParameters
    from quad_modelling.core.physics.rigid_body import PhysicsState
    from quad_modelling.core.training.hybrid import feature_statistics, flight_segments
    from quad_modelling.core.vehicle import load_vehicle
    from quad_modelling.io.loader import load_flight
    from test.conftest import REPO

    vehicle = load_vehicle("crazyflie21")
    log = load_flight(REPO / "bags" / "nanobench_B7_oval_medium_rep2", vehicle)
    spans = [(5.0, 15.0), (15.0, 22.0), (22.0, 30.0)]  # three segments of different lengths
    segments = flight_segments(PhysicsParameters.from_vehicle(vehicle), [log] * 3, spans, Observer())
    rows = np.concatenate([net_features(PhysicsState(np.zeros_like(s["vel"]), s["vel"], s["rot"].reshape(-1, 3, 3), s["rates"],
                                                     s["rotor"], np.zeros(len(s["vel"]))), s["u"]) for s in segments])
    mean, std = feature_statistics(segments)
    np.testing.assert_allclose(mean, rows.mean(axis=0), rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(std, rows.std(axis=0), rtol=1e-12, atol=1e-12)


def _full_batch_lbfgs(segments, config, seed):
    """The series-parallel training as it was before streaming: one batch of the stacked regressors, L-BFGS."""
    from quad_modelling.core.models.narx import MIN_STD
    from quad_modelling.core.training.rollout import seeded_torch

    y_std = np.maximum(np.concatenate([s.y for s in segments]).std(axis=0), MIN_STD)
    steps = np.concatenate([np.diff((s.y - np.concatenate([s.y for s in segments]).mean(axis=0)) / y_std, axis=0)
                            for s in segments])
    y_step = np.maximum(steps.std(axis=0), MIN_STD) if config.incremental else np.ones(6)
    x_u, x_y, target = _stacked(segments, config, y_step)
    with seeded_torch(seed):
        nets = _make_nets(6, config.hidden, x_u.shape[1], config.output_delays, y_step, config.incremental)
        optimiser = torch.optim.LBFGS(nets.parameters(), lr=1.0, max_iter=config.iterations_per_epoch, history_size=20,
                                      line_search_fn="strong_wolfe", tolerance_grad=1e-9, tolerance_change=1e-12)

        def closure():
            optimiser.zero_grad()
            loss = ((nets(x_u, x_y) - target) ** 2).mean(dim=0).sum()
            loss.backward()
            return loss

        for _ in range(config.epochs):
            optimiser.step(closure)
    return {name: p.detach().double().numpy() for name, p in nets.named_parameters()}


@pytest.mark.parametrize("incremental", [False, True])
def test_series_parallel_training_on_one_chunk_is_the_full_batch_training_bit_for_bit(incremental):
    """With no more rows than a chunk (here 2 flights, 560 rows), train_narx's weights equal those of the old
    full-batch L-BFGS on the stacked regressors exactly (no target noise; the thesis's noise draws are unchanged)."""
    import dataclasses

    from quad_modelling.core.training.narx import train_narx

    config = dataclasses.replace(CONFIG, epochs=2, iterations_per_epoch=5, incremental=incremental)
    segments = _segments(2, rows=280, seed=4)
    model = train_narx(segments, 0.01, "test", config, seed=3)
    reference = _full_batch_lbfgs(segments, config, seed=3)
    for name, weights in reference.items():
        np.testing.assert_array_equal(getattr(model, name), weights, err_msg=name)
