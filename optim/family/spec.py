"""A family request (paper sections 5.3 and 6.2): a base task spec, the path of one number in
it (`param`, e.g. `task.mass`), its `values`, a `strategy` and the checks' settings
(`FamilySpec`, `parse_family`), and the spec of each member (`member_spec`). Each member is the
base spec with the number at `param` set to the value (named `<family>_<leaf><value>`, family
kept); every value must be accepted by the task's validator.
"""

from __future__ import annotations

import copy
from collections.abc import Mapping
from typing import Annotated, Any, Literal

from pydantic import BeforeValidator, Field, PrivateAttr, ValidationError, model_validator

from cmrt.defaults import DEFAULT_SEED
from optim.errors import OptimError
from optim.objective import SimObjective
from sim.errors import SpecError
from sim.spec import OptimizeConfig, TaskSpec, parse_spec
from sim.specbase import StrictModel

#: RMS distance (spline parameters, box units in [0, 1]) between two neighbouring members above
#: which they are two strategies of the task: the family's report flags a switch there and the
#: library never averages across it. Members of one strategy lie 0.02-0.13 apart in the stored
#: families (sumo box, bend speed, the domino's chains, the lion's tire at 28-32 kg); the
#: switches found there lie 0.21-0.35 apart (docs/families.md).
SWITCH_DISTANCE = 0.15


class FamilyError(OptimError, ValueError):
    """A family spec is invalid (the message names the field and the rule)."""


class WarmConfig(StrictModel):
    """Continuation members after a chain's first: CMA-ES step and stopping rules."""

    sigma0: Annotated[float, Field(gt=0.0, le=1.0)] = 0.05
    min_evaluations: Annotated[int, Field(ge=0)] = 0
    window: Annotated[int, Field(ge=1)] = 5
    improvement: Annotated[float, Field(gt=0.0, lt=1.0)] = 0.01
    max_evaluations: Annotated[int, Field(ge=1, le=100_000)] = 100


def value_id(v: float) -> str:
    """A value as it appears in run ids and names (`40`, `0.35`)."""
    return format(float(v), ".12g").replace("+", "")


def get_path(data: Mapping[str, Any], path: str) -> Any:
    """The entry at a dotted path of a nested mapping; KeyError naming the missing part."""
    node: Any = data
    for i, part in enumerate(path.split(".")):
        if not isinstance(node, Mapping) or part not in node:
            raise KeyError(".".join(path.split(".")[: i + 1]))
        node = node[part]
    return node


def set_path(data: dict[str, Any], path: str, value: Any) -> dict[str, Any]:
    """A deep copy of `data` with the entry at `path` replaced (it must exist)."""
    out = copy.deepcopy(data)
    *parents, leaf = path.split(".")
    node = out
    for part in parents:
        node = node[part]
    node[leaf] = value
    return out


