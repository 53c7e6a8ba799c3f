"""Multi-step (IDSIA) evaluation: MAE@h per group from many start times, SimErr, ratio to naive.

Every model evaluated is in the table (:func:`multistep_form`): a model with a vectorised
``predict_horizons`` (:class:`~quad_modelling.core.models.base.MultiStepPredictor`) uses it; any
other model that runs live (:class:`~quad_modelling.core.models.streaming.StreamingPredictor`)
uses its live form from each start
(:func:`~quad_modelling.core.models.streaming.predict_horizons_by_stream`: ``start_window`` on
the warm rows ending at the start, then ``push`` of each later command), causal by construction.
Only a model with neither (the dummy, whose prediction is the window's trim value) is listed
under ``not_multistep`` with the reason. Every model is scored from the same starts: s from
``warm - 1`` (the first start with ``warm`` rows up to it, ``warm`` = the evaluation's warm start
in rows) to ``N - 1 - H``.

One ``predict_horizons`` call serves many starts, so a predictor receives the whole segment; it must
read nothing after each start but the commands (the causality rule,
:class:`~quad_modelling.core.models.base.MultiStepPredictor`). The truth is the best measurement of
each row (:func:`~quad_modelling.core.preprocess.measured_variables`).

A group whose sensor the flights lack (angular velocity without a gyro) is marked
``{"needs": "gyro"}`` instead of scored."""

from __future__ import annotations

from collections.abc import Iterator, Sequence

import numpy as np

from quad_modelling.core import frames
from quad_modelling.core.evaluation.metrics import (
    SIM_ERR_HORIZON,
    mae_by_horizon,
    sim_err,
    vector_error_norm,
)
from quad_modelling.core.evaluation.statistics import MultistepSums
from quad_modelling.core.flight_log import SENSORS, FlightLog
from quad_modelling.core.models.base import (
    ConstantStatePredictor,
    MultiStepPredictor,
    Predictor,
)
from quad_modelling.core.models.streaming import StreamingHorizons, StreamingPredictor
from quad_modelling.core.preprocess import (
    NEEDS,
    ground_contact,
    measured_variables,
)
from quad_modelling.core.variables import VARIABLES
from quad_modelling.core.vehicle import VehicleConfig
from quad_modelling.core.windows import EvaluationConfig, span_segments, warm_samples_for
from quad_modelling.errors import DataError

GROUPS: dict[str, slice] = {
    "position": slice(0, 3),
    "velocity": slice(3, 6),
    "orientation": slice(9, 12),
    "angular_velocity": slice(12, 15),
}
"""Multi-step groups and their VARIABLES columns (orientation: the Euler angles)."""


GROUP_UNITS = {"position": "m", "velocity": "m/s", "orientation": "rad", "angular_velocity": "rad/s"}


NOT_MULTISTEP_REASON = "no multi-step form: neither predict_horizons nor a live (streaming) form"
"""Why a model is left out of the multi-step table (the dummy: its prediction is the window's trim value)."""


def multistep_form(model: Predictor, warm_samples: int) -> MultiStepPredictor | None:
    """The form a model is scored with in the multi-step table (module docstring): its own
    ``predict_horizons``, else its live form from each start with ``warm_samples`` warm rows,
    else None."""
    if isinstance(model, MultiStepPredictor):
        return model
    if isinstance(model, StreamingPredictor):
        return StreamingHorizons(model, warm_samples)
    return None


