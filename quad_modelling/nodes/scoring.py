"""Adapters between live (streamed) predictions and the core evaluation.

The evaluator node hands the received absolute predictions to
:class:`~quad_modelling.core.models.streaming.RecordedPrediction`, which trims them as the
offline predictors do.

* :class:`WindowBuffer`: the evaluator node's received samples of one window; :func:`window_measurements` (the
  measurements interpolated to the scored rows) and :func:`score_horizon` (receding-horizon errors) read them.
* :class:`HorizonRecord`: the receding-horizon errors of one model in one closed window (sums of the
  per-prediction group errors of :func:`~quad_modelling.core.evaluation.multistep.group_error_norms`), pooled
  into MAE@h by :meth:`LiveScores.horizon_mae` exactly as the offline multi-step MAE_h pools its starts.
* :class:`LiveScores`: per-window results of the evaluator node gathered into a core
  :class:`~quad_modelling.core.evaluation.windowed.EvaluationResult` (mean over scored windows
  per model and span), written with ``quad_modelling.io.reports.evaluation.write_report``.
* :data:`EVALUATOR_PARAMETERS`: the evaluator node's parameters.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from quad_modelling.core.alignment import coverage_reason, interpolate_at, stream_coverage
from quad_modelling.core.evaluation.multistep import GROUP_UNITS, GROUPS, group_error_norms, measured_groups
from quad_modelling.core.evaluation.statistics import EvaluationStatistics
from quad_modelling.core.evaluation.windowed import (
    EvaluationResult,
    ExampleWindow,
    SpanScores,
    WindowResult,
    evaluate_window,
)
from quad_modelling.core.flight_log import FlightLog
from quad_modelling.core.models.streaming import RecordedPrediction
from quad_modelling.core.preprocess import smooth, trimmed_inputs, trimmed_variables
from quad_modelling.core.variables import EVAL_VARIABLES, VARIABLES
from quad_modelling.core.windows import EvaluationConfig, SpanSpec
from quad_modelling.errors import QuadModellingError
from quad_modelling.io import topics
from quad_modelling.nodes.common import (
    model_name_check,
    sample_period,
    topic_name,
    IMU,
    MOCAP_ODOM,
    MOTOR_INPUT,
    Param,
    executor_param,
    math_threads_param,
    niceness,
    non_empty,
    non_negative,
    positive,
    time_span,
    qos_param,
    spans_check,
    stamp_step_param,
    vehicle_param,
)
from quad_modelling.nodes.mapping.streams import topic_map_param


@dataclass
class WindowRecord:
    """One closed window of one model: scored (rms/tic per VARIABLES column) or marked with a reason."""

    model: str
    span: str
    index: int
    start_s: float
    end_s: float
    rms: np.ndarray | None = None
    tic: np.ndarray | None = None
    reason: str = ""
    time_base: int = 0
    """How many times the engine inputs' clock jumped or the window origin moved before this window (0: none):
    after a jump back the window indices repeat, and (time_base, index) tells the windows apart."""

    @property
    def scored(self) -> bool:
        return self.rms is not None

    def to_json(self) -> dict:
        out = {"model": self.model, "span": self.span, "window": self.index, "time_base": self.time_base,
               "start_s": self.start_s, "end_s": self.end_s, "scored": self.scored}
        if self.scored:
            idx = {v: i for i, v in enumerate(VARIABLES)}
            out["scores"] = {v: {"rms": float(self.rms[idx[v]]), "tic": float(self.tic[idx[v]])} for v in EVAL_VARIABLES}
        else:
            out["reason"] = self.reason
        return out


@dataclass
class HorizonRecord:
    """Receding-horizon predictions of one model stamped in one closed window: per group (GROUPS order) the sum of
    the error norms [m, m/s, rad, rad/s], how many were scored, and how many the measurements did not reach."""

    model: str
    index: int
    error_sums: np.ndarray
    scored: int
    unreached: int = 0
    time_base: int = 0  # WindowRecord.time_base

    def mae(self) -> np.ndarray | None:
        """MAE@h of this window per group, :math:`\\frac{1}{S}\\sum_s e_s` (None without a scored prediction)."""
        return self.error_sums / self.scored if self.scored else None


@dataclass
class LiveScores:
    """Everything the evaluator node has scored or marked, in arrival order."""

    config: EvaluationConfig
    spans: list[SpanSpec]
    models: list[str]
    records: list[WindowRecord] = field(default_factory=list)
    examples: dict[str, ExampleWindow] = field(default_factory=dict)
    horizon_s: float = 0.0
    horizon: list[HorizonRecord] = field(default_factory=list)
    vehicle: str = ""  # the vehicle config's name, for the statistics (set once the node knows it)
    received: dict[str, int] = field(default_factory=dict)  # messages delivered per stream (the node's StreamTally)

    def horizon_mae(self) -> dict:
        """MAE@h per model and group over every scored receding-horizon prediction (pooled over windows:
        :math:`\\mathrm{MAE}_h = \\sum_w \\sum_s e_{w,s} / \\sum_w S_w`, the offline multi-step MAE_h over the same
        starts), with the counts; units in ``units``."""
        out: dict = {"horizon_s": self.horizon_s, "units": GROUP_UNITS, "models": {}}
        for model in dict.fromkeys(r.model for r in self.horizon):
            mine = [r for r in self.horizon if r.model == model]
            scored = sum(r.scored for r in mine)
            sums = np.sum([r.error_sums for r in mine], axis=0)
            entry = {group: (float(sums[g] / scored) if scored else None) for g, group in enumerate(GROUPS)}
            out["models"][model] = {"mae": entry, "predictions": scored, "unreached": sum(r.unreached for r in mine)}
        return out

    def add_example(self, span: str, window: FlightLog, measured: np.ndarray, predicted: dict, warm: int) -> None:
        """Keep the first scored window of each span for the report's figures (inputs trimmed with ``config.trim``)."""
        if span not in self.examples:
            self.examples[span] = ExampleWindow(window.meta.source, span, window.t - window.t[0], trimmed_inputs(window, self.config.trim),
                                                measured, dict(predicted), warm)

    def statistics(self) -> EvaluationStatistics:
        """The sufficient statistics of the scored windows (per model and span: window count, exact sums of RMS and
        TIC; :mod:`~quad_modelling.core.evaluation.statistics`), as ``evaluate`` writes them, so ``quad-modelling
        merge`` takes a run-bag result. No multi-step sums: run-bag adds them (``commands/run_bag.complete_results``)."""
        stats = EvaluationStatistics.empty(self.vehicle, self.models, [s.name for s in self.spans], None)
        for record in self.records:
            if record.scored and record.model in stats.windowed:
                stats.windowed[record.model][record.span].add_window(record.rms, record.tic)
        return stats

    def result(self, source: str) -> EvaluationResult:
        """Mean RMS/TIC over scored windows per model and span (the exact sums over the windows divided by their count,
        as offline), as a core EvaluationResult with its statistics."""
        stats = self.statistics()
        scores: dict[str, dict[str, SpanScores]] = {m: {} for m in self.models}
        for model in self.models:
            for span, sums in stats.windowed[model].items():
                if sums.windows:
                    scores[model][span] = SpanScores(*sums.means(), sums.windows)
        flights = [{"source": source, "live": True}]
        examples = list(self.examples.values())
        return EvaluationResult(scores, {}, self.config, flights, examples, stats)

    def write(self, output_dir, source: str, figures: bool, title: str) -> str:
        """Write results.json, tables.md (and, with ``figures``, the figures) into ``output_dir`` (replaced
        atomically); a one-line summary."""
        from quad_modelling.atomic import atomic_output
        from quad_modelling.io.reports.evaluation import write_report

        result = self.result(source)
        if not figures:
            result.examples = []
        with atomic_output(output_dir, force=True) as tmp:
            write_report(result, tmp, title=title, document=self.to_json(source))
            if self.horizon_s > 0:  # the receding-horizon mode's scores: in tables.md too, not only results.json
                with (tmp / "tables.md").open("a") as tables:
                    tables.write("\n" + self.horizon_table() + "\n")
        scored = sum(r.scored for r in self.records)
        return f"wrote {output_dir} ({scored} scored, {len(self.records) - scored} marked window results)"

    def horizon_table(self) -> str:
        """tables.md's section of the receding-horizon MAE (:meth:`horizon_mae`) per model and group, SI units."""
        from quad_modelling.io.reports.formatting import markdown_table

        mae = self.horizon_mae()
        rows = [[model, str(m["predictions"]), str(m["unreached"]),
                 *("-" if m["mae"][g] is None else f"{m['mae'][g]:.4g}" for g in GROUPS)] for model, m in mae["models"].items()]
        head = [f"## Receding horizon: MAE at {self.horizon_s:g} s ahead", "",
                "Every forecast scored against the measurement at its stamp, pooled over the windows (results.json "
                "live.horizon).", ""]
        columns = ["model", "predictions", "unreached", *(f"{g} [{GROUP_UNITS[g]}]" for g in GROUPS)]
        return "\n".join(head + markdown_table(columns, rows or [["(none received)", "0", "0", *("-" for _ in GROUPS)]]))

    def to_json(self, source: str) -> dict:
        """results.json: the core EvaluationResult JSON plus the live spans, every window (scored or marked) and the
        messages received per stream (``live.received``: run-bag compares them with what was sent)."""
        data = self.result(source).to_json()
        data["live"] = {
            "spans": [{"name": s.name, "start_s": s.start, "end_s": s.end if np.isfinite(s.end) else None} for s in self.spans],
            "windows": [r.to_json() for r in self.records],
            "marked": [r.to_json() for r in self.records if not r.scored],
            "received": dict(self.received),
        }
        if self.horizon_s > 0:
            data["live"]["horizon"] = self.horizon_mae()
        return data


