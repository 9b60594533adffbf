"""Push grids: a push task's spec simulated at every force x duration x direction of a grid,
on the product's executors, and the envelope it shows (which pushes are survived).

Contracts:
  * `PushGrid(spec, forces, durations, directions)` checks the grid against the spec before
    anything is simulated: the spec's task is a push (`task.type`), every force and duration
    gives a valid spec (the push task's own ranges), and each duration leaves some of the
    spec's clip after the push. A bad grid raises `OptimError` naming the option and rule.
  * A cell's spec is the spec with `task.force`, `task.direction` and the clip's task window
    (`clip.duration`) set, the clip's length kept (its decay shortened or lengthened), so
    every cell is judged over the same time; the push acts over the task window
    (`task.start` and `task.duration` dropped). Nothing else of the spec changes: its
    character, controller (stepping or not) and gains are the spec's.
  * `PushCellObjective` is picklable (the base spec's canonical JSON) and evaluates one cell
    from its parameters [force N, duration s, +1 forward / -1 backward] in any process, with
    the process's spec cache (`optim.objective.SPECS`: the spec parsed and its simulator
    built by the product's own factories), no CMRT. Its outcome is a `CellOutcome`: the
    clip's `EvalOutcome` and the steps the controller took (None for a controller that does
    not step).
  * `run_grid(grid, executor)` evaluates every cell as one batch (`Executor.map`: in this
    process or in the process pool), results in the grid's order and independent of the
    number of workers.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from cmrt.canonical import canonical_json
from optim.errors import OptimError
from optim.executors import Executor
from optim.outcome import EvalOutcome
from sim.errors import SpecError
from sim.spec import TaskSpec, parse_spec

#: The directions of a push task, and their sign in a cell's parameters.
DIRECTIONS: dict[str, float] = {"forward": 1.0, "backward": -1.0}
#: s: the shortest decay a cell may keep after its push (the clip must go on after it to
#: judge whether it was survived).
MIN_DECAY = 0.1


@dataclass(frozen=True)
class CellOutcome(EvalOutcome):
    """One cell's outcome: the clip's `EvalOutcome` and `foot_steps`, the steps the
    controller took (None: a controller that does not step)."""

    foot_steps: int | None = None


def cell_document(base: dict[str, Any], force: float, duration: float,
                  direction: str) -> dict[str, Any]:
    """The spec document of one cell (see the module doc): `base` is a push spec's document."""
    doc = {**base, "task": dict(base["task"]), "clip": dict(base["clip"])}
    clip = doc["clip"]
    length = float(clip["preparation"]) + float(clip["duration"]) + float(clip["decay"])
    clip["duration"] = float(duration)
    clip["decay"] = length - float(clip["preparation"]) - float(duration)
    task = doc["task"]
    task.pop("start", None)
    task.pop("duration", None)
    task["force"] = float(force)
    task["direction"] = direction
    return doc


def spec_document(spec: TaskSpec) -> dict[str, Any]:
    """The spec as a document (what `parse_spec` reads back to the same spec)."""
    return spec.model_dump(mode="json", exclude_none=True)


@dataclass(frozen=True)
class Cell:
    force: float  # N
    duration: float  # s
    direction: str  # "forward" | "backward"

    def params(self) -> np.ndarray:
        return np.array([self.force, self.duration, DIRECTIONS[self.direction]])


class PushGrid:
    """The cells of a push grid over one spec (see the module doc)."""

    def __init__(self, spec: TaskSpec, forces: Sequence[float], durations: Sequence[float],
                 directions: Sequence[str] = ("forward", "backward")):
        if spec.task_type != "push":
            raise OptimError(f"task.type: a push grid needs a push task, got "
                             f"{spec.task_type!r}")
        if not forces:
            raise OptimError("--forces: no force in the grid")
        if not durations:
            raise OptimError("--durations: no duration in the grid")
        bad = [d for d in directions if d not in DIRECTIONS]
        if bad or not directions:
            raise OptimError(f"--directions: each must be forward or backward, got "
                             f"{list(directions)}")
        self.spec = spec
        self.base = spec_document(spec)
        clip = spec.clip
        self.length = clip.preparation + clip.duration + clip.decay
        for d in durations:
            if not math.isfinite(d) or d <= 0.0 or clip.preparation + d > self.length - MIN_DECAY:
                raise OptimError(
                    f"--durations: {d:g} s must be > 0 and leave at least {MIN_DECAY:g} s of "
                    f"the {self.length:g} s clip after the push (it starts at "
                    f"{clip.preparation:g} s)")
        self.forces = [float(f) for f in forces]
        self.durations = [float(d) for d in durations]
        self.directions = list(dict.fromkeys(directions))
        self.cells = [Cell(f, d, r) for r in self.directions for d in self.durations
                      for f in self.forces]
        # Every cell's spec is valid before anything runs (a force out of the push's range,
        # say): the message names the option and the spec's rule.
        for c in {(c.force, c.duration): c for c in self.cells}.values():
            try:
                parse_spec(cell_document(self.base, c.force, c.duration, c.direction))
            except SpecError as err:
                raise OptimError(f"--forces/--durations: {c.force:g} N x {c.duration:g} s: "
                                 f"{err}") from None

    def objective(self) -> PushCellObjective:
        return PushCellObjective(self.base)


