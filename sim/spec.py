"""Task specs: the one validated model shared by the CLI, the optimiser and the HTTP API.

A spec describes one clip: a preparation window (where anticipation happens), a task window
(a pose change, a push, a catch ...) and a decay window, plus the controller settings, the CMRT
parameterisation and the optimiser settings. Specs are read from YAML or JSON; every field is
checked (strict types, finite numbers, no control characters: `sim.specbase`) and unknown
fields are rejected, so a typo is an error naming the field. Every rule the simulator relies on
(joint and body names of the character, windows inside the clip, the CoP box inside the
support) is checked here, once, when the spec is parsed.

The `task` block is a discriminated union on `type` over the registry `sim.tasks.TASK_TYPES`:

    task: {type: push, force: 100, direction: forward}
    task: {type: pose_change, target: {waist: -90}}

A task given by its name alone (`task: push`, the form before the registry) is refused with
a message saying what to send instead.

The `controller` block is a discriminated union on `type` over the registry
`sim.controllers.registry.CONTROLLER_TYPES` (contract in `sim.controllers.config`):

    controller: {type: momentum, k_l: 30}    # the default type; its gains override the defaults

A block without its `type` (the old flat dict of momentum gains) is refused the same way.

Units: seconds, metres, newtons, kilograms; joint angles in specs are in degrees.
"""

from __future__ import annotations

import json
import os
import types
import typing
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any, Union

import annotated_types
from pydantic import (
    BaseModel,
    Discriminator,
    Field,
    PrivateAttr,
    SerializerFunctionWrapHandler,
    Tag,
    ValidationError,
    ValidationInfo,
    field_validator,
    model_serializer,
    model_validator,
)
from pydantic.fields import FieldInfo

from cmrt.canonical import canonical_json, document_hash, text_hash
from cmrt.specfile import SpecReadError, read_spec_file
from sim.character import (
    DATA_DIR,
    DEFAULT_CHARACTER,
    Character,
    character_reference,
    definition_reference,
    load_character,
    parse_character,
    shipped_characters,
)
from sim.character_rules import HEIGHT_RANGE, MASS_RANGE
from sim.controllers.config import DEFAULT_CONTROLLER, GAIN_NAMES
from sim.controllers.registry import CONTROLLER_TYPES
from sim.errors import CharacterError, SpecError
from sim.robust import NOT_SCENE, RobustConfig, variant_document, variant_values
from sim.specbase import Samples, StrictModel, count, quantity
from sim.tasks import TASK_TYPES
from sim.tasks.base import MAX_CLIP_SECONDS

#: Most evaluations a spec may ask for (and bound of the stopping rules counted in them).
MAX_EVALUATIONS = 100_000
#: The task window is at least one simulation step (sim.physics.DT, s): a shorter one is no
#: motion the simulator can make (a pose change in 5e-324 s made the controller non-finite).
MIN_TASK_SECONDS = 0.001
#: Narrowest room (m) the CoP box may leave on each side of the support centre.
MIN_COP_BOX_WIDTH = 0.005

_Strict = StrictModel
#: The `task` field: one of the registered task types, chosen by its `type`.
TaskBlock = Annotated[Union[tuple(TASK_TYPES.values())], Field(discriminator="type")]  # noqa: UP007


def _controller_tag(value: Any) -> str | None:
    """The `controller` block's type: its `type` (None when it has none)."""
    tag = value.get("type") if isinstance(value, dict) else getattr(value, "type", None)
    return tag if isinstance(tag, str) else None


#: The `controller` field: one of the registered controller types, chosen by its `type`
#: (a spec without the block has the default, momentum).
ControllerBlock = Annotated[
    Union[tuple(Annotated[c, Tag(k)] for k, c in CONTROLLER_TYPES.items())],  # noqa: UP007
    Discriminator(_controller_tag, custom_error_type="controller_type",
                  custom_error_message=(f"must be a mapping whose `type` is one of "
                                        f"{', '.join(CONTROLLER_TYPES)}"))]


#: The `model` of a character given by its `definition` when the spec names none.
DEFINED_CHARACTER = "custom"


