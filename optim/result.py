"""`OptimizationResult`: what one optimisation produced, as a JSON document.

File format (JSON object, `format` = "cmrt-result/1"); units: seconds, metres.
    spec                 the task spec (dict, as validated by sim.spec)
    dimension            length of `params` (spec.cmrt_dimension)
    params               best parameter vector in [0, 1]^dimension (see optim.spline)
    length               clip length (s); knot_times (s), values (m), vertical_values (m|null)
    curve                {"t": [...], "dx": [...](, "dy": [...])}: 100 samples of the CMRT
    objective, fell                      best CMRT, re-evaluated at the end
    fall_direction, task_success         its fall's direction ("forward" | "backward" | null)
                                         and the task's goal (true | false | null: no goal)
    baseline_objective, baseline_fell    the same clip without CMRT (flat spline)
    baseline_fall_direction, baseline_task_success   likewise (the last four optional: absent
                                         in files written before they existed, read as null)
    evaluations, iterations, stop_rule, wall_seconds, seed
    history              per generation: iteration, evaluations, best, median, worst, sigma,
                         best_so_far
    basis_id             id of the PCA basis if optimised in a reduced space, else null
    reduced_params       the best point in the reduced search box [0, 1]^k, else null
    robust               a robust spec's (absent otherwise): vary ({path: [lo, hi]}), samples,
                         aggregate, and per variant (`sim.robust.variant_values` order) of the
                         best CMRT (`variants`) and the flat spline (`baseline_variants`):
                         values, objective, fell, fall_time, fall_direction, task_success

`save` writes atomically (temp file, fsync, rename). `load`/`from_dict` check every field and
raise `ResultFileError` naming the file and the field for missing, mistyped or inconsistent data.
"""

from __future__ import annotations

import copy
import json
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from optim._io import atomic_write_text, read_json_file
from optim.errors import ParamsError, ResultFileError
from optim.spline import CmrtSpline, check_params, decode, sample_curve

RESULT_FORMAT = "cmrt-result/1"
#: The values a fall direction takes (sim.clip_result.Evaluation.fall_direction).
FALL_DIRECTIONS = ("forward", "backward")


def _num(v: Any) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)


def _int(v: Any) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _num_list(v: Any) -> bool:
    return isinstance(v, list) and all(_num(x) for x in v)


def _opt(check: Callable[[Any], bool]) -> Callable[[Any], bool]:
    return lambda v: v is None or check(v)


_FIELDS: dict[str, tuple[Callable[[Any], bool], str]] = {
    "spec": (lambda v: isinstance(v, dict), "an object (the task spec)"),
    "dimension": (lambda v: _int(v) and v >= 1, "a positive integer"),
    "params": (_num_list, "a list of numbers"),
    "length": (lambda v: _num(v) and v > 0, "a positive number of seconds"),
    "knot_times": (_num_list, "a list of numbers (seconds)"),
    "values": (_num_list, "a list of numbers (metres)"),
    "vertical_values": (_opt(_num_list), "null or a list of numbers (metres)"),
    "curve": (lambda v: isinstance(v, dict), "an object with lists t and dx"),
    "objective": (_num, "a finite number"),
    "fell": (lambda v: isinstance(v, bool), "true or false"),
    "baseline_objective": (_num, "a finite number"),
    "baseline_fell": (lambda v: isinstance(v, bool), "true or false"),
    "evaluations": (lambda v: _int(v) and v >= 0, "a non-negative integer"),
    "iterations": (lambda v: _int(v) and v >= 0, "a non-negative integer"),
    "stop_rule": (lambda v: isinstance(v, str), "a string"),
    "wall_seconds": (lambda v: _num(v) and v >= 0, "a non-negative number"),
    "seed": (_int, "an integer"),
    "history": (lambda v: isinstance(v, list), "a list of per-generation objects"),
    "basis_id": (_opt(lambda v: isinstance(v, str)), "null or a string"),
    "reduced_params": (_opt(_num_list), "null or a list of numbers"),
    "fall_direction": (_opt(lambda v: v in FALL_DIRECTIONS), 'null, "forward" or "backward"'),
    "task_success": (_opt(lambda v: isinstance(v, bool)), "null, true or false"),
    "baseline_fall_direction": (_opt(lambda v: v in FALL_DIRECTIONS),
                                'null, "forward" or "backward"'),
    "baseline_task_success": (_opt(lambda v: isinstance(v, bool)), "null, true or false"),
    "robust": (_opt(lambda v: isinstance(v, dict) and isinstance(v.get("variants"), list)
                    and all(isinstance(r, dict) and _num(r.get("objective"))
                            for r in v["variants"])),
               "null or an object whose variants list each has a numeric objective"),
}
_OPTIONAL = {"vertical_values", "basis_id", "reduced_params", "history", "fall_direction",
             "task_success", "baseline_fall_direction", "baseline_task_success", "robust"}