class FamilySpec(StrictModel):
    """A family request (docs/families.md, "The request"). Build with `parse_family`."""

    # kept as the mapping it came as (the members are made from it), documented as the task
    # spec it must be (parsed whole in `_check`)
    spec: Annotated[dict[str, Any], BeforeValidator(lambda v: v, json_schema_input_type=TaskSpec)]
    param: Annotated[str, Field(pattern=r"^[A-Za-z_][A-Za-z0-9_]*(\.[A-Za-z_][A-Za-z0-9_]*)+$")]
    values: Annotated[list[float], Field(min_length=1, max_length=200)]
    strategy: Literal["independent", "continuation"] = "independent"
    start_from: Literal["low", "high", "both", "middle"] = Field("both", alias="from")
    warm: WarmConfig = WarmConfig()
    leave_out: Annotated[list[float], Field(max_length=200)] = []
    # A reduced run searches k coordinates: CMA-ES needs at least 2 (optim.cmaes.MIN_DIMENSION).
    k: Annotated[int, Field(ge=2, le=16)] = 3
    seed: Annotated[int, Field(ge=0, lt=2**31)] = DEFAULT_SEED
    reduced_start: Literal["neighbours", "centre"] = "neighbours"
    switch_threshold: Annotated[float, Field(gt=0.0, le=1.0)] = SWITCH_DISTANCE

    model_config = {**StrictModel.model_config, "populate_by_name": True}

    #: The base spec and the member specs, parsed once per FamilySpec.
    _base: Any = PrivateAttr(default=None)
    _members: dict[tuple[float, str], TaskSpec] = PrivateAttr(default_factory=dict)

    @model_validator(mode="after")
    def _check(self) -> FamilySpec:
        try:
            base = parse_spec(self.spec, "spec")
        except SpecError as err:
            raise ValueError(str(err)) from None
        self._base = base
        dumped = base.model_dump(mode="json")
        try:
            current = get_path(dumped, self.param)
        except KeyError as err:
            raise ValueError(f"param: {self.param!r} is not in the spec (no {err.args[0]!r})"
                             ) from None
        if isinstance(current, bool) or not isinstance(current, int | float):
            raise ValueError(f"param: {self.param!r} must name a number in the spec, it holds "
                             f"{type(current).__name__}")
        if len(set(self.values)) != len(self.values):
            dup = sorted({v for v in self.values if self.values.count(v) > 1})
            raise ValueError("values: must be distinct; repeated: "
                             f"{', '.join(map(value_id, dup))}")
        for i, v in enumerate(self.values):
            try:
                parse_spec(set_path(dumped, self.param, v), "spec")
            except SpecError as err:
                raise ValueError(f"values[{i}]: {self.param} = {value_id(v)} is refused: "
                                 f"{str(err).removeprefix('spec: ')}") from None
        for i, v in enumerate(self.leave_out):
            if v not in self.values:
                raise ValueError(f"leave_out[{i}]: {value_id(v)} is not one of the values")
        if len(set(self.leave_out)) != len(self.leave_out):
            raise ValueError("leave_out: must be distinct")
        need = self.k + 2 if self.leave_out else self.k + 1
        if len(self.values) < need:
            besides = " besides the left-out one" if self.leave_out else ""
            raise ValueError(f"k: {self.k} components need at least {need} values (a basis "
                             f"of k + 1 members{besides}), got {len(self.values)}")
        return self

    # -- derived -------------------------------------------------------------------------------
    @property
    def base(self) -> TaskSpec:
        if self._base is None:
            self._base = parse_spec(self.spec, "spec")
        return self._base

    @property
    def family(self) -> str:
        return self.base.family_name

    @property
    def leaf(self) -> str:
        """The parameter's last path part (`mass` for `task.mass`): the key in tables."""
        return self.param.rsplit(".", 1)[-1]

    @property
    def sorted_values(self) -> list[float]:
        return sorted(float(v) for v in self.values)

    def to_dict(self) -> dict[str, Any]:
        return self.model_dump(mode="json", by_alias=True)


def _format_error(err: ValidationError) -> str:
    lines = []
    for e in err.errors():
        where = ".".join(str(p) for p in e["loc"])
        msg = e["msg"].removeprefix("Value error, ")
        lines.append(f"{where}: {msg}" if where else msg)
    return "; ".join(lines)


def parse_family(data: Any, source: str = "family") -> FamilySpec:
    """Validate a mapping into a FamilySpec; FamilyError naming each bad field and its rule."""
    if not isinstance(data, Mapping):
        raise FamilyError(f"{source}: a family must be a mapping, got {type(data).__name__}")
    try:
        return FamilySpec.model_validate(dict(data))
    except ValidationError as err:
        raise FamilyError(f"{source}: {_format_error(err)}") from None


#: Roles of a run's spec: the main rules (members from the flat spline, references, reduced
#: runs) or the warm rules (continuation members after a chain's first).
MAIN, WARM = "main", "warm"


def member_spec(fs: FamilySpec, value: float, role: str = MAIN) -> TaskSpec:
    """The base spec with `param` = value, named `<family>_<leaf><value>` in the family; with
    role WARM its optimizer step and stopping rules are `fs.warm`'s. Parsed once per family
    spec, value and role."""
    key = (float(value), role)
    hit = fs._members.get(key)
    if hit is None:
        hit = fs._members[key] = _member_spec(fs, value, role)
    return hit


def member_objective(fs: FamilySpec, value: float) -> SimObjective:
    """The simulation of the member at `value` under the main rules (one simulator per value,
    whatever a run's rules): what both family drivers evaluate a member's runs and probe with."""
    return SimObjective(member_spec(fs, value))


def _member_spec(fs: FamilySpec, value: float, role: str) -> TaskSpec:
    data = set_path(fs.base.model_dump(mode="json"), fs.param, float(value))
    data["family"] = fs.family
    data["name"] = f"{fs.family}_{fs.leaf}{value_id(value)}"[:100]
    if role == WARM:
        main = OptimizeConfig.model_validate(data["optimize"])
        warm = fs.warm.model_dump(mode="json")
        # a warm-started member never gets more evaluations than a cold one
        warm["max_evaluations"] = min(warm["max_evaluations"], main.max_evaluations)
        data["optimize"] = {**main.model_dump(mode="json"), **warm}
    return parse_spec(data, f"family member {fs.param} = {value_id(value)}")


__all__ = [
    "MAIN",
    "SWITCH_DISTANCE",
    "WARM",
    "FamilyError",
    "FamilySpec",
    "WarmConfig",
    "get_path",
    "member_objective",
    "member_spec",
    "parse_family",
    "set_path",
    "value_id",
]
