"""Task specs: the one validated model shared by the CLI, the optimiser and the HTTP API.

A spec describes one clip: a preparation window (where anticipation happens), a task window
(a pose change, a push, ...) and a decay window, plus the controller settings, the CMRT
parameterisation and the optimiser settings. Specs are read from YAML or JSON; every field is
checked and unknown fields are rejected, so a typo is an error naming the field.

Units: seconds, metres, newtons, kilograms; joint angles in specs are in degrees.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated, Any, Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from sim.errors import SpecError

#: Hinge names of the planar humanoid (the coordinate order is the character file's).
HINGE_NAMES: tuple[str, ...] = (
    "hip_r", "knee_r", "ankle_r", "hip_l", "knee_l", "ankle_l",
    "waist", "neck", "shoulder_r", "elbow_r", "shoulder_l", "elbow_l",
)

#: Names accepted in controller overrides and gain schedules (see sim.controller.ControllerParams).
GAIN_NAMES: tuple[str, ...] = ("k_l", "d_l", "d_l_vertical", "k_t", "d_t", "b_l", "b_h", "b_t",
                               "b_p", "cop_box")

MAX_CLIP_SECONDS = 20.0
MAX_FORCE_N = 5000.0


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class CharacterRef(_Strict):
    """Which character, scaled to a height (m) and mass (kg)."""

    model: Literal["humanoid"] = "humanoid"
    height: Annotated[float, Field(gt=1.0, le=2.5)] = 1.75
    mass: Annotated[float, Field(gt=20.0, le=250.0)] = 70.0


class Clip(_Strict):
    """Clip timing in seconds: preparation, then the task window, then decay."""

    preparation: Annotated[float, Field(ge=0.0, le=10.0)] = 1.0
    duration: Annotated[float, Field(gt=0.0, le=10.0)]
    decay: Annotated[float, Field(ge=0.0, le=10.0)] = 1.0

    @property
    def task_start(self) -> float:
        return self.preparation

    @property
    def task_end(self) -> float:
        return self.preparation + self.duration

    @property
    def length(self) -> float:
        return self.preparation + self.duration + self.decay

    @model_validator(mode="after")
    def _bounded(self) -> Clip:
        if self.length > MAX_CLIP_SECONDS:
            raise ValueError(f"clip length {self.length:g} s exceeds {MAX_CLIP_SECONDS:g} s")
        return self


def _check_pose(pose: dict[str, float]) -> dict[str, float]:
    for name, deg in pose.items():
        if name not in HINGE_NAMES:
            raise ValueError(f"unknown joint {name!r}; joints are {', '.join(HINGE_NAMES)}")
        if not -180.0 <= deg <= 180.0:
            raise ValueError(f"joint {name!r}: {deg} degrees is outside [-180, 180]")
    return pose


class Motion(_Strict):
    """A pose change: ease-in-ease-out from the current target to `target` over `duration`.

    `target` maps hinge names to angles in degrees relative to the standing pose; joints not
    named keep their previous target. `start` is seconds from the clip's start.
    `cmrt` optionally names a result file whose CMRT is superposed for this motion.
    """

    target: dict[str, float]
    start: Annotated[float, Field(ge=0.0)]
    duration: Annotated[float, Field(gt=0.0, le=10.0)]
    cmrt: str | None = None

    @field_validator("target")
    @classmethod
    def _pose(cls, v: dict[str, float]) -> dict[str, float]:
        return _check_pose(v)


class PoseChange(_Strict):
    """A single pose change over the clip's task window."""

    target: dict[str, float]

    @field_validator("target")
    @classmethod
    def _pose(cls, v: dict[str, float]) -> dict[str, float]:
        return _check_pose(v)


class Push(_Strict):
    """A horizontal external force (N) on a body from `start` (s from clip start), `duration` s."""

    force: Annotated[float, Field(gt=0.0, le=MAX_FORCE_N)]
    direction: Literal["forward", "backward"] = "forward"
    body: Literal["trunk", "pelvis", "head"] = "trunk"
    start: Annotated[float, Field(ge=0.0)] | None = None
    duration: Annotated[float, Field(gt=0.0, le=5.0)] | None = None


class GainSchedule(_Strict):
    """Ease-in-ease-out change of controller gains and weights (paper 6.3.2).

    `scale` multiplies the named parameters (1.15 is "+15 %"); `set` moves them to a value
    (for one whose default is 0, such as the CoP weight b_p). The window defaults to the task
    window; `ramp` is the ease time in seconds at each end of the window.
    """

    scale: dict[str, Annotated[float, Field(gt=0.0, le=20.0)]] = {}
    set: dict[str, Annotated[float, Field(ge=0.0, le=1e4)]] = {}
    start: Annotated[float, Field(ge=0.0)] | None = None
    end: Annotated[float, Field(ge=0.0)] | None = None
    ramp: Annotated[float, Field(ge=0.0, le=5.0)] = 0.1

    @field_validator("scale", "set")
    @classmethod
    def _names(cls, v: dict[str, float]) -> dict[str, float]:
        for name in v:
            if name not in GAIN_NAMES:
                raise ValueError(f"unknown gain {name!r}; gains are {', '.join(GAIN_NAMES)}")
        return v

    @model_validator(mode="after")
    def _changes_something(self) -> GainSchedule:
        if not self.scale and not self.set:
            raise ValueError("a schedule entry needs `scale` or `set`")
        both = sorted(set(self.scale) & set(self.set))
        if both:
            raise ValueError(f"{', '.join(both)}: in both `scale` and `set`")
        return self