_HISTORY_KEYS = ("iteration", "evaluations", "best", "median", "worst", "sigma", "best_so_far")


@dataclass
class OptimizationResult:
    """One optimisation's outcome (see module docstring for the fields and units)."""

    spec: dict[str, Any]
    dimension: int
    params: list[float]
    length: float
    knot_times: list[float]
    values: list[float]
    vertical_values: list[float] | None
    curve: dict[str, list[float]]
    objective: float
    fell: bool
    baseline_objective: float
    baseline_fell: bool
    evaluations: int
    iterations: int
    stop_rule: str
    wall_seconds: float
    seed: int
    history: list[dict[str, Any]] = field(default_factory=list)
    basis_id: str | None = None
    reduced_params: list[float] | None = None
    fall_direction: str | None = None
    task_success: bool | None = None
    baseline_fall_direction: str | None = None
    baseline_task_success: bool | None = None
    robust: dict[str, Any] | None = None

    @classmethod
    def build(
        cls,
        spec: Any,
        params: Sequence[float] | np.ndarray,
        *,
        objective: float,
        fell: bool = False,
        baseline_objective: float,
        baseline_fell: bool = False,
        evaluations: int = 0,
        iterations: int = 0,
        stop_rule: str = "",
        wall_seconds: float = 0.0,
        seed: int = 0,
        history: Sequence[Mapping[str, Any]] = (),
        basis_id: str | None = None,
        reduced_params: Sequence[float] | None = None,
        fall_direction: str | None = None,
        task_success: bool | None = None,
        baseline_fall_direction: str | None = None,
        baseline_task_success: bool | None = None,
        robust: Mapping[str, Any] | None = None,
    ) -> OptimizationResult:
        """A result for `spec` (a TaskSpec, or a `sim.spec.CanonicalSpec` whose document it
        keeps without dumping the spec again) whose best CMRT is `params` (spline data
        derived)."""
        from sim.spec import CanonicalSpec  # loaded already: `spec` is one of its types

        if isinstance(spec, CanonicalSpec):
            document, spec = spec.document, spec.spec
        else:
            document = spec.model_dump(mode="json")
        p = check_params(spec, params)
        spline = decode(spec, p)
        result = cls(
            spec=copy.deepcopy(dict(document)),
            dimension=spec.cmrt_dimension,
            params=[float(v) for v in p],
            length=spline.length,
            knot_times=[float(v) for v in spline.knot_times],
            values=[float(v) for v in spline.values],
            vertical_values=None
            if spline.vertical_values is None
            else [float(v) for v in spline.vertical_values],
            curve=sample_curve(spline),
            objective=float(objective),
            fell=bool(fell),
            baseline_objective=float(baseline_objective),
            baseline_fell=bool(baseline_fell),
            evaluations=int(evaluations),
            iterations=int(iterations),
            stop_rule=stop_rule,
            wall_seconds=float(wall_seconds),
            seed=int(seed),
            history=[dict(h) for h in history],
            basis_id=basis_id,
            reduced_params=None if reduced_params is None else [float(v) for v in reduced_params],
            fall_direction=fall_direction,
            task_success=task_success,
            baseline_fall_direction=baseline_fall_direction,
            baseline_task_success=baseline_task_success,
            robust=None if robust is None else copy.deepcopy(dict(robust)),
        )
        result.__dict__["_task_spec"] = spec  # typed already: no parse on use
        return result

    # -- derived -------------------------------------------------------------------------------
    @property
    def name(self) -> str:
        return str(self.spec.get("name", ""))

    @property
    def family(self) -> str:
        """The spec's library family (its `family`, else its name)."""
        return str(self.spec.get("family") or self.spec.get("name", ""))

    @property
    def duration(self) -> float:
        """The clip's task duration (s)."""
        return float(self.spec["clip"]["duration"])

    @property
    def cmrt(self) -> dict[str, Any]:
        """The spec's `cmrt` block (how the params decode)."""
        return dict(self.spec.get("cmrt") or {})

    def task_spec(self) -> Any:
        """The spec as a validated `sim.spec.TaskSpec` (parsed on first use, then kept)."""
        typed = self.__dict__.get("_task_spec")
        if typed is None:
            from sim.spec import parse_spec

            typed = parse_spec(self.spec, f"result {self.name!r} spec")
            self.__dict__["_task_spec"] = typed
        return typed

    def task_parameters(self) -> dict[str, float]:
        """The spec's task parameters (e.g. {"duration": 0.4}), see TaskSpec.task_parameters."""
        return self.task_spec().task_parameters()

    def spline(self) -> CmrtSpline:
        """The best CMRT as a callable spline."""
        return CmrtSpline(self.length, self.knot_times, self.values, self.vertical_values)

    @property
    def params_array(self) -> np.ndarray:
        return np.asarray(self.params, dtype=float)

    @property
    def improvement(self) -> float:
        """Relative objective reduction versus the no-CMRT baseline (0.25 = 25 % lower)."""
        if self.baseline_objective == 0:
            return 0.0
        return (self.baseline_objective - self.objective) / abs(self.baseline_objective)

    # -- (de)serialisation -------------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        return {
            "format": RESULT_FORMAT,
            "spec": self.spec,
            "dimension": self.dimension,
            "params": [float(v) for v in self.params],
            "length": float(self.length),
            "knot_times": [float(v) for v in self.knot_times],
            "values": [float(v) for v in self.values],
            "vertical_values": None
            if self.vertical_values is None
            else [float(v) for v in self.vertical_values],
            "curve": self.curve,
            "objective": float(self.objective),
            "fell": bool(self.fell),
            "baseline_objective": float(self.baseline_objective),
            "baseline_fell": bool(self.baseline_fell),
            "evaluations": int(self.evaluations),
            "iterations": int(self.iterations),
            "stop_rule": self.stop_rule,
            "wall_seconds": float(self.wall_seconds),
            "seed": int(self.seed),
            "history": self.history,
            "basis_id": self.basis_id,
            "reduced_params": None
            if self.reduced_params is None
            else [float(v) for v in self.reduced_params],
            "fall_direction": self.fall_direction,
            "task_success": self.task_success,
            "baseline_fall_direction": self.baseline_fall_direction,
            "baseline_task_success": self.baseline_task_success,
            **({} if self.robust is None else {"robust": self.robust}),
        }

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=1, allow_nan=False)

    @classmethod
    def from_dict(cls, data: Any, source: str = "<result>") -> OptimizationResult:
        """Validate and build; a bad field raises ResultFileError naming `source` and the field."""
        if not isinstance(data, Mapping):
            raise ResultFileError(f"{source}: a result must be a JSON object")
        fmt = data.get("format", RESULT_FORMAT)
        if fmt != RESULT_FORMAT:
            raise ResultFileError(
                f"{source}: field 'format': unsupported {fmt!r} (expected {RESULT_FORMAT!r})"
            )
        for name, (check, what) in _FIELDS.items():
            if name not in data:
                if name in _OPTIONAL:
                    continue
                raise ResultFileError(f"{source}: missing field {name!r}")
            if not check(data[name]):
                raise ResultFileError(f"{source}: field {name!r} must be {what}")
        d = data
        if len(d["params"]) != d["dimension"]:
            raise ResultFileError(
                f"{source}: field 'params' has {len(d['params'])} numbers, "
                f"'dimension' says {d['dimension']}"
            )
        if any(not 0.0 <= v <= 1.0 for v in d["params"]):
            raise ResultFileError(f"{source}: field 'params' must lie in [0, 1]")
        curve = d["curve"]
        for key in ("t", "dx"):
            if not _num_list(curve.get(key)):
                raise ResultFileError(f"{source}: field 'curve.{key}' must be a list of numbers")
        for i, row in enumerate(d.get("history") or []):
            if not isinstance(row, Mapping) or not all(_num(row.get(k)) for k in _HISTORY_KEYS):
                raise ResultFileError(
                    f"{source}: field 'history[{i}]' needs numbers {', '.join(_HISTORY_KEYS)}"
                )
        res = cls(
            spec=dict(d["spec"]),
            dimension=int(d["dimension"]),
            params=[float(v) for v in d["params"]],
            length=float(d["length"]),
            knot_times=[float(v) for v in d["knot_times"]],
            values=[float(v) for v in d["values"]],
            vertical_values=None
            if d.get("vertical_values") is None
            else [float(v) for v in d["vertical_values"]],
            curve={k: list(v) for k, v in curve.items()},
            objective=float(d["objective"]),
            fell=bool(d["fell"]),
            baseline_objective=float(d["baseline_objective"]),
            baseline_fell=bool(d["baseline_fell"]),
            evaluations=int(d["evaluations"]),
            iterations=int(d["iterations"]),
            stop_rule=str(d["stop_rule"]),
            wall_seconds=float(d["wall_seconds"]),
            seed=int(d["seed"]),
            history=[dict(r) for r in d.get("history") or []],
            basis_id=d.get("basis_id"),
            reduced_params=None
            if d.get("reduced_params") is None
            else [float(v) for v in d["reduced_params"]],
            fall_direction=d.get("fall_direction"),
            task_success=d.get("task_success"),
            baseline_fall_direction=d.get("baseline_fall_direction"),
            baseline_task_success=d.get("baseline_task_success"),
            robust=None if d.get("robust") is None else dict(d["robust"]),
        )
        try:
            res.spline()
        except ParamsError as err:
            raise ResultFileError(
                f"{source}: fields 'knot_times'/'values'/'vertical_values'/'length' "
                f"do not form a valid spline: {err}"
            ) from None
        return res

    def save(self, path: str | Path) -> None:
        """Write the JSON file atomically."""
        atomic_write_text(path, self.to_json() + "\n")

    @classmethod
    def load(cls, path: str | Path) -> OptimizationResult:
        """Read and validate a result file (ResultFileError on any problem)."""
        return cls.from_dict(read_json_file(path, "result file"), str(path))


