"""Sufficient statistics of an evaluation and their one merge (issue #19).

An evaluation of many flights is the merge of per-flight statistics, in flight order: the serial
``evaluate``, its ``--jobs``/``--scheduler`` fan-out and ``quad-modelling merge`` of results.json files
all call :meth:`EvaluationStatistics.merge`, so they give the same numbers, bit for bit.

The averages keep the protocol's definitions (``windowed``, ``multistep``):

* windowed, per model and span: the mean over the W windows of the per-window RMS and TIC of each
  variable, :math:`\\bar s = \\frac1W \\sum_w s_w`. Statistics: ``windows`` = W and the sums
  :math:`\\sum_w \\mathrm{RMS}_w`, :math:`\\sum_w \\mathrm{TIC}_w` (18 variables, SI units; NaN where the
  flights' sensors do not measure the variable). The mean is ``sum / W``: the sum accumulated window
  by window, as ``numpy.mean`` over the stacked windows does.
* multi-step, per model: :math:`\\mathrm{MAE}_h = \\frac1S \\sum_{\\text{segments } g} S_g\\,\\mathrm{MAE}_h(g)`
  over the S starts of every segment g. Statistics: ``starts`` = S and ``error_sums`` =
  :math:`\\sum_g S_g\\,\\mathrm{MAE}_h(g)` per group (position, velocity, orientation, angular
  velocity: m, m/s, rad, rad/s) and horizon h = 1..H.

Sums are added flight after flight (``total = total + flight``, starting from zero); floating-point
addition is not associative, so merging the same flights grouped differently (two merged halves
instead of the flights one by one) may differ in the last bit, never more. Serialised floats are
Python's shortest round-trip text, so results.json holds the sums exactly.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from quad_modelling.errors import DataError

STATISTICS_VERSION = 1
"""Format version of results.json ``statistics``; a merge refuses any other."""


def _floats(values: np.ndarray) -> list:
    """An array as nested lists of floats, NaN as None (JSON has no NaN)."""
    array = np.asarray(values, dtype=float)
    if array.ndim == 0:
        return None if not np.isfinite(array) else float(array)
    return [_floats(v) for v in array]


def _array(values, where: str) -> np.ndarray:
    """The inverse of :func:`_floats`: None -> NaN; DataError naming ``where`` for anything but numbers."""
    try:
        def walk(v):
            return [walk(x) for x in v] if isinstance(v, list) else (np.nan if v is None else float(v))
        return np.asarray(walk(values), dtype=float)
    except (TypeError, ValueError) as err:
        raise DataError(f"{where}: expected numbers, got {str(values)[:60]}") from err


@dataclass
class WindowSums:
    """Windowed statistics of one model on one span: window count W and per-variable sums of RMS and TIC (SI)."""

    windows: int = 0
    rms_sum: np.ndarray | float = 0.0
    tic_sum: np.ndarray | float = 0.0

    def add_window(self, rms: np.ndarray, tic: np.ndarray) -> None:
        """Add one window's RMS and TIC rows (18 variables)."""
        self.rms_sum = self.rms_sum + np.asarray(rms, dtype=float)
        self.tic_sum = self.tic_sum + np.asarray(tic, dtype=float)
        self.windows += 1

    def merge(self, other: WindowSums) -> None:
        """Add ``other``'s windows (the statistics of later flights)."""
        self.rms_sum = self.rms_sum + other.rms_sum
        self.tic_sum = self.tic_sum + other.tic_sum
        self.windows += other.windows

    def means(self) -> tuple[np.ndarray, np.ndarray]:
        """(mean RMS, mean TIC) over the windows: ``sum / W``."""
        return self.rms_sum / self.windows, self.tic_sum / self.windows

    def to_json(self) -> dict:
        return {"windows": self.windows, "rms_sum": _floats(self.rms_sum), "tic_sum": _floats(self.tic_sum)}

    @classmethod
    def from_json(cls, data: dict, where: str) -> WindowSums:
        return cls(int(data["windows"]), _array(data["rms_sum"], f"{where}.rms_sum"), _array(data["tic_sum"], f"{where}.tic_sum"))