class PushCellObjective:
    """Picklable: evaluates one cell of a push grid (see the module doc)."""

    def __init__(self, base: dict[str, Any]):
        self.base_json = canonical_json(base)
        self._base: dict[str, Any] | None = base

    def __getstate__(self) -> dict[str, str]:
        return {"base_json": self.base_json}

    def __setstate__(self, state: dict[str, str]) -> None:
        self.base_json = state["base_json"]
        self._base = None

    def __call__(self, params: Sequence[float] | np.ndarray) -> CellOutcome:
        import json

        from optim.objective import SPECS, _canonical

        if self._base is None:
            self._base = json.loads(self.base_json)
        force, duration, sign = (float(v) for v in params)
        doc = cell_document(self._base, force, duration,
                            "forward" if sign > 0.0 else "backward")
        canonical = _canonical(doc)
        sim = SPECS.simulator(canonical)
        ev = sim.run(None)
        return CellOutcome(
            objective=float(ev.objective), fell=bool(ev.fell), cpu_seconds=float(ev.cpu_seconds),
            sim_seconds=float(ev.sim_seconds),
            fall_time=None if ev.fall_time is None else float(ev.fall_time),
            fall_direction=ev.fall_direction, task_success=ev.task_success,
            foot_steps=sim.controller.foot_steps)


@dataclass(frozen=True)
class CellResult:
    cell: Cell
    outcome: EvalOutcome

    @property
    def survived(self) -> bool:
        return self.outcome.error is None and not self.outcome.fell

    @property
    def foot_steps(self) -> int | None:
        o = self.outcome  # a cell whose evaluation raised is a plain EvalOutcome
        return o.foot_steps if isinstance(o, CellOutcome) else None

    def to_dict(self) -> dict[str, Any]:
        o = self.outcome
        return {"force": self.cell.force, "duration": self.cell.duration,
                "direction": self.cell.direction, "survived": self.survived,
                "fell": o.fell, "fall_time": o.fall_time, "fall_direction": o.fall_direction,
                "foot_steps": self.foot_steps, "objective": o.objective, "error": o.error}


def run_grid(grid: PushGrid, executor: Executor) -> list[CellResult]:
    """Every cell of the grid, in its order (one batch on `executor`)."""
    outs = executor.map(grid.objective(), [c.params() for c in grid.cells])
    return [CellResult(c, o) for c, o in zip(grid.cells, outs, strict=True)]


def survived_ranges(forces: Sequence[float], survived: Sequence[bool]
                    ) -> list[tuple[float, float]]:
    """The survived forces as runs of consecutive grid points [(first, last), ...]."""
    out: list[tuple[float, float]] = []
    start: float | None = None
    prev: float | None = None
    for f, ok in zip(forces, survived, strict=True):
        if ok and start is None:
            start = f
        if not ok and start is not None:
            out.append((start, prev if prev is not None else start))
            start = None
        prev = f
    if start is not None and prev is not None:
        out.append((start, prev))
    return out


def cell_text(r: CellResult) -> str:
    """'stands, 3 steps' / 'fell 2.420 s backward, 3 steps' (steps left out when the
    controller does not step; an evaluation error is said as such)."""
    o = r.outcome
    if o.error is not None:
        return f"error: {o.error}"
    n = r.foot_steps
    steps = "" if n is None else f", {n} step{'' if n == 1 else 's'}"
    if not o.fell:
        return f"stands{steps}"
    when = "" if o.fall_time is None else f" {o.fall_time:.3f} s"
    return f"fell{when} {o.fall_direction or ''}".rstrip() + steps


def table(grid: PushGrid, results: Sequence[CellResult]) -> str:
    """The grid as a text table: one row per force, one column per direction and duration,
    then each column's survived forces as runs of grid points."""
    by = {(r.cell.direction, r.cell.duration, r.cell.force): r for r in results}
    cols = [(r, d) for r in grid.directions for d in grid.durations]
    heads = ["force N"] + [f"{r} {d:g} s" for r, d in cols]
    rows = [[f"{f:g}"] + [cell_text(by[(r, d, f)]) for r, d in cols] for f in grid.forces]
    widths = [max(len(x) for x in col) for col in zip(heads, *rows, strict=True)]

    def line(cells: list[str]) -> str:
        return "  ".join(c.ljust(w) for c, w in zip(cells, widths, strict=True)).rstrip()

    out = [line(heads), line(["-" * w for w in widths])] + [line(r) for r in rows]
    out.append("")
    for r, d in cols:
        ok = [by[(r, d, f)].survived for f in grid.forces]
        runs = survived_ranges(grid.forces, ok)
        text = ", ".join(f"{a:g}" if a == b else f"{a:g}-{b:g}" for a, b in runs) or "none"
        out.append(f"{r} {d:g} s: survived {sum(ok)} of {len(ok)}: {text} N")
    return "\n".join(out)


__all__ = ["DIRECTIONS", "MIN_DECAY", "Cell", "CellOutcome", "CellResult", "PushCellObjective",
           "PushGrid", "cell_document", "cell_text", "run_grid", "spec_document",
           "survived_ranges", "table"]