__all__ = ["RESULT_FORMAT", "OptimizationResult"]


def load_cmrt(path: str | Path) -> CmrtSpline:
    """The CMRT of a file: an optimisation result (`cmrt optimize --out`), an interpolation
    (`cmrt interpolate --out`) or a library answer (`cmrt library interpolate --out`), each
    of which carries the decoded spline (`length`, `knot_times`, `values`, optional
    `vertical_values`). ResultFileError naming the file and the field otherwise."""
    p = Path(path)
    data = read_json_file(p, "CMRT file")
    if isinstance(data, Mapping) and "spec" in data and "params" in data:
        return OptimizationResult.from_dict(data, str(p)).spline()
    if not isinstance(data, Mapping):
        raise ResultFileError(f"{p}: a CMRT file must be a JSON object")
    for name in ("length", "knot_times", "values"):
        if name not in data:
            raise ResultFileError(f"{p}: missing field {name!r} (a result, an interpolation "
                                  "or a library answer carries it)")
    if not _num(data["length"]) or data["length"] <= 0:
        raise ResultFileError(f"{p}: field 'length' must be a positive number")
    for name in ("knot_times", "values"):
        if not _num_list(data[name]) or len(data[name]) != len(data["knot_times"]):
            raise ResultFileError(f"{p}: field {name!r} must be a list of numbers, one per knot")
    vy = data.get("vertical_values")
    if vy is not None and (not _num_list(vy) or len(vy) != len(data["knot_times"])):
        raise ResultFileError(f"{p}: field 'vertical_values' must be null or one number per knot")
    return CmrtSpline(float(data["length"]), np.asarray(data["knot_times"], dtype=float),
                      np.asarray(data["values"], dtype=float),
                      None if vy is None else np.asarray(vy, dtype=float))