class CharacterRef(_Strict):
    """Which character: a shipped file `sim/data/<model>.yaml`, or a full `definition` (the
    same schema, docs/characters.md) named `model`; scaled to a height (m) and mass (kg).
    A height or mass left out is the character's own (its `reference`).

    A definition travels with the spec (a stored job holds it; the spec hash covers it); a
    spec without one has the canonical form it always had (the field is left out)."""

    definition: dict[str, Any] | None = None
    model: Annotated[str, Field(pattern=r"^[a-z0-9_]{1,64}$")] = DEFAULT_CHARACTER
    height: quantity(*HEIGHT_RANGE, "m") = 1.75
    mass: quantity(*MASS_RANGE, "kg") = 70.0
    _loaded: list[Character] = PrivateAttr(default_factory=list)

    @model_validator(mode="before")
    @classmethod
    def _file_reference(cls, data: Any) -> Any:
        """Fill a missing height / mass from the character's `reference` (the defaults above
        are the default character's), a definition's model name; an unknown model or a bad
        definition is left to the field's own check."""
        if not isinstance(data, dict):
            return data
        if "file" in data:
            raise ValueError("file: a character file is read by the command line (cmrt "
                             "simulate, optimize, submit), which sends its content as "
                             "`definition`; a request holds the definition itself")
        definition = data.get("definition")
        if definition is not None and "model" not in data:
            data = {**data, "model": DEFINED_CHARACTER}
        if "height" not in data or "mass" not in data:
            ref = (definition_reference(definition) if definition is not None
                   else character_reference(data.get("model", DEFAULT_CHARACTER)))
            if ref is not None:
                data = {"height": ref[0], "mass": ref[1], **data}
        return data

    @field_validator("definition")
    @classmethod
    def _definition(cls, v: dict[str, Any] | None) -> dict[str, Any] | None:
        """A definition obeys every rule of a character file (sim.character_rules)."""
        if v is not None:
            try:
                parse_character(v)
            except CharacterError as err:
                raise ValueError(str(err)) from None
        return v

    @field_validator("model")
    @classmethod
    def _exists(cls, v: str, info: ValidationInfo) -> str:
        if "definition" not in info.data:
            return v  # a definition was given and broke a rule: that error says it all
        shipped = (DATA_DIR / f"{v}.yaml").is_file()
        if info.data["definition"] is not None:
            if shipped:
                raise ValueError(f"{v!r} is a shipped character; a definition's name must be "
                                 f"another")
            return v
        if not shipped:
            raise ValueError(f"unknown character {v!r}; characters are "
                             f"{', '.join(shipped_characters())}")
        return v

    @model_serializer(mode="wrap")
    def _without_absent_definition(self, handler: SerializerFunctionWrapHandler
                                   ) -> dict[str, Any]:
        """A spec without a definition keeps the canonical form (and hash) it always had."""
        out = handler(self)
        if self.definition is None:
            out.pop("definition", None)
        return out

    def identity(self) -> dict[str, Any]:
        """What tells this character from another (the library's `character` of a CMRT): its
        model, height and mass, and for a definition the hash of the definition's canonical
        text in its place (the definition itself is in the spec the library keeps)."""
        out = self.model_dump(mode="json")
        if self.definition is not None:
            out["definition_hash"] = document_hash(out.pop("definition"))
        return out

    @property
    def field(self) -> str:
        """Where the spec holds this character's data: its definition, or the named file."""
        return ("character.definition" if self.definition is not None
                else f"character.model ({self.model}.yaml)")

    def load(self) -> Character:
        if self.definition is None:
            return load_character(self.model, self.height, self.mass)
        if not self._loaded:  # parsed once per spec: a rollout asks for it again
            self._loaded.append(parse_character(self.definition, self.height, self.mass,
                                                name=self.model))
        return self._loaded[0]


class Clip(_Strict):
    """Clip timing in seconds: preparation, then the task window, then decay."""

    preparation: quantity(0.0, 10.0, "s") = 1.0
    duration: quantity(MIN_TASK_SECONDS, 10.0, "s")
    decay: quantity(0.0, 10.0, "s") = 1.0

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


class GainSchedule(_Strict):
    """Ease-in-ease-out change of controller gains and weights (paper 6.3.2).

    `scale` multiplies the named parameters (1.15 is "+15 %"); `set` moves them to a value
    (for one whose default is 0, such as the CoP weight b_p). The window defaults to the task
    window; `ramp` is the ease time in seconds at each end of the window.
    """

    scale: dict[str, quantity(0.01, 20.0, "times the gain")] = {}
    set: dict[str, quantity(0.0, 1e4, "in the gain's unit")] = {}
    start: quantity(0.0, MAX_CLIP_SECONDS, "s") | None = None
    end: quantity(0.0, MAX_CLIP_SECONDS, "s") | None = None
    ramp: quantity(0.0, 5.0, "s") = 0.1

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

    knots: count(1, 16, "knots") = 4
    vertical: bool = False
    max_displacement: quantity(0.001, 0.5, "m") = 0.15
    max_vertical: quantity(0.001, 0.3, "m") = 0.08


