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

Sums are exact (:class:`ExactSum`): every finite float64 is an integer multiple of
:math:`2^{-1074}`, so a sum of them is an integer at that scale, and integer addition is associative.
Merging the same flights in any grouping or order (per-flight files, shards, the flights one by one)
gives the same sums to the last bit, and every mean is the exact sum divided by the count, correctly
rounded once. results.json stores each exact sum as a hexadecimal mantissa and a power of two
(``"0x1b3p-60"`` = 0x1b3 * 2^-60); NaN (a variable the sensors do not measure) as null.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field

import numpy as np

from quad_modelling.core.variables import VARIABLES
from quad_modelling.errors import DataError

STATISTICS_VERSION = 1
"""Format version of results.json ``statistics``; a merge refuses any other."""


SCALE_BITS = 1074
"""Every finite float64 is an integer multiple of 2^-1074 (the smallest subnormal), so x * 2^1074 is an integer."""

MAX_SUM_BITS = 1024 + SCALE_BITS + 64
"""Bits of the largest exact sum read back: 2^64 finite float64 values (each below 2^1024) at scale 2^1074. A file's
sum beyond it is no sum of float64 values (an edited exponent asked for 2^5000: an OverflowError traceback)."""

_HEX_SUM = re.compile(r"^(-?)0x([0-9a-f]+)p([+-]\d+)$")


def _scaled(x: float) -> int | float:
    """x * 2^1074 as an int, exactly, for a finite x; x itself (NaN, +-inf) otherwise."""
    if not math.isfinite(x):
        return x
    numerator, denominator = x.as_integer_ratio()  # denominator: a power of two <= 2^1074
    return numerator << (SCALE_BITS - denominator.bit_length() + 1)


def _add(a: int | float, b: int | float) -> int | float:
    """Exact sum of two scaled values; NaN and inf propagate as in IEEE arithmetic."""
    if isinstance(a, int) and isinstance(b, int):
        return a + b
    special = [v for v in (a, b) if isinstance(v, float)]
    return special[0] if len(special) == 1 else special[0] + special[1]  # inf + -inf = NaN, as IEEE