def diagnostics_message(records: list[WindowRecord], stamp_ns: int, horizon: list[HorizonRecord] = ()):
    """The ``evaluation`` message of one closed window: a diagnostic_msgs/DiagnosticArray stamped ``stamp_ns``
    (the window's end) with one status per record: OK + ``<var>.rms``/``<var>.tic`` (SI, :data:`EVAL_VARIABLES`)
    for a scored window, WARN + ``not scored: <reason>`` for a marked one; and per ``horizon`` record a status
    ``evaluation/<model>/horizon/window_<k>``: OK + ``<group>.mae`` (SI) and ``predictions``, or WARN when no
    receding-horizon prediction of the window could be scored."""
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

    from quad_modelling.nodes.messages import ns_stamp

    msg = DiagnosticArray()
    msg.header.stamp = ns_stamp(stamp_ns)
    idx = {v: i for i, v in enumerate(VARIABLES)}
    for r in records:
        status = DiagnosticStatus(name=f"evaluation/{r.model}/{r.span}/window_{r.index}", hardware_id=r.model)
        values = [KeyValue(key="start_s", value=f"{r.start_s:g}"), KeyValue(key="end_s", value=f"{r.end_s:g}"),
                  KeyValue(key="time_base", value=str(r.time_base))]
        if r.scored:
            status.level = DiagnosticStatus.OK
            status.message = "scored"
            for v in EVAL_VARIABLES:
                values.append(KeyValue(key=f"{v}.rms", value=repr(float(r.rms[idx[v]]))))
                values.append(KeyValue(key=f"{v}.tic", value=repr(float(r.tic[idx[v]]))))
        else:
            status.level = DiagnosticStatus.WARN
            status.message = f"not scored: {r.reason}"
        status.values = values
        msg.status.append(status)
    for h in horizon:
        status = DiagnosticStatus(name=f"evaluation/{h.model}/horizon/window_{h.index}", hardware_id=h.model)
        mae = h.mae()
        values = [KeyValue(key="predictions", value=str(h.scored)), KeyValue(key="unreached", value=str(h.unreached)),
                  KeyValue(key="time_base", value=str(h.time_base))]
        if mae is None:
            status.level, status.message = DiagnosticStatus.WARN, "not scored: no measurement reaches the predicted stamps"
        else:
            status.level, status.message = DiagnosticStatus.OK, "scored"
            values += [KeyValue(key=f"{group}.mae", value=repr(float(mae[g]))) for g, group in enumerate(GROUPS)]
        status.values = values
        msg.status.append(status)
    return msg