class OptimizeConfig(_Strict):
    """CMA-ES settings and the paper's stopping rules."""

    threshold: quantity(1e-6, 1e6, "(objective)") | None = None
    sigma0: quantity(0.001, 1.0, "(of the unit cube)") = 0.2
    popsize: count(2, 200, "candidates") | None = None
    min_evaluations: count(0, MAX_EVALUATIONS, "evaluations") = 700
    max_evaluations: count(1, MAX_EVALUATIONS, "evaluations") = 2000
    window: count(1, MAX_EVALUATIONS, "evaluations") = 100
    improvement: quantity(1e-4, 0.999, "(fraction)") = 0.05
    #: One CMRT for a range of scenes (`sim.robust`); None: the spec's one scene.
    robust: RobustConfig | None = None

    @model_serializer(mode="wrap")
    def _without_absent_robust(self, handler: SerializerFunctionWrapHandler) -> dict[str, Any]:
        """A spec without a robust block keeps the canonical form (and hash) it always had."""
        out = handler(self)
        if self.robust is None:
            out.pop("robust", None)
        return out


class TaskSpec(_Strict):
    """One task clip. See examples/*.yaml."""

    name: Annotated[str, Field(min_length=1, max_length=100, pattern=r"^[A-Za-z0-9_.\-]+$")]
    task: TaskBlock
    family: Annotated[str, Field(min_length=1, max_length=100)] | None = None
    character: CharacterRef = CharacterRef()
    clip: Clip
    controller: ControllerBlock = CONTROLLER_TYPES[DEFAULT_CONTROLLER]()
    schedule: Annotated[list[GainSchedule], Field(max_length=16)] = []
    cmrt: CmrtConfig = CmrtConfig()
    optimize: OptimizeConfig = OptimizeConfig()

    @model_validator(mode="before")
    @classmethod
    def _task_by_name(cls, data: Any) -> Any:
        """Refuse `task: push` (+ a `push:` block), the form before the registry, saying what
        to send instead."""
        if isinstance(data, dict) and isinstance(data.get("task"), str):
            raise ValueError(f"task: must be a mapping with its type, e.g. {{type: "
                             f"{data['task']}, ...}} holding the task's fields; a task named "
                             f"alone (with a separate block of its fields) is no longer read")
        return data

    @model_validator(mode="after")
    def _cross_field(self) -> TaskSpec:
        try:
            ch = self.character.load()
        except CharacterError as err:
            raise ValueError(f"character: {err}") from None
        self.task.check_needs(ch, self.character.field)
        self.task.check(self, ch)
        self.controller.check(self, ch)
        if self.schedule and not self.controller.schedules_gains:
            raise ValueError(f"schedule: gain schedules apply to the momentum controller's "
                             f"gains; controller type {self.controller.type!r} takes none")
        for i, s in enumerate(self.schedule):
            a, b = self.schedule_window(s)
            if b <= a:
                raise ValueError(f"schedule.{i}: end must be after start")
        room = 0.5 * ch.support_length - MIN_COP_BOX_WIDTH
        boxes = [("controller.cop_box", getattr(self.controller, "cop_box", None)),
                 ("controller.feet_fixed.cop_box",
                  (getattr(self.controller, "feet_fixed", None) or {}).get("cop_box"))] + [
            (f"schedule.{i}.set.cop_box", s.set.get("cop_box"))
            for i, s in enumerate(self.schedule)]
        for where, v in boxes:
            if v is not None and not v < room:
                raise ValueError(
                    f"{where}: must be below half the support length minus "
                    f"{MIN_COP_BOX_WIDTH} m ({room:.3f} m for this character), got {v:g}")
        _check_robust(self)  # last: the variants are checked against a valid spec
        return self

    # ---- derived quantities -------------------------------------------------------------
    @property
    def family_name(self) -> str:
        """The library family: `family` if given, else the spec's name."""
        return self.family or self.name

    @property
    def task_type(self) -> str:
        """The task's registered name (`task.type`)."""
        return self.task.type

    def load_character(self) -> Character:
        return self.character.load()

    def schedule_window(self, s: GainSchedule) -> tuple[float, float]:
        start = s.start if s.start is not None else self.clip.task_start
        end = s.end if s.end is not None else self.clip.task_end
        return start, end

    def task_parameters(self) -> dict[str, float]:
        """The numbers that place this task within its family (library keys): the task
        window's duration and the task type's own (e.g. a push's signed `force`)."""
        return {"duration": self.clip.duration, **self.task.parameters()}

    def parameter_paths(self) -> dict[str, str]:
        """Each library parameter's dotted path in the spec document (`duration` ->
        `clip.duration`, the domino's `mass` -> `task.mass`); a parameter that is not one plain
        field (a push's signed force) maps to its main field."""
        out = {"duration": "clip.duration"}
        for key in self.task.parameters():
            path = type(self.task).PARAMETER_PATHS.get(key)
            out[key] = "task." + (path if path is not None else key)
        return out

    def library_key(self, name: str) -> str:
        """The library parameter `name` names: a library key (`mass`) as it is, or its dotted
        spec path (`task.mass`); ValueError naming both forms for anything else."""
        paths = self.parameter_paths()
        if name in paths:
            return name
        for key, path in paths.items():
            if path == name:
                return key
        known = ", ".join(f"{k} ({p})" for k, p in sorted(paths.items()))
        raise ValueError(f"{name!r} is not a task parameter of this {self.task_type} task; "
                         f"its parameters are {known}")

    def with_parameter(self, key: str, value: float) -> dict[str, Any]:
        """This spec's document with library parameter `key` set to `value` (not validated:
        parse it). KeyError if the task has no such parameter."""
        doc = self.model_dump(mode="json", exclude_unset=False)
        updates = ({"clip.duration": value} if key == "duration" else
                   {"task." + p: v for p, v in self.task.parameter_updates(key, value).items()})
        for path, v in updates.items():
            node: Any = doc
            *head, last = path.split(".")
            for part in head:
                node = node[int(part)] if isinstance(node, list) else node[part]
            if isinstance(node, list):
                node[int(last)] = v
            else:
                node[last] = v
        return doc

    @property
    def cmrt_dimension(self) -> int:
        """Length of the parameter vector: knot times and control values (x, and y if vertical)."""
        per_knot = 3 if self.cmrt.vertical else 2
        return per_knot * self.cmrt.knots