class ExactSum:
    """A running sum of float64 arrays of one shape, kept exactly (integers at scale 2^1074; module docstring).

    ``add(values)`` adds an array; ``merge(other)`` adds another sum; ``mean(count)`` is the sum / count as
    float64, correctly rounded once (Python's int true division is); ``to_json``/``from_json`` store it exactly."""

    def __init__(self, shape: tuple | None = None):
        self.shape = None if shape is None else tuple(shape)  # None: nothing added yet (takes the first array's shape)
        self.terms: list = [] if shape is None else [0] * math.prod(self.shape)

    def add(self, values) -> ExactSum:
        array = np.asarray(values, dtype=float)
        if self.shape is None:
            self.shape, self.terms = array.shape, [0] * array.size
        if array.shape != self.shape:
            raise DataError(f"cannot add an array of shape {array.shape} to a sum of shape {self.shape}")
        self.terms = [_add(t, _scaled(float(v))) for t, v in zip(self.terms, array.ravel())]
        return self

    def merge(self, other: ExactSum) -> ExactSum:
        if other.shape is None:
            return self
        if self.shape is None:
            self.shape, self.terms = other.shape, list(other.terms)
            return self
        if other.shape != self.shape:
            raise DataError(f"cannot merge a sum of shape {other.shape} into one of shape {self.shape}")
        self.terms = [_add(a, b) for a, b in zip(self.terms, other.terms)]
        return self

    def mean(self, count: int) -> np.ndarray:
        """sum / count [units of the values], correctly rounded; NaN where the sum is NaN, all NaN for no count."""
        if self.shape is None or count == 0:
            return np.full(self.shape or (), np.nan)
        divisor = count << SCALE_BITS
        return np.array([t if isinstance(t, float) else t / divisor for t in self.terms], dtype=float).reshape(self.shape)

    def to_json(self) -> dict:
        def text(t):
            if isinstance(t, float):
                return None if math.isnan(t) else ("inf" if t > 0 else "-inf")
            if t == 0:
                return "0x0p+0"
            shift = (t & -t).bit_length() - 1  # trailing zero bits: the shortest exact text
            return f"{'-' if t < 0 else ''}0x{abs(t) >> shift:x}p{shift - SCALE_BITS:+d}"
        return {"shape": None if self.shape is None else list(self.shape), "sums": [text(t) for t in self.terms]}

    @classmethod
    def from_json(cls, data, where: str) -> ExactSum:
        try:
            shape = None if data["shape"] is None else tuple(int(n) for n in data["shape"])
            if shape is not None and (min(shape, default=0) < 0 or math.prod(shape) != len(data["sums"])):
                raise DataError(f"{where}: {len(data['sums'])} sums for shape {shape}")  # before [0] * prod is held
            out = cls(shape)
            terms = []
            for item in data["sums"]:
                if item is None or item in ("inf", "-inf"):
                    terms.append(math.nan if item is None else float(item))
                    continue
                sign, mantissa, exponent = _HEX_SUM.match(item).groups()
                shift = int(exponent) + SCALE_BITS
                if shift < 0 or len(mantissa) * 4 + shift > MAX_SUM_BITS + 4:
                    raise ValueError(f"{item[:40]}: no sum of float64 values")
                terms.append((-1 if sign else 1) * (int(mantissa, 16) << shift))
        except (KeyError, TypeError, ValueError, AttributeError) as err:
            raise DataError(f"{where}: expected an exact sum {{shape, sums: ['0x..p..', ...]}}, got {str(data)[:60]}") from err
        if len(terms) != (0 if out.shape is None else math.prod(out.shape)):
            raise DataError(f"{where}: {len(terms)} sums for shape {out.shape}")
        out.terms = terms
        return out

    def __eq__(self, other) -> bool:
        return isinstance(other, ExactSum) and self.to_json() == other.to_json()


@dataclass
class WindowSums:
    """Windowed statistics of one model on one span: window count W and per-variable sums of RMS and TIC (SI)."""

    windows: int = 0
    rms_sum: ExactSum = field(default_factory=ExactSum)
    tic_sum: ExactSum = field(default_factory=ExactSum)

    def add_window(self, rms: np.ndarray, tic: np.ndarray) -> None:
        """Add one window's RMS and TIC rows (18 variables)."""
        self.rms_sum.add(rms)
        self.tic_sum.add(tic)
        self.windows += 1

    def merge(self, other: WindowSums) -> None:
        """Add ``other``'s windows (the statistics of other flights; exact, so any grouping gives the same sums)."""
        self.rms_sum.merge(other.rms_sum)
        self.tic_sum.merge(other.tic_sum)
        self.windows += other.windows

    def means(self) -> tuple[np.ndarray, np.ndarray]:
        """(mean RMS, mean TIC) over the windows: exact ``sum / W``, rounded once."""
        return self.rms_sum.mean(self.windows), self.tic_sum.mean(self.windows)

    def to_json(self) -> dict:
        return {"windows": self.windows, "rms_sum": self.rms_sum.to_json(), "tic_sum": self.tic_sum.to_json()}

    @classmethod
    def from_json(cls, data: dict, where: str) -> WindowSums:
        """The sums of a statistics document; DataError naming ``where`` when they contradict their count: sums of one
        row of 18 variables exactly when windows were scored, mean RMS >= 0 and mean TIC in [0, 1] (NaN allowed: a
        window without a signal). A window count edited to 0 with its sums kept merged into TIC 2 and RMS 3944 m/s."""
        sums = cls(count(data["windows"], f"{where}.windows"), ExactSum.from_json(data["rms_sum"], f"{where}.rms_sum"),
                   ExactSum.from_json(data["tic_sum"], f"{where}.tic_sum"))
        expected = (len(VARIABLES),) if sums.windows else None
        for name, total in (("rms_sum", sums.rms_sum), ("tic_sum", sums.tic_sum)):
            if total.shape != expected:
                raise DataError(f"{where}.{name}: sums of shape {total.shape} for {sums.windows} windows (expected {expected})")
        rms, tic = sums.means()
        if sums.windows and (np.any(rms < 0) or np.any(tic < 0) or np.any(tic > 1 + TIC_ROUNDING)):  # NaN compares False
            raise DataError(f"{where}: mean RMS {np.nanmin(rms):.9g} or mean TIC {np.nanmin(tic):.9g}..{np.nanmax(tic):.9g} over "
                            f"{sums.windows} windows: the sums and the window count disagree (RMS >= 0, TIC in [0, 1])")
        return sums


