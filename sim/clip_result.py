"""The result of simulating one clip: `Evaluation` (the scores and outcome) with its optional
`Traces` and joint `States` (1 kHz) and replay `Frames`; all but the states JSON-serialisable
by `to_dict`."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, fields
from typing import Any

import numpy as np


@dataclass
class Traces:
    """Per-step traces (one row per 1 ms step). Positions are world x in metres."""

    t: np.ndarray  # s
    cp: np.ndarray  # centre of pressure x, NaN where no foot touches the ground
    support: np.ndarray  # support centre x
    cm: np.ndarray  # (n, 2) centre of mass x, y
    cm_ref: np.ndarray  # (n, 2) controller's CM reference x, y (support centre + CMRT)
    error: np.ndarray  # cp - support, NaN where no contact
    normal: np.ndarray  # N, total normal force of the feet's ground contacts

    def to_dict(self) -> dict[str, list]:
        def clean(a: np.ndarray) -> list:
            return [None if (isinstance(v, float) and v != v) else v for v in a.tolist()]

        return {k: clean(np.asarray(v)) for k, v in asdict(self).items()}

    def to_csv(self, path: str) -> None:
        header = "t,cp,support,cm_x,cm_y,cm_ref_x,cm_ref_y,error,normal"
        table = np.column_stack(
            [self.t, self.cp, self.support, self.cm, self.cm_ref, self.error, self.normal]
        )
        np.savetxt(path, table, delimiter=",", header=header, comments="", fmt="%.6g")


@dataclass
class States:
    """The character's generalised coordinates at the start of every 1 ms step (row k is the
    state at t[k] = k x DT, before step k acts; Traces row k ends one step later).

    q[k] = [root x, root y (m, the root segment's CoM), root angle, hinge angles (rad, child
    relative to parent, the character's hinge order)], as `sim.physics.Physics.read_state`.
    """

    t: np.ndarray  # (n,) s
    q: np.ndarray  # (n, ndof)


@dataclass
class Frames:
    """Poses for replay, sampled every `1 / rate` s (row i is at time t[i]).

    poses[i][j] = (x, y, angle) in m and rad of the CoM of body or prop `names[j]` (the
    character's bodies in file order, then every prop and its chain links). cm, cm_ref: (x, y);
    cp: centre of pressure x (None without foot contact); support: (back edge x, front edge x).
    """

    rate: float  # Hz
    names: list[str]
    t: list[float]
    poses: list[list[tuple[float, float, float]]]
    cm: list[tuple[float, float]]
    cm_ref: list[tuple[float, float]]
    cp: list[float | None]
    support: list[tuple[float, float]]

    def to_dict(self) -> dict[str, Any]:
        def clean(v: Any) -> Any:
            if isinstance(v, float):
                return None if v != v else v
            if isinstance(v, list | tuple):
                return [clean(x) for x in v]
            return v

        return {k: clean(v) for k, v in asdict(self).items()}


@dataclass
class Evaluation:
    """Outcome of one clip.

    objective: 2-norm (metres) of the CP error e = cp - support centre sampled every step,
        no-contact steps left out. A fall replaces it by a penalty larger than any non-fall
        objective (see sim.rollout.fall_penalty), so every fall ranks worse than every non-fall.
    error_norm: the 2-norm of the error actually accumulated until the clip ended (or fell).
    fall_direction: "forward" or "backward" (where the CM's capture point c_x + cd_x
        sqrt(c_y / g) was relative to the support centre at the fall), None without a fall.
    task_success: the task's own goal (ball held at the end, ...), None for tasks that have
        none beyond balance. task_penalty: what the task added to the objective (0 if nothing).
    cut: stopped early as a certain last of its generation (see `sim.rollout.Rollout.run`).
    cmrt_released_at: when (s) the rollout released the CMRT because the task reported that
        the interaction it anticipates did not happen (`Task.interaction_failed`); None if it
        was held to the end (or there was none).
    """

    objective: float
    fell: bool
    fall_time: float | None  # s from clip start
    fall_reason: str | None
    error_norm: float  # m
    max_abs_error: float  # m
    sim_seconds: float
    cpu_seconds: float
    steps: int
    contact_steps: int
    fall_direction: str | None = None
    task_success: bool | None = None
    task_penalty: float = 0.0
    #: The run was stopped early by `stop_above` (sim.rollout): `objective` is then a lower
    #: bound of the clip's objective, not its value.
    cut: bool = False
    cmrt_released_at: float | None = None
    traces: Traces | None = field(default=None, repr=False)
    frames: Frames | None = field(default=None, repr=False)
    #: The 1 kHz joint states (recorded with the traces; what `sim.export` writes).
    states: States | None = field(default=None, repr=False)

    def to_dict(self, include_traces: bool = False) -> dict[str, Any]:
        """JSON-ready; with include_traces also `traces` and `frames` (when recorded). The
        1 kHz `states` are not part of it: `sim.export` writes them as BVH or CSV."""
        d = {f.name: getattr(self, f.name) for f in fields(self)
             if f.name not in ("traces", "frames", "states")}
        if include_traces and self.traces is not None:
            d["traces"] = self.traces.to_dict()
        if include_traces and self.frames is not None:
            d["frames"] = self.frames.to_dict()
        return d