def error_location(loc: Sequence[str | int]) -> list[str | int]:
    """A pydantic error path as the spec's author wrote it: pydantic puts the chosen member's
    tag of a discriminated union in the path (`task.push.force`), which names no field of the
    file; the tag right after a `task` or `controller` key is dropped, at any depth (a spec
    nested in a request body included), and only it (the domino's `task.push` is a field)."""
    out: list[str | int] = []
    for i, part in enumerate(loc):
        before = loc[i - 1] if i else None  # the raw key: a field named like a tag is kept
        if (before == "task" and part in TASK_TYPES) or (before == "controller"
                                                         and part in CONTROLLER_TYPES):
            continue
        out.append(part)
    return out


def format_error(err: ValidationError) -> str:
    lines = []
    for e in err.errors():
        loc = error_location(e["loc"])
        msg = e["msg"].removeprefix("Value error, ")
        if e["type"] == "controller_type":
            loc = [*loc, "type"]
            tag = e["input"].get("type") if isinstance(e["input"], dict) else None
            if isinstance(e["input"], dict) and "type" not in e["input"]:
                msg = (f"required: send {{type: {DEFAULT_CONTROLLER}, ...}} with the gains "
                       f"(one of {', '.join(CONTROLLER_TYPES)}); a block without its type is "
                       f"no longer read")
            elif isinstance(tag, str):
                msg = (f"unknown controller type {tag!r}; controller types are "
                       f"{', '.join(CONTROLLER_TYPES)}")
        elif e["type"] == "union_tag_invalid":
            msg = (f"unknown task type {e['ctx']['tag']!r}; task types are "
                   f"{', '.join(TASK_TYPES)}")
        elif e["type"] == "union_tag_not_found":
            msg = f"needs a `type`, one of {', '.join(TASK_TYPES)}"
        where = ".".join(str(p) for p in loc)
        lines.append(f"{where}: {msg}" if where else msg)
    return "; ".join(lines)


#: Diagnostics: when this variable names a file, every parse of a spec and every canonical
#: serialisation appends one line `<pid> parse|serialise <name> <source>` to it (the tests count
#: the parses of a job's spec per process with it).
TRACE_VARIABLE = "CMRT_SPEC_TRACE"