TIC_ROUNDING = 1e-9
"""How far above 1 a mean TIC read back may lie: a window's TIC is 1 + 2e-16 for some predictions (float rounding)."""


def count(value, where: str, least: int = 0) -> int:
    """A count of a results document (windows, starts, horizons): a whole JSON number >= ``least`` and below 2^53;
    ValueError naming ``where`` otherwise (a merge took -5 windows and printed TIC -0.5, truncated 1.5 to 1)."""
    if isinstance(value, bool) or not isinstance(value, int) or not least <= value < 2**53:
        raise ValueError(f"{where} is {value!r}, not a whole number >= {least}")
    return value


def duration(value, where: str) -> float:
    """A flight's duration of a results document [s]: a finite JSON number >= 0; ValueError naming ``where`` otherwise."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0 <= value < math.inf:
        raise ValueError(f"{where} is {value!r}, not a duration >= 0 s")
    return float(value)


@dataclass
class MultistepSums:
    """Multi-step statistics of the span ``span``: S starts and, per model that has a multi-step form,
    the (4, H) sums of S_g MAE_h(g) over segments g (module docstring); how each model predicted
    (``forms``) and the models left out with the reason (``not_multistep``); ``ground_starts``: how many of the S
    starts' rows s..s+H touch the ground (scored as the rest; no model here has ground contact; absent in statistics
    files before session 34, read as 0)."""

    span: str
    max_horizon: int
    order: list[str]  # models in table order (naive first)
    starts: int = 0
    error_sums: dict[str, ExactSum] = field(default_factory=dict)
    forms: dict[str, str] = field(default_factory=dict)
    not_multistep: dict[str, str] = field(default_factory=dict)
    ground_starts: int = 0

    def empty_like(self) -> MultistepSums:
        """The statistics of no flight for the same span, horizon and models (the start of a merge)."""
        return MultistepSums(self.span, self.max_horizon, list(self.order))

    def add_segment(self, model: str, mae: np.ndarray, starts: int) -> None:
        """Add the MAE_h (4, H) of ``model`` over the ``starts`` starts of one segment (the pooled term S_g MAE_h(g))."""
        self.error_sums.setdefault(model, ExactSum()).add(np.asarray(mae, dtype=float) * starts)

    def mae(self, model: str) -> np.ndarray:
        """MAE_h (4, H) of ``model`` over every start: exact error sum / S (zeros for a model with no segment)."""
        if model not in self.error_sums:
            return np.zeros((4, self.max_horizon))
        return self.error_sums[model].mean(self.starts)

    def merge(self, other: MultistepSums) -> None:
        """Add ``other``'s starts (a later flight's)."""
        self.starts += other.starts
        self.ground_starts += other.ground_starts
        for name in other.order:  # table order
            if name in other.error_sums:
                self.error_sums.setdefault(name, ExactSum()).merge(other.error_sums[name])
        self.forms.update(other.forms)
        self.not_multistep.update(other.not_multistep)

    def to_json(self) -> dict:
        return {"span": self.span, "max_horizon": self.max_horizon, "order": list(self.order), "starts": self.starts,
                "error_sums": {m: s.to_json() for m, s in self.error_sums.items()},
                "forms": dict(self.forms), "not_multistep": dict(self.not_multistep), "ground_starts": self.ground_starts}

    @classmethod
    def from_json(cls, data: dict, where: str) -> MultistepSums:
        sums = {m: ExactSum.from_json(s, f"{where}.error_sums.{m}") for m, s in data["error_sums"].items()}
        max_horizon = count(data["max_horizon"], f"{where}.max_horizon", least=1)
        starts = count(data["starts"], f"{where}.starts")
        for m, s in sums.items():
            if s.shape != (4, max_horizon):
                raise DataError(f"{where}.error_sums.{m}: shape {s.shape}, expected (4, {max_horizon})")
            mae = s.mean(max(starts, 1))
            if np.any(mae < 0) or (not starts and np.any(mae != 0)):  # a sum of absolute errors: >= 0, 0 over no start
                raise DataError(f"{where}.error_sums.{m}: sums of absolute errors below 0 or over {starts} starts: they and the "
                                "start count disagree")
        return cls(str(data["span"]), max_horizon, [str(m) for m in data["order"]], starts, sums,
                   dict(data["forms"]), dict(data["not_multistep"]), count(data.get("ground_starts", 0), f"{where}.ground_starts"))


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
    vehicle_numbers: dict[str, float] | None = None
    """Every number of the vehicle the models were run with (:meth:`~quad_modelling.core.vehicle.VehicleConfig.numbers`);
    None where it is not known (the live evaluator scores predictors that loaded their own vehicle files)."""
    model_files: dict[str, str] | None = None
    """The SHA-256 of each file-backed model's file, by model name (two ``narx`` of different files differ)."""
    model_specs: dict[str, str] | None = None
    """The spec of each model given a name (``--model NAME=SPEC``), by name: tables.md's ``Models:`` line after a
    merge or run-bag, which read the statistics only."""

    @classmethod
    def empty(cls, vehicle: str, models: list[str], spans: list[str], multistep: MultistepSums | None,
              vehicle_numbers: dict[str, float] | None = None) -> EvaluationStatistics:
        """No flight yet: every sum zero (the start of every merge)."""
        return cls(vehicle, list(models), {m: {s: WindowSums() for s in spans} for m in models}, multistep,
                   vehicle_numbers=vehicle_numbers)

    def empty_like(self, spans: list[str]) -> EvaluationStatistics:
        """The statistics of no flight for the same models, vehicle and multi-step table, with ``spans`` in order."""
        empty = EvaluationStatistics.empty(self.vehicle, self.models, spans, None if self.multistep is None else self.multistep.empty_like(),
                                           self.vehicle_numbers)
        empty.model_files, empty.model_specs = self.model_files, self.model_specs
        return empty

    def vehicle_difference(self, other: EvaluationStatistics) -> str | None:
        """The first number in which the two evaluations' vehicles differ (``NAME A vs B``), or None when they agree
        or either is not known."""
        if self.vehicle_numbers is None or other.vehicle_numbers is None:
            return None
        for name in dict.fromkeys([*self.vehicle_numbers, *other.vehicle_numbers]):
            mine, theirs = self.vehicle_numbers.get(name), other.vehicle_numbers.get(name)
            if mine != theirs and not (mine is not None and theirs is not None and math.isnan(mine) and math.isnan(theirs)):
                return f"{name} {'absent' if mine is None else f'{mine:.6g}'} vs {'absent' if theirs is None else f'{theirs:.6g}'}"
        return None

    def model_file_difference(self, other: EvaluationStatistics) -> str | None:
        """The name of the first model whose file differs between the two evaluations (by content), or None."""
        if self.model_files is None or other.model_files is None:
            return None
        return next((m for m in self.models if self.model_files.get(m) != other.model_files.get(m)), None)

    def model_spec_difference(self, other: EvaluationStatistics) -> str | None:
        """``NAME (SPEC vs SPEC)`` of the first named model whose spec differs in kind or, for a model without a file
        (greybox, naive, physics:L,A), in its text; None when they agree or either is not known. A file's path may
        differ (:meth:`model_file_difference` compares the contents): ``m=greybox`` and ``m=naive`` merged as one."""
        mine, theirs = self.model_specs or {}, other.model_specs or {}
        for name in (n for n in self.models if n in mine and n in theirs):
            a, b = mine[name], theirs[name]
            files = self.model_files is not None and name in self.model_files
            if (a.partition(":")[0] != b.partition(":")[0]) if files else a != b:
                return f"{name} ({a} vs {b})"
        return None

    def merge(self, other: EvaluationStatistics) -> None:
        """Add a later flight's (or a later evaluation's) statistics: the one merge (module docstring)."""
        if other.vehicle != self.vehicle:
            raise DataError(f"cannot merge an evaluation on vehicle {other.vehicle!r} into one on {self.vehicle!r}")
        difference = self.vehicle_difference(other)
        if difference:
            raise DataError(f"cannot merge evaluations of vehicle {self.vehicle!r} run with different constants ({difference})")
        if other.models != self.models:  # before their files: a model both hold
            raise DataError(f"cannot merge the statistics of models {other.models} into those of {self.models}")
        difference = self.model_file_difference(other)
        if difference:
            raise DataError(f"cannot merge evaluations whose model {difference} was loaded from different files")
        spec = self.model_spec_difference(other)
        if spec:
            raise DataError(f"cannot merge evaluations whose model {spec} is another model in each")
        for model, spans in other.windowed.items():
            for span, sums in spans.items():
                self.windowed[model].setdefault(span, WindowSums()).merge(sums)
        if (self.multistep is None) != (other.multistep is None):
            raise DataError("cannot merge an evaluation with a multi-step table and one without (--no-multistep)")
        if self.multistep is not None:
            self.multistep.merge(other.multistep)
        self.durations.extend(other.durations)
        if other.model_specs:  # a name's model agrees (above); a file's path may differ: the first one said
            self.model_specs = {**other.model_specs, **(self.model_specs or {})}

    @property
    def windows(self) -> int:
        """Windows scored over every span (each model scores every window)."""
        return sum(s.windows for s in self.windowed[self.models[0]].values())

    def to_json(self) -> dict:
        return {"version": STATISTICS_VERSION, "vehicle": self.vehicle, "models": list(self.models),
                "windowed": {m: {s: sums.to_json() for s, sums in spans.items()} for m, spans in self.windowed.items()},
                "multistep": None if self.multistep is None else self.multistep.to_json(),
                "durations_s": list(self.durations),
                **({} if self.vehicle_numbers is None else {"vehicle_numbers": dict(self.vehicle_numbers)}),
                **({} if self.model_files is None else {"model_files": dict(self.model_files)}),
                **({} if not self.model_specs else {"model_specs": dict(self.model_specs)})}

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
            numbers = data.get("vehicle_numbers")  # absent in results written before it was kept
            stats = cls(str(data["vehicle"]), [str(m) for m in data["models"]], windowed, multistep,
                        [duration(d, f"{where}.durations_s[{i}]") for i, d in enumerate(data["durations_s"])],
                        None if numbers is None else {str(k): float(v) for k, v in numbers.items()})
            files = data.get("model_files")
            stats.model_files = None if files is None else {str(k): str(v) for k, v in files.items()}
            specs = data.get("model_specs")  # absent in results written before it was kept, or without a named model
            stats.model_specs = None if specs is None else {str(k): str(v) for k, v in specs.items()}
        except (KeyError, TypeError, AttributeError, ValueError) as err:
            if isinstance(err, DataError):
                raise
            raise DataError(f"{where}: malformed statistics ({type(err).__name__}: {err})") from err
        if set(stats.windowed) != set(stats.models):
            raise DataError(f"{where}: windowed statistics of models {sorted(stats.windowed)}, the document names {stats.models}")
        return stats