# --- the evaluator's window buffers and what it computes from them at a close --------------------

class WindowBuffer:
    """Received samples of one window, by stamp [ns]: measurement fields, each model's prediction fields and
    receding-horizon predictions (stamped at the predicted time)."""

    __slots__ = ("index", "time_base", "motor", "omega", "odom", "imu", "mapped", "pred_odom", "pred_accel", "horizon", "passed_at")

    def __init__(self, index: int, models: list[str], time_base: int = 0):
        self.index = index
        self.time_base = time_base  # WindowRecord.time_base
        self.motor: dict[int, list] = {}
        self.omega: dict[int, list | None] = {}
        self.odom: dict[int, list] = {}
        self.imu: dict[int, list] = {}
        self.mapped: dict[str, dict[int, dict]] = {}  # with a topic map: topic -> stamp -> {map field: numbers}
        self.pred_odom = {m: {} for m in models}
        self.pred_accel = {m: {} for m in models}
        self.horizon = {m: {} for m in models}
        self.passed_at: float | None = None  # wall time [s, monotonic] the first stream moved past this window


def samples(windows: list[WindowBuffer], get, width: int) -> tuple[np.ndarray, np.ndarray]:
    """(stamps [ns] sorted, values (n, ``width``)) of one stream over consecutive windows (``get``: the window's dict);
    none: (0, ``width``) (a window closed with predictions but no measurement: a (0,) array made a traceback)."""
    merged: dict[int, list] = {}
    for w in windows:
        merged.update(get(w))
    stamps = np.array(sorted(merged), dtype=np.int64)
    return stamps, np.array([merged[ns] for ns in stamps], dtype=float).reshape(len(stamps), width)