def _trace(kind: str, name: Any, source: str) -> None:
    path = os.environ.get(TRACE_VARIABLE)
    if path:
        with open(path, "a") as f:
            f.write(f"{os.getpid()} {kind} {name} {source}\n")


def parse_spec(data: Any, source: str = "<spec>") -> TaskSpec:
    """Validate a mapping into a TaskSpec, raising SpecError naming each bad field and rule."""
    _trace("parse", data.get("name") if isinstance(data, dict) else None, source)
    if not isinstance(data, dict):
        raise SpecError(f"{source}: a spec must be a mapping, got {type(data).__name__}")
    try:
        return TaskSpec.model_validate(data)
    except ValidationError as err:
        raise SpecError(f"{source}: {format_error(err)}") from None


def load_spec(path: str | Path) -> TaskSpec:
    """Read a YAML or JSON spec file, with the blocks it takes from other files inline
    (`cmrt.specfile`)."""
    try:
        data = read_spec_file(path)
    except SpecReadError as err:
        raise SpecError(str(err)) from None
    return parse_spec(data, str(path))


def _check_robust(spec: TaskSpec) -> None:
    """ValueError naming `optimize.robust...` and the rule unless every path is a number of
    this spec's scene, every range lies within the field's bounds with lo < hi, and every
    variant is a valid spec."""
    robust = spec.optimize.robust
    if robust is None:
        return
    fields = {f.name: f for f in numeric_fields(spec) if f.value is not None}
    for path, (lo, hi) in robust.vary.items():
        where = f"optimize.robust.vary.{path}"
        if path.split(".")[0] in NOT_SCENE:
            raise ValueError(f"{where}: the {path.split('.')[0]} block is not part of the "
                             "scene; vary numbers of the task, clip, controller or character")
        f = fields.get(path)
        if f is None:
            raise ValueError(f"{where}: not a number this spec sets (a path such as "
                             f"`cmrt family run --param` takes, e.g. task.mass)")
        if f.integer:
            raise ValueError(f"{where}: {path} is a whole number; only real numbers can vary "
                             "over a range")
        if not lo < hi:
            raise ValueError(f"{where}: the range must be [lo, hi] with lo < hi, got "
                             f"[{lo:g}, {hi:g}]")
        if (f.lo is not None and lo < f.lo) or (f.hi is not None and hi > f.hi):
            shown = f"{'-inf' if f.lo is None else f'{f.lo:g}'} to " \
                    f"{'inf' if f.hi is None else f'{f.hi:g}'}"
            raise ValueError(f"{where}: the range [{lo:g}, {hi:g}] must lie within the "
                             f"field's own range, {shown}")
    document = spec.model_dump(mode="json")
    for i, values in enumerate(variant_values(robust)):
        try:
            TaskSpec.model_validate(variant_document(document, values))
        except ValidationError as err:
            shown = ", ".join(f"{p} = {v:g}" for p, v in values.items())
            raise ValueError(f"optimize.robust: variant {i} ({shown}) is not a valid spec: "
                             f"{format_error(err)}") from None


# ---- the canonical form ----------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class CanonicalSpec:
    """A validated spec with its JSON document (what the store keeps) and the hash of the
    document's canonical text (`cmrt.canonical`): made once where a spec enters (the route, the
    command line), and the key every other process caches the typed spec under, so that a
    process parses a spec at most once (`optim.objective.SPECS`). `text`, the canonical JSON,
    is what a pickled objective carries; it is computed on first use when the spec was read
    from the store (which keeps the document and the hash)."""

    spec: TaskSpec
    document: dict[str, Any]
    hash: str
    _text: list[str] = field(default_factory=list, repr=False)

    @property
    def text(self) -> str:
        if not self._text:
            _trace("serialise", self.spec.name, "canonical text")
            self._text.append(canonical_json(self.document))
        return self._text[0]


def canonical_spec(spec: TaskSpec) -> CanonicalSpec:
    """The canonical form of a typed spec: one dump to its JSON document, one canonical text,
    its hash."""
    _trace("serialise", spec.name, "canonical document")
    document = spec.model_dump(mode="json")
    text = canonical_json(document)
    return CanonicalSpec(spec, document, text_hash(text), [text])


