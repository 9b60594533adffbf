"""The result of simulating one clip: `Evaluation`, JSON-serialisable."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
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

    def to_dict(self) -> dict[str, list]:
        def clean(a: np.ndarray) -> list:
            return [None if (isinstance(v, float) and v != v) else v for v in a.tolist()]

        return {k: clean(np.asarray(v)) for k, v in asdict(self).items()}

    def to_csv(self, path: str) -> None:
        header = "t,cp,support,cm_x,cm_y,cm_ref_x,cm_ref_y,error"
        table = np.column_stack(
            [self.t, self.cp, self.support, self.cm, self.cm_ref, self.error]
        )
        np.savetxt(path, table, delimiter=",", header=header, comments="", fmt="%.6g")


@dataclass
class Evaluation:
    """Outcome of one clip.

    objective: 2-norm (metres) of the CP error e = cp - support centre sampled every step,
        no-contact steps left out. A fall replaces it by a penalty larger than any non-fall
        objective (see sim.clip.fall_penalty), so every fall ranks worse than every non-fall.
    error_norm: the 2-norm of the error actually accumulated until the clip ended (or fell).
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
    traces: Traces | None = field(default=None, repr=False)

    def to_dict(self, include_traces: bool = False) -> dict[str, Any]:
        d = {k: v for k, v in asdict(self).items() if k != "traces"}
        if include_traces and self.traces is not None:
            d["traces"] = self.traces.to_dict()
        return d