def measurement_samples(neighbours: list[WindowBuffer], rows: np.ndarray, mapped=None, hold: bool = True) -> dict[str, np.ndarray]:
    """Every measured stream at the stamps ``rows`` [ns] (:func:`~quad_modelling.core.alignment.interpolate_at`, NaN
    where it does not reach): the contract's ``odom`` (n, 10) and ``imu`` (n, 6) fields or, with a topic map
    (``mapped``: :class:`~quad_modelling.nodes.mapping.streams.MappedStreams`), each map field's numbers."""
    if mapped is None:
        return {"odom": interpolate_at(*samples(neighbours, lambda w: w.odom, topics.ODOM_FIELDS), rows, quaternion=topics.ODOM_QUATERNION,
                                       hold=hold),
                "imu": interpolate_at(*samples(neighbours, lambda w: w.imu, topics.IMU_FIELDS), rows, hold=hold)}
    return {f: interpolate_at(*samples(neighbours, lambda w, f=f: mapped.field_samples(w.mapped, f), mapped.tracks[f].width), rows,
                              quaternion=(0, 4) if f == "attitude" else None, hold=hold) for f in mapped.tracks}


def samples_log(measured: dict[str, np.ndarray], rows: np.ndarray, motor, vehicle: str, source: str, omega=None, mapped=None) -> FlightLog:
    """:func:`measurement_samples` on ``rows`` -> FlightLog (the contract's or the map's conversion)."""
    motor = np.zeros((len(rows), 4)) if motor is None else motor
    if mapped is None:
        return topics.measurement_log(rows, motor, measured["odom"], measured["imu"], vehicle, source, omega=omega)
    return mapped.flight_log(rows, motor, measured, vehicle, source, omega)


def score_horizon(window: WindowBuffer, neighbours: list[WindowBuffer], models: list[str], vehicle, mapped=None) -> list[HorizonRecord]:
    """Error of each group (:func:`~quad_modelling.core.evaluation.multistep.group_error_norms`) of every
    receding-horizon prediction stamped in this window against the measurements interpolated at its stamp;
    predictions whose stamp the measurements do not bracket (e.g. past the flight's end) are counted as
    ``unreached``, not scored (offline, a start whose horizon passes the end is no start either)."""
    out = []
    for model in models:
        stamps = np.array(sorted(window.horizon[model]), dtype=np.int64)
        if len(stamps) == 0:
            continue
        fields = np.array([window.horizon[model][ns] for ns in stamps])
        measured = measurement_samples(neighbours, stamps, mapped, hold=False)
        have = np.logical_and.reduce([np.isfinite(v).all(axis=1) for v in measured.values()])
        errors = np.empty((0, len(GROUPS)))
        if have.any():
            truth = measured_groups(samples_log({k: v[have] for k, v in measured.items()}, stamps[have], None, vehicle.name,
                                                f"live window {window.index}", mapped=mapped))
            predicted = topics.predictions_from_fields(fields[have], np.zeros((int(have.sum()), topics.ACCEL_FIELDS)))
            errors = group_error_norms(truth, predicted)
        out.append(HorizonRecord(model, window.index, errors.sum(axis=0) if len(errors) else np.zeros(len(GROUPS)),
                                 len(errors), int((~have).sum()), window.time_base))
    return out