class CmrtConfig(_Strict):
    """How a parameter vector in [0, 1]^d decodes into a CMRT spline (see optim.spline)."""

    knots: Annotated[int, Field(ge=1, le=16)] = 4
    vertical: bool = False
    max_displacement: Annotated[float, Field(gt=0.0, le=0.5)] = 0.15
    max_vertical: Annotated[float, Field(gt=0.0, le=0.3)] = 0.08


class OptimizeConfig(_Strict):
    """CMA-ES settings and the paper's stopping rules."""

    threshold: Annotated[float, Field(gt=0.0)] | None = None
    sigma0: Annotated[float, Field(gt=0.0, le=1.0)] = 0.2
    popsize: Annotated[int, Field(ge=2, le=200)] | None = None
    min_evaluations: Annotated[int, Field(ge=0)] = 700
    max_evaluations: Annotated[int, Field(ge=1, le=100_000)] = 2000
    window: Annotated[int, Field(ge=1)] = 100
    improvement: Annotated[float, Field(gt=0.0, lt=1.0)] = 0.05


class TaskSpec(_Strict):
    """One task clip. See examples/*.yaml."""

    name: Annotated[str, Field(min_length=1, max_length=100, pattern=r"^[A-Za-z0-9_.\-]+$")]
    task: Literal["quiet_stance", "push", "pose_change", "sequence"]
    family: Annotated[str, Field(min_length=1, max_length=100)] | None = None
    character: CharacterRef = CharacterRef()
    clip: Clip
    pose_change: PoseChange | None = None
    push: Push | None = None
    motions: Annotated[list[Motion], Field(max_length=32)] | None = None
    controller: dict[str, Annotated[float, Field(gt=0.0, le=1e4)]] = {}
    schedule: Annotated[list[GainSchedule], Field(max_length=16)] = []
    cmrt: CmrtConfig = CmrtConfig()
    optimize: OptimizeConfig = OptimizeConfig()

    @field_validator("controller")
    @classmethod
    def _gain_names(cls, v: dict[str, float]) -> dict[str, float]:
        for name in v:
            if name not in GAIN_NAMES:
                raise ValueError(f"unknown gain {name!r}; gains are {', '.join(GAIN_NAMES)}")
        return v

    @model_validator(mode="after")
    def _task_block(self) -> TaskSpec:
        need = {"push": "push", "pose_change": "pose_change", "sequence": "motions"}.get(self.task)
        for block in ("push", "pose_change", "motions"):
            present = getattr(self, block) is not None
            if block == need and not present:
                raise ValueError(f"task {self.task!r} needs a {block!r} block")
            if block != need and present:
                raise ValueError(f"{block!r} is not allowed for task {self.task!r}")
        if self.push is not None:
            start, dur = self.push_window()
            if start + dur > self.clip.length + 1e-9:
                raise ValueError("push: start + duration exceeds the clip length")
        for i, m in enumerate(self.motions or []):
            if m.start + m.duration > self.clip.length + 1e-9:
                raise ValueError(f"motions[{i}]: start + duration exceeds the clip length")
        for i, s in enumerate(self.schedule):
            a, b = self.schedule_window(s)
            if b <= a:
                raise ValueError(f"schedule[{i}]: end must be after start")
        return self

    # ---- derived quantities -------------------------------------------------------------
    @property
    def family_name(self) -> str:
        """The library family: `family` if given, else the spec's name without a trailing tag."""
        return self.family or self.name

    def push_window(self) -> tuple[float, float]:
        """(start, duration) of the push in seconds; defaults to the task window."""
        assert self.push is not None
        start = self.push.start if self.push.start is not None else self.clip.task_start
        dur = self.push.duration if self.push.duration is not None else self.clip.duration
        return start, dur

    def schedule_window(self, s: GainSchedule) -> tuple[float, float]:
        start = s.start if s.start is not None else self.clip.task_start
        end = s.end if s.end is not None else self.clip.task_end
        return start, end

    def task_parameters(self) -> dict[str, float]:
        """The numbers that place this task within its family (library keys)."""
        params: dict[str, float] = {"duration": self.clip.duration}
        if self.push is not None:
            sign = 1.0 if self.push.direction == "forward" else -1.0
            params["force"] = sign * self.push.force
        return params

    @property
    def cmrt_dimension(self) -> int:
        """Length of the parameter vector: knot times and control values (x, and y if vertical)."""
        per_knot = 3 if self.cmrt.vertical else 2
        return per_knot * self.cmrt.knots


def _format_error(err: ValidationError) -> str:
    lines = []
    for e in err.errors():
        loc = ".".join(str(p) for p in e["loc"]) or "<spec>"
        msg = e["msg"].removeprefix("Value error, ")
        lines.append(f"{loc}: {msg}")
    return "; ".join(lines)


def parse_spec(data: Any, source: str = "<spec>") -> TaskSpec:
    """Validate a mapping into a TaskSpec, raising SpecError naming each bad field and rule."""
    if not isinstance(data, dict):
        raise SpecError(f"{source}: a spec must be a mapping, got {type(data).__name__}")
    try:
        return TaskSpec.model_validate(data)
    except ValidationError as err:
        raise SpecError(f"{source}: {_format_error(err)}") from None


def load_spec(path: str | Path) -> TaskSpec:
    """Read a YAML or JSON spec file."""
    p = Path(path)
    try:
        text = p.read_text()
    except OSError as err:
        raise SpecError(f"{p}: cannot read spec ({err.strerror})") from None
    try:
        data = json.loads(text) if p.suffix == ".json" else yaml.safe_load(text)
    except (yaml.YAMLError, json.JSONDecodeError) as err:
        kind = "JSON" if p.suffix == ".json" else "YAML"
        raise SpecError(f"{p}: not valid {kind}: {err}") from None
    return parse_spec(data, str(p))