def multistep_mae(predictor: MultiStepPredictor, segment: FlightLog, max_horizon: int, vehicle: VehicleConfig | None = None,
                  chunk: int = 2048, first_start: int = 0, stride: int = 1) -> tuple[np.ndarray, int]:
    """MAE_h of each group over every start of ``segment``: ((4, H) MAE in GROUPS order, number of starts S).

    Every ``stride``-th sample s = first_start + k stride with s + H inside the segment is a start
    (``stride`` 1: every sample, the protocol; more: a sample of the starts, for benchmarks);
    predictions are made ``chunk`` starts at a time. With no start the MAE is zero and S = 0.
    """
    measured = measured_variables(segment, vehicle)
    n_starts = -(-(len(segment) - max_horizon - first_start) // stride)  # ceil: starts first_start, +stride, ... < N - H
    if n_starts <= 0:
        return np.zeros((len(GROUPS), max_horizon)), 0
    norms = np.empty((n_starts, len(GROUPS), max_horizon))
    steps = np.arange(1, max_horizon + 1)
    for first in range(0, n_starts, chunk):
        rows = np.arange(first, min(first + chunk, n_starts))
        starts = first_start + rows * stride
        predicted = np.asarray(predictor.predict_horizons(segment, starts, max_horizon))[:, 1:, :]
        truth = measured[starts[:, None] + steps[None, :]]
        errors = group_error_norms(truth.reshape(-1, len(VARIABLES)), predicted.reshape(-1, len(VARIABLES)))
        norms[rows] = errors.reshape(len(starts), max_horizon, len(GROUPS)).transpose(0, 2, 1)
    return mae_by_horizon(norms), n_starts


def group_error_norms(truth: np.ndarray, predicted: np.ndarray) -> np.ndarray:
    """(n, 18) measured and predicted variables (VARIABLES order, SI, N/FRD) -> (n, 4) error of each group in
    GROUPS order: the Euclidean norm :math:`\\lVert y_m - y_p \\rVert` of the position [m], velocity [m/s] and
    angular velocity [rad/s] 3-vectors, and for orientation the geodesic angle [rad] between the two attitudes.
    The one per-sample error of MAE_h, offline (:func:`multistep_mae`) and live (the evaluator's ``horizon_s``)."""
    truth, predicted = np.asarray(truth, dtype=float), np.asarray(predicted, dtype=float)
    out = np.empty((len(truth), len(GROUPS)))
    for g, (group, cols) in enumerate(GROUPS.items()):
        if group == "orientation":
            out[:, g] = frames.geodesic_angle(truth[:, cols], predicted[:, cols]) if len(truth) else []
        else:
            out[:, g] = vector_error_norm(truth[:, cols], predicted[:, cols])
    return out


def measured_groups(log: FlightLog) -> np.ndarray:
    """(N, 18) truth of the MAE_h groups of each row (VARIABLES order; other columns NaN): the same values as
    :func:`~quad_modelling.core.preprocess.measured_variables` for position, velocity, Euler angles and gyro
    rates, without the differentiated columns (so any number of rows at any stamps will do)."""
    out = np.full((len(log), len(VARIABLES)), np.nan)
    out[:, GROUPS["position"]] = log.pos_n
    out[:, GROUPS["velocity"]] = log.vel_n
    out[:, GROUPS["orientation"]] = log.euler
    if log.gyro_b is not None:
        out[:, GROUPS["angular_velocity"]] = log.gyro_b
    return out


def multistep_evaluation(flights: Sequence[FlightLog], models: Sequence[Predictor], vehicle: VehicleConfig, config: EvaluationConfig,
                         start_stride: int = 1) -> dict:
    """The IDSIA multi-step table of every model (module docstring): MAE at ``config.horizons``, SimErr, naive
    baseline and ratios (SI units); ``forms`` says how each model predicted (``predict_horizons`` or ``streaming``).
    ``start_stride`` > 1 scores every start_stride-th start only (recorded in the result; benchmarks).
    The merge of :func:`flight_multistep_sums` over the flights in order, then :func:`multistep_table`."""
    total = None
    for log in flights:
        sums = flight_multistep_sums(log, models, vehicle, config, start_stride)
        if total is None:
            total = sums
        else:
            total.merge(sums)
    if total is None:
        total = flight_multistep_sums(None, models, vehicle, config, start_stride)
    return multistep_table(total, config, start_stride)


def flight_multistep_sums(log: FlightLog | None, models: Sequence[Predictor], vehicle: VehicleConfig, config: EvaluationConfig,
                          start_stride: int = 1) -> MultistepSums:
    """The multi-step statistics of one flight (:class:`~quad_modelling.core.evaluation.statistics.MultistepSums`):
    every segment of its ``config.multistep_span`` (split at marked measurement gaps) longer than H plus the warm
    start, every model scored from the same starts; ``log`` None gives the empty statistics."""
    span = next(s for s in config.spans() if s.name == config.multistep_span)
    max_h = max(max(config.horizons), SIM_ERR_HORIZON)
    naive = ConstantStatePredictor(vehicle, config.trim)
    evaluated = [naive] + [m for m in models if m.name != naive.name]
    sums = MultistepSums(span.name, max_h, [m.name for m in evaluated])
    contact = contact_counts(log) if log is not None else None
    for start, stop in span_segments(log, span, config) if log is not None else ():
        segment = log.slice(start, stop)
        warm = warm_samples_for(segment, config.warm_s)
        if stop - start <= max_h + warm - 1:
            continue
        rows = start + np.arange(warm - 1, stop - start - max_h, start_stride)  # the starts multistep_mae scores
        sums.ground_starts += int(np.count_nonzero(touching(contact, rows, max_h)))
        for m in evaluated:
            form = multistep_form(m, warm)
            if form is None:
                sums.not_multistep[m.name] = NOT_MULTISTEP_REASON
                continue
            sums.forms[m.name] = "predict_horizons" if form is m else "streaming"
            mae, n = multistep_mae(form, segment, max_h, vehicle, first_start=warm - 1, stride=start_stride)
            sums.add_segment(m.name, mae, n)  # pooled over segments: MAE of all starts = sum_g S_g MAE_g / sum_g S_g
        sums.starts += n
    return sums


def multistep_table(sums: MultistepSums, config: EvaluationConfig, start_stride: int = 1) -> dict:
    """The results.json ``horizons`` document of merged multi-step statistics: MAE_h = error sum / S per model and
    group, SimErr, the naive baseline and the ratios (SI units); a note when no segment had a start."""
    max_h = sums.max_horizon
    count = sums.starts
    naive_name = sums.order[0]
    if count == 0:
        return {"span": sums.span, "starts": 0, "note": f"no {sums.span} segment longer than {max_h} samples plus the warm start"}
    out: dict = {"span": sums.span, "starts": count, "horizons": list(config.horizons), "sim_err_horizon": max_h,
                 "units": GROUP_UNITS, "forms": {m: sums.forms[m] for m in sums.order if m in sums.forms}, "models": {}}
    if start_stride != 1:
        out["start_stride"] = start_stride
    if sums.ground_starts:
        out["ground_starts"] = sums.ground_starts
    mae = {name: sums.mae(name) for name in sums.order if name in sums.forms}
    for name, values in mae.items():
        entry = {}
        for g, (group, cols) in enumerate(GROUPS.items()):
            if not np.isfinite(mae[naive_name][g]).all():  # the flights lack the group's sensor: marked, not scored
                entry[group] = {"needs": SENSORS[NEEDS[VARIABLES[cols.start]]]}
                continue
            model_se = sim_err(values[g])
            naive_se = sim_err(mae[naive_name][g])
            entry[group] = {
                "mae": {str(h): float(values[g, h - 1]) for h in config.horizons},
                "sim_err": model_se,
                "naive_mae": {str(h): float(mae[naive_name][g, h - 1]) for h in config.horizons},
                "naive_sim_err": naive_se,
                "ratio_sim_err": model_se / naive_se if naive_se > 0 else None,
                "ratio_mae": {str(h): (float(values[g, h - 1] / mae[naive_name][g, h - 1]) if mae[naive_name][g, h - 1] > 0 else None) for h in config.horizons},
            }
        out["models"][name] = entry
    if sums.not_multistep:
        out["not_multistep"] = {m: sums.not_multistep[m] for m in sums.order if m in sums.not_multistep}
    return out


def start_errors(flights: Sequence[FlightLog], models: Sequence[MultiStepPredictor], vehicle: VehicleConfig,
                 config: EvaluationConfig, groups: Sequence[str] = ("velocity", "angular_velocity"), stride: int = 1,
                 block_s: float = 2.0, airborne: bool = False) -> tuple[list[np.ndarray], np.ndarray]:
    """Per start, each model's SimErr contribution :math:`\\sum_{h \\le H} \\lVert y_{s+h} - \\hat y_{s+h} \\rVert` of
    ``groups`` (the protocol's starts and segments of ``config.multistep_span``, every ``stride``-th start): a list of
    (S, G) arrays in ``models`` order, and (S,) the index of each start's block of ``block_s`` seconds (consecutive
    over segments; for a block bootstrap). Their means over starts are the models' SimErr (:func:`multistep_table`'s
    at ``stride`` 1). ``airborne``: only the starts whose rows s..s+H do not touch the ground
    (:func:`~quad_modelling.core.preprocess.ground_contact`; no model here has ground contact). DataError when no
    segment is long enough."""
    horizon = max(max(config.horizons), SIM_ERR_HORIZON)
    scored, truths = [], []  # (segment, starts) and the measured rows 1..H after each start
    blocks, first_block = [], 0
    for segment, starts in protocol_starts(flights, config, stride, airborne):
        scored.append((segment, starts))
        truths.append(measured_variables(segment, vehicle)[starts[:, None] + np.arange(1, horizon + 1)[None, :]])
        block = np.floor((segment.t[starts] - segment.t[starts[0]]) / block_s).astype(int)
        blocks.append(first_block + block)
        first_block += int(block.max()) + 1
    if not blocks:
        raise _no_segment(flights, config)
    def contributions(truth, predicted):  # (S, G): each group's error summed over the horizon
        return np.stack([_group_norms(truth, np.asarray(predicted)[:, 1:], group).sum(axis=1) for group in groups], axis=1)

    errors = [np.vstack([contributions(truth, predicted) for truth, predicted in zip(truths, predict_parts(model, scored, horizon))])
              for model in models]
    return errors, np.concatenate(blocks)


def _no_segment(flights: Sequence[FlightLog], config: EvaluationConfig) -> DataError:
    horizon = max(max(config.horizons), SIM_ERR_HORIZON)
    return DataError(f"no {config.multistep_span} segment longer than {horizon} samples plus the warm start in the flights "
                     f"({', '.join(f'{log.meta.source} {log.duration:.1f} s' for log in flights)}) after the drops "
                     f"{config.drop_start:g}/{config.drop_end:g} s and ground contact")


def check_protocol_starts(flights: Sequence[FlightLog], config: EvaluationConfig, airborne: bool = False) -> None:
    """:func:`start_errors`'s DataError when ``flights`` hold no start of the protocol (:func:`protocol_starts`), raised
    before a caller spends minutes fitting (the diagnosis said three phases first)."""
    if next(protocol_starts(flights, config, 1, airborne), None) is None:
        raise _no_segment(flights, config)


def protocol_starts(flights: Sequence[FlightLog], config: EvaluationConfig, stride: int = 1,
                    airborne: bool = False) -> Iterator[tuple[FlightLog, np.ndarray]]:
    """Each segment of ``config.multistep_span`` with a start and its starts (rows of the segment): the protocol's
    (:func:`multistep_evaluation`'s at ``stride`` 1: s from ``warm - 1`` to ``N - 1 - H``), every ``stride``-th;
    ``airborne``: only those whose rows s..s+H do not touch the ground (:func:`~quad_modelling.core.preprocess.ground_contact`).
    The one definition of the starts :func:`start_errors` scores and the diagnosis counts."""
    span = next(s for s in config.spans() if s.name == config.multistep_span)
    horizon = max(max(config.horizons), SIM_ERR_HORIZON)
    for log in flights:
        contact = contact_counts(log) if airborne else None
        for start, stop in span_segments(log, span, config):
            segment = log.slice(start, stop)
            starts = np.arange(warm_samples_for(segment, config.warm_s) - 1, len(segment) - horizon, stride)
            if contact is not None:  # rows start + s .. start + s + H free of contact
                starts = starts[~touching(contact, start + starts, horizon)]
            if starts.size:
                yield segment, starts


def contact_counts(log: FlightLog) -> np.ndarray:
    """(N + 1,) how many rows before each row of ``log`` touch the ground
    (:func:`~quad_modelling.core.preprocess.ground_contact`, judged on the whole flight: where it stood)."""
    return np.concatenate([[0], np.cumsum(ground_contact(log))])


def touching(contact: np.ndarray, rows: np.ndarray, horizon: int) -> np.ndarray:
    """(S,) whether rows s..s+H after each start row s (flight rows) touch the ground, from :func:`contact_counts`:
    the one test of the starts the diagnosis leaves out and the table counts (``ground_starts``)."""
    return contact[rows + horizon + 1] > contact[rows]


BATCH_STARTS = 4096
"""Most starts one batched multi-step call takes (:func:`predict_parts`): (4096, 51, 18) floats, 30 MB."""


def predict_parts(model: MultiStepPredictor, parts: Sequence[tuple[FlightLog, np.ndarray]], horizon: int) -> list[np.ndarray]:
    """``model.predict_horizons`` of each (segment, starts) of ``parts``, for the :data:`GROUPS` (no acceleration):
    through the model's ``predict_horizons_of`` (one batch for the starts of many segments; the physics model's,
    whose per-step cost is numpy's call overhead; its acceleration columns NaN) in groups of at most
    :data:`BATCH_STARTS` starts where it has one, else part by part."""
    batched = getattr(model, "predict_horizons_of", None)
    if batched is None:
        return [model.predict_horizons(segment, starts, horizon) for segment, starts in parts]
    out, group, count = [], [], 0
    for part in parts:
        if group and count + len(part[1]) > BATCH_STARTS:
            out += batched(group, horizon)
            group, count = [], 0
        group.append(part)
        count += len(part[1])
    return out + (batched(group, horizon) if group else [])


def ratio_to_naive(errors: np.ndarray, naive: np.ndarray) -> float:
    """The mean over the groups of SimErr / naive's SimErr from per-start errors (S, G) of :func:`start_errors`: the
    one number the physics model's observer choice and the diagnosis minimise."""
    return float(np.mean(errors.mean(axis=0) / naive.mean(axis=0)))


def _group_norms(truth: np.ndarray, predicted: np.ndarray, group: str) -> np.ndarray:
    """(..., ) error of one group, as :func:`group_error_norms` computes it, for rows of any leading shape."""
    if group == "orientation":
        shape = truth.shape[:-1]
        return group_error_norms(truth.reshape(-1, len(VARIABLES)), predicted.reshape(-1, len(VARIABLES)))[:, 2].reshape(shape)
    cols = GROUPS[group]
    return vector_error_norm(truth[..., cols], predicted[..., cols])