def window_measurements(window: WindowBuffer, neighbours: list[WindowBuffer], lo: int, hi: int, vehicle,
                        config: EvaluationConfig, mapped=None) -> tuple[FlightLog | None, np.ndarray | None, str]:
    """The window's measurements on its rows (the engine-input stamps in [lo, hi) [ns]) and their smoothed trimmed
    variables, or (None, None, reason) when a measurement stream (with a topic map ``mapped``: each measured topic)
    fails the coverage rule or cannot be used."""
    rows = np.array(sorted(window.motor), dtype=np.int64)
    streams = [(MOCAP_ODOM, window.odom), (IMU, window.imu)] if mapped is None else \
        [(topic, window.mapped.get(topic, {})) for topic in mapped.measured_topics]
    reason = coverage_reason([stream_coverage(MOTOR_INPUT, rows, lo, hi),
                              *(stream_coverage(name, np.array(sorted(buffer)), lo, hi) for name, buffer in streams)])
    if reason:
        return None, None, reason
    omegas = [window.omega[ns] for ns in rows]
    if len(rows) == 0:
        return None, None, "no engine input in the window"
    try:
        measured = measurement_samples(neighbours, rows, mapped)
        unreached = {name: np.flatnonzero(~np.isfinite(v).reshape(len(rows), -1).all(axis=1)) for name, v in measured.items()}
        unreached = {name: k for name, k in unreached.items() if len(k)}
        if unreached:  # named, with where (it said "mocap or imu ends early" of a stream late at the start)
            return None, None, "measurements do not reach every engine input of the window: " + "; ".join(
                f"{'mocap/odom' if name == 'odom' else name} none at {(rows[k[0]] - lo) / 1e9:.3f}..{(rows[k[-1]] - lo) / 1e9:.3f} s "
                "into the window" for name, k in unreached.items())
        log = samples_log(measured, rows, [window.motor[ns] for ns in rows], vehicle.name, f"live window {window.index}",
                          np.array(omegas) if all(o is not None for o in omegas) else None, mapped)
        return log, smooth(trimmed_variables(log, config.trim, vehicle), log.sample_rate, config.smooth_cutoff_hz), ""
    except QuadModellingError as err:
        return None, None, f"measurements unusable: {err}"


def score_model(model: str, window: WindowBuffer, neighbours: list[WindowBuffer], lo: int, hi: int, log: FlightLog,
                measured: np.ndarray, warm: int, config: EvaluationConfig, vehicle) -> tuple[WindowResult | None, str]:
    """One model on one window: its predictions checked by the coverage rule, interpolated to the window's rows (its
    engine-input stamps, integer ns: exact where a prediction's stamp matches) and
    scored with the core :func:`~quad_modelling.core.evaluation.windowed.evaluate_window`; (None, reason) when not."""
    odom, accel = window.pred_odom[model], window.pred_accel[model]
    reason = coverage_reason([stream_coverage(f"{model}/odom", np.array(sorted(odom)), lo, hi),
                              stream_coverage(f"{model}/accel", np.array(sorted(accel)), lo, hi)])
    if reason:
        return None, f"predictions: {reason} (predictor late, restarted or failed)"
    rows = np.array(sorted(window.motor), dtype=np.int64)
    pred_odom = interpolate_at(*samples(neighbours, lambda w: w.pred_odom[model], topics.PREDICTED_ODOM_FIELDS), rows,
                               quaternion=topics.ODOM_QUATERNION)
    pred_accel = interpolate_at(*samples(neighbours, lambda w: w.pred_accel[model], topics.ACCEL_FIELDS), rows)
    if not (np.isfinite(pred_odom).all() and np.isfinite(pred_accel).all()):
        return None, "predictions do not reach every engine input of the window"
    absolute = topics.predictions_from_fields(pred_odom, pred_accel)
    try:
        return evaluate_window(RecordedPrediction(model, absolute, config.trim), log, warm, config.trim, vehicle,
                               config.smooth_cutoff_hz, measured), ""
    except QuadModellingError as err:
        return None, f"cannot score: {err}"


def late_reason(last_ns: dict[str, int | None], origin_ns: int, grace_s: float) -> str:
    """Why a window closed by ``close_grace_s`` is marked: each late stream with its last stamp (``last_ns``, None:
    nothing yet) relative to the window origin."""
    described = [f"{stream} ({'nothing yet' if ns is None else f'last stamp {(ns - origin_ns) / 1e9:.3f} s after t0'})"
                 for stream, ns in last_ns.items()]
    return f"closed by close_grace_s={grace_s:g} s before every stream passed the window's end: late {', '.join(described)}"