def parse_canonical(data: Any, source: str = "<spec>") -> CanonicalSpec:
    """Validate raw input (a request body, a file's mapping) and canonicalise it: the one
    parse at a boundary. SpecError as `parse_spec`."""
    return canonical_spec(parse_spec(data, source))


def stored_spec(document: Mapping[str, Any], hash: str, source: str = "<spec>"
                ) -> CanonicalSpec:
    """The typed form of a document stored with its hash (a job's spec): one parse; the
    stored hash is trusted (the boundary computed it from this document)."""
    doc = dict(document)
    return CanonicalSpec(parse_spec(doc, source), doc, hash)


def text_spec(text: str, hash: str | None = None, source: str = "<spec>") -> CanonicalSpec:
    """The typed form of a canonical text (a pickled objective's): one parse."""
    doc = json.loads(text)
    return CanonicalSpec(parse_spec(doc, source), doc, hash or text_hash(text), [text])


# ---- the numeric fields of a spec ------------------------------------------------------------
@dataclass(frozen=True)
class NumericField:
    """One number a spec sets or could set: its path (as in error messages, `task.ball.mass`,
    `schedule.0.ramp`, `task.target.waist`), its value (None: an optional field left out),
    whether it is an integer, and its range (None: unbounded on that side)."""

    path: tuple[str | int, ...]
    value: float | None
    integer: bool
    lo: float | None
    hi: float | None

    @property
    def name(self) -> str:
        return ".".join(str(p) for p in self.path)


def _bounds(meta: Sequence[Any]) -> tuple[float | None, float | None]:
    lo = hi = None
    for m in meta:
        if isinstance(m, FieldInfo):
            a, b = _bounds(m.metadata)
            lo, hi = (a if a is not None else lo), (b if b is not None else hi)
        elif isinstance(m, annotated_types.Ge | annotated_types.Gt):
            lo = float(m.ge if isinstance(m, annotated_types.Ge) else m.gt)
        elif isinstance(m, annotated_types.Le | annotated_types.Lt):
            hi = float(m.le if isinstance(m, annotated_types.Le) else m.lt)
    return lo, hi


def _numeric_type(ann: Any, meta: Sequence[Any] = ()) -> tuple[bool, float | None,
                                                               float | None] | None:
    """(integer, lo, hi) of a numeric annotation (optional or annotated), else None."""
    origin = typing.get_origin(ann)
    if origin in (Union, types.UnionType):
        args = [a for a in typing.get_args(ann) if a is not type(None)]
        return _numeric_type(args[0], meta) if len(args) == 1 else None
    if origin is Annotated:
        return _numeric_type(typing.get_args(ann)[0], [*meta, *ann.__metadata__])
    if ann in (int, float):
        return (ann is int, *_bounds(meta))
    return None


def _walk(value: Any, ann: Any, meta: Sequence[Any],
          path: tuple[str | int, ...]) -> Iterator[NumericField]:
    if isinstance(value, BaseModel):
        for name, info in type(value).model_fields.items():
            yield from _walk(getattr(value, name), info.annotation, info.metadata,
                             (*path, name))
        return
    num = _numeric_type(ann, meta)
    if num is not None and (value is None or not isinstance(value, bool | str)):
        yield NumericField(path, value, *num)
    elif isinstance(value, dict):
        args = typing.get_args(_strip_optional(ann))
        item = args[1] if len(args) == 2 else Any
        for k, v in value.items():
            yield from _walk(v, item, (), (*path, k))
    elif isinstance(value, list | tuple):
        args = typing.get_args(_strip_optional(ann))
        item = args[0] if args else Any
        if any(isinstance(m, Samples) for m in meta):
            value = value[:1]  # one rule for every entry: the first stands for them all
        for i, v in enumerate(value):
            yield from _walk(v, item, (), (*path, i))


def _strip_optional(ann: Any) -> Any:
    while True:
        origin = typing.get_origin(ann)
        if origin is Annotated:
            ann = typing.get_args(ann)[0]
        elif origin in (Union, types.UnionType):
            args = [a for a in typing.get_args(ann) if a is not type(None)]
            if len(args) != 1:
                return ann
            ann = args[0]
        else:
            return ann


def numeric_fields(spec: TaskSpec) -> list[NumericField]:
    """Every number the spec sets, and every optional number it leaves out (value None), with
    its range: the fields of its blocks, the entries of its pose targets and gain maps, and of
    a samples list (a motion's frames, `sim.specbase.SAMPLES`) its first entry's."""
    return list(_walk(spec, TaskSpec, (), ()))