@dataclass
class MultistepSums:
    """Multi-step statistics of the span ``span``: S starts and, per model that has a multi-step form,
    the (4, H) sums of S_g MAE_h(g) over segments g (module docstring); how each model predicted
    (``forms``) and the models left out with the reason (``not_multistep``)."""

    span: str
    max_horizon: int
    order: list[str]  # models in table order (naive first)
    starts: int = 0
    error_sums: dict[str, np.ndarray] = field(default_factory=dict)
    forms: dict[str, str] = field(default_factory=dict)
    not_multistep: dict[str, str] = field(default_factory=dict)

    def empty_like(self) -> MultistepSums:
        """The statistics of no flight for the same span, horizon and models (the start of a merge)."""
        return MultistepSums(self.span, self.max_horizon, list(self.order))

    def add_segment(self, model: str, mae: np.ndarray, starts: int) -> None:
        """Add the MAE_h (4, H) of ``model`` over the ``starts`` starts of one segment (the pooled term S_g MAE_h(g))."""
        self.error_sums[model] = self.error_sums.get(model, 0.0) + mae * starts

    def merge(self, other: MultistepSums) -> None:
        """Add ``other``'s starts (a later flight's)."""
        self.starts += other.starts
        for name in other.order:  # table order
            if name in other.error_sums:
                self.error_sums[name] = self.error_sums.get(name, 0.0) + other.error_sums[name]
        self.forms.update(other.forms)
        self.not_multistep.update(other.not_multistep)

    def to_json(self) -> dict:
        return {"span": self.span, "max_horizon": self.max_horizon, "order": list(self.order), "starts": self.starts,
                "error_sums": {m: _floats(s) for m, s in self.error_sums.items()},
                "forms": dict(self.forms), "not_multistep": dict(self.not_multistep)}

    @classmethod
    def from_json(cls, data: dict, where: str) -> MultistepSums:
        sums = {m: _array(s, f"{where}.error_sums.{m}") for m, s in data["error_sums"].items()}
        for m, s in sums.items():
            if s.shape != (4, int(data["max_horizon"])):
                raise DataError(f"{where}.error_sums.{m}: shape {s.shape}, expected (4, {data['max_horizon']})")
        return cls(str(data["span"]), int(data["max_horizon"]), [str(m) for m in data["order"]], int(data["starts"]), sums,
                   dict(data["forms"]), dict(data["not_multistep"]))


@dataclass
class EvaluationStatistics:
    """Everything an evaluation's averages are computed from (module docstring), for one flight or many.

    ``vehicle``: the vehicle config's name; ``models``: the model names in table order;
    ``windowed[model][span]``: :class:`WindowSums`; ``multistep``: :class:`MultistepSums` or None
    (``--no-multistep``); ``durations``: the flights' lengths [s] (for the error when no window fits)."""

    vehicle: str
    models: list[str]
    windowed: dict[str, dict[str, WindowSums]]
    multistep: MultistepSums | None
    durations: list[float] = field(default_factory=list)

    @classmethod
    def empty(cls, vehicle: str, models: list[str], spans: list[str], multistep: MultistepSums | None) -> EvaluationStatistics:
        """No flight yet: every sum zero (the start of every merge)."""
        return cls(vehicle, list(models), {m: {s: WindowSums() for s in spans} for m in models}, multistep)

    def empty_like(self, spans: list[str]) -> EvaluationStatistics:
        """The statistics of no flight for the same models and multi-step table, with ``spans`` in order."""
        return EvaluationStatistics.empty(self.vehicle, self.models, spans, None if self.multistep is None else self.multistep.empty_like())

    def merge(self, other: EvaluationStatistics) -> None:
        """Add a later flight's (or a later evaluation's) statistics: the one merge (module docstring)."""
        if other.vehicle != self.vehicle:
            raise DataError(f"cannot merge an evaluation on vehicle {other.vehicle!r} into one on {self.vehicle!r}")
        if other.models != self.models:
            raise DataError(f"cannot merge the statistics of models {other.models} into those of {self.models}")
        for model, spans in other.windowed.items():
            for span, sums in spans.items():
                self.windowed[model].setdefault(span, WindowSums()).merge(sums)
        if (self.multistep is None) != (other.multistep is None):
            raise DataError("cannot merge an evaluation with a multi-step table and one without (--no-multistep)")
        if self.multistep is not None:
            self.multistep.merge(other.multistep)
        self.durations.extend(other.durations)

    @property
    def windows(self) -> int:
        """Windows scored over every span (each model scores every window)."""
        return sum(s.windows for s in self.windowed[self.models[0]].values())

    def to_json(self) -> dict:
        return {"version": STATISTICS_VERSION, "vehicle": self.vehicle, "models": list(self.models),
                "windowed": {m: {s: sums.to_json() for s, sums in spans.items()} for m, spans in self.windowed.items()},
                "multistep": None if self.multistep is None else self.multistep.to_json(),
                "durations_s": list(self.durations)}

    @classmethod
    def from_json(cls, data: dict, where: str = "statistics") -> EvaluationStatistics:
        """The statistics of a results.json ``statistics`` document; DataError naming the field when malformed."""
        if not isinstance(data, dict) or data.get("version") != STATISTICS_VERSION:
            raise DataError(f"{where}: statistics version {data.get('version') if isinstance(data, dict) else None!r}, "
                            f"this version reads {STATISTICS_VERSION}")
        try:
            windowed = {m: {s: WindowSums.from_json(v, f"{where}.windowed.{m}.{s}") for s, v in spans.items()}
                        for m, spans in data["windowed"].items()}
            multistep = None if data["multistep"] is None else MultistepSums.from_json(data["multistep"], f"{where}.multistep")
            stats = cls(str(data["vehicle"]), [str(m) for m in data["models"]], windowed, multistep, [float(d) for d in data["durations_s"]])
        except (KeyError, TypeError, AttributeError, ValueError) as err:
            if isinstance(err, DataError):
                raise
            raise DataError(f"{where}: malformed statistics ({type(err).__name__}: {err})") from err
        if set(stats.windowed) != set(stats.models):
            raise DataError(f"{where}: windowed statistics of models {sorted(stats.windowed)}, the document names {stats.models}")
        return stats