def shared_models(count_publishers, models: list[str], kinds: tuple[str, ...]) -> dict[str, int]:
    """model -> the most publishers any of its prediction topics ``<model>/<kind>`` has, for the models with more
    than one: two predictors given one ``model_name`` (or a bag replay republishing recorded predictions beside a
    live predictor) interleave their predictions on one topic, which no score may mix. ``count_publishers(topic)``:
    the node's graph query."""
    counts = {model: max(count_publishers(f"{model}/{kind}") for kind in kinds) for model in models}
    return {model: n for model, n in counts.items() if n > 1}


def unmatched_models(node, models: list[str], kinds: tuple[str, ...]) -> list[str]:
    """The models one of whose prediction subscriptions ``<model>/<kind>`` of ``node`` has matched no publisher yet.
    Matched, not merely in the graph (``count_publishers``): over a lossy link the evaluator acknowledged, the replay
    started, and the first second of a model's predictions arrived before its reader had matched (two-host test)."""
    topics_of = {node.resolve_topic_name(f"{model}/{kind}"): model for model in models for kind in kinds}
    matched = {s.topic_name for s in node.subscriptions if s.topic_name in topics_of and s.get_publisher_count() > 0}
    return [model for model in models if any(t not in matched for t, m in topics_of.items() if m == model)]


def shared_reason(model: str, publishers: int) -> str:
    """Why a model's records are marked while :func:`shared_models` finds it published by several nodes."""
    return (f"{publishers} nodes publish {model}'s predictions: two predictors share the model name {model} (give each "
            "its own model_name); mixed predictions are not scored")


def _models_check(value) -> str | None:
    names = [str(v).strip() for v in (value or [])]
    if not names:
        return "give at least one predictor name, e.g. models:=[greybox]"
    if any(not n or "/" in n or ":" in n for n in names):
        return f"model names must be plain topic prefixes (no '/' or ':'), got {names}"
    if len(set(names)) != len(names):
        return f"model names must be unique, got {names}"
    return next((model_name_check(n) for n in names if model_name_check(n)), None)


EVALUATOR_PARAMETERS = [
    Param("models", ["naive"], "names of the predictors to score (their topics <name>/odom, <name>/accel)", _models_check),
    vehicle_param(),
    Param("window_s", EvaluationConfig.window_s, "window length W [s], as the predictors", time_span),
    Param("warm_s", EvaluationConfig.warm_s, "warm start [s], as the predictors", time_span),
    Param("sample_period_s", 0.0, "nominal engine-input period [s] of the window clock's dt/2 shift; 0 = median of the first "
                                  "motor-input steps", sample_period),
    Param("horizon_s", 0.0, "receding-horizon scoring: MAE@h of <model>/horizon/odom (predicted horizon_s ahead, stamped at the "
                            "predicted time) against the measurements; the predictors' horizon_s; 0 = off", non_negative),
    stamp_step_param(),
    Param("spans", ["live:0:inf"], "spans NAME:A:B in seconds from t0; only windows entirely inside one are scored", spans_check),
    Param("output_dir", "", "directory for results.json/tables.md/figures (replaced on each write); empty = do not write"),
    Param("record", "", "record measurements, predictions and evaluation into this new MCAP bag directory (zstd "
                        "chunks; written when the node ends); empty = do not record"),
    Param("force", False, "replace an output_dir (or record bag) that existed before this node started"),
    Param("figures", True, "also write the thesis-style figures of the first window of each span"),
    Param("motor_input_topic", "motor_input", "engine inputs (sensor_msgs/JointState)", topic_name),
    Param("odom_topic", "mocap/odom", "motion capture (nav_msgs/Odometry)", topic_name),
    Param("imu_topic", "imu", "IMU (sensor_msgs/Imu)", topic_name),
    topic_map_param(),
    Param("stale_model_s", 2.0, "a model silent this long [wall s] no longer holds back progress or window closing", positive),
    Param("close_grace_s", 3.0, "close a window this long [wall s] after the first stream passed its end, even if another "
                                "stream (measurement or model) has not; that stream's part is then marked, naming it", positive),
    Param("ready_timeout_s", 20.0, "wait this long [wall s] for every model's publishers before acknowledging progress", non_negative),
    qos_param(),
    Param("qos_depth", 1000, "depth of the keep-last subscriptions", positive),
    Param("nice", 10, "raise this process's scheduling niceness by this much (0-19): scoring a closed window is not "
                      "time-critical, the predictors' per-input answers are", niceness),
    executor_param(),
    math_threads_param(),
]
