"""The strict base of every spec model (sim.spec and the task types in sim.tasks).

Strict types: a number given as a string ("0.1") or a boolean (true) is rejected, as is an
integer field given 4.0; every float must be finite (NaN, inf and 1e999 are rejected); unknown
fields are rejected; strings may not hold control characters (NUL, newline, escape, ...) nor
the bidirectional formatting characters (U+202E RIGHT-TO-LEFT OVERRIDE and the other embeddings,
overrides, isolates and marks, `BIDI_CONTROLS`: they reorder how a name is displayed), also in
mapping keys. Errors name the field (pydantic's location) and the rule.
"""

from __future__ import annotations

import math
import unicodedata
from typing import Annotated, Any

from pydantic import BaseModel, BeforeValidator, ConfigDict, Field, field_validator

#: Smallest size of a nonzero quantity (in its own unit).
MIN_MAGNITUDE = 1e-9

#: The bidirectional formatting characters (Unicode's Bidi_Control property): a name holding
#: one can be displayed as another (`abc\u202edcba` shows as `abcabcd`).
BIDI_CONTROLS = frozenset("\u061c\u200e\u200f\u202a\u202b\u202c\u202d\u202e"
                          "\u2066\u2067\u2068\u2069")


def _is_control(ch: str) -> bool:
    return ch in BIDI_CONTROLS or unicodedata.category(ch) == "Cc"


def _check_text(value: Any) -> None:
    if isinstance(value, str):
        bad = next((ch for ch in value if _is_control(ch)), None)
        if bad is not None:
            raise ValueError(f"control character {bad!r} not allowed in text")
    elif isinstance(value, dict):
        for k, v in value.items():
            _check_text(k)
            _check_text(v)
    elif isinstance(value, list | tuple):
        for v in value:
            _check_text(v)


#: The JSON Schema pattern of text without control characters (Unicode's Cc: U+0000-U+001F,
#: U+007F-U+009F) nor `BIDI_CONTROLS`: what `_check_text` refuses, said in the schema.
TEXT_PATTERN = ("^[^\\u0000-\\u001f\\u007f-\\u009f\\u061c\\u200e\\u200f\\u202a-\\u202e"
                "\\u2066-\\u2069]*$")


def _text_schema(node: dict[str, Any]) -> None:
    """Put TEXT_PATTERN on every string of a field's schema that has no pattern, enum or const
    of its own, and on the keys of every mapping (in place; a `$ref` is the other model's)."""
    if node.get("type") == "string" and not {"pattern", "enum", "const"} & node.keys():
        node["pattern"] = TEXT_PATTERN
    values = node.get("additionalProperties")
    if node.get("type") == "object" and values is not False:
        node["propertyNames"] = {"pattern": TEXT_PATTERN, **node.get("propertyNames", {})}
    for sub in (*node.get("anyOf", ()), *node.get("oneOf", ()), *node.get("prefixItems", ())):
        _text_schema(sub)
    for sub in (node.get("items"), values):
        if isinstance(sub, dict):
            _text_schema(sub)


def _schema_rules(schema: dict[str, Any], cls: type) -> None:
    """The rules of a StrictModel that JSON Schema can state, put in its schema: no control
    characters in text, and a variant's `type` tag required (a task or controller block is
    chosen by it: the block without one is refused)."""
    for name, prop in schema.get("properties", {}).items():
        _text_schema(prop)
        if name == "type" and "const" in prop and name not in schema.get("required", ()):
            schema.setdefault("required", []).insert(0, name)


class Samples:
    """Marks a list field whose entries all follow one rule (a motion's frames): the walk over a
    spec's numbers (`sim.spec.numeric_fields`) takes its first entry to stand for them all."""

    def __repr__(self) -> str:
        return "SAMPLES"


#: The marker of a samples list (`Annotated[list[...], Field(...), SAMPLES]`).
SAMPLES = Samples()


class StrictModel(BaseModel):
    """Frozen, strict, finite, no extra fields, no control characters in text."""

    model_config = ConfigDict(extra="forbid", frozen=True, strict=True, allow_inf_nan=False,
                              json_schema_extra=_schema_rules)

    @field_validator("*", mode="after")
    @classmethod
    def _no_control_characters(cls, value: Any) -> Any:
        if not isinstance(value, BaseModel):
            _check_text(value)
        return value


def _shown(v: float) -> str:
    """A number for a message (an integer of hundreds of digits is not printed whole)."""
    if isinstance(v, int) and abs(v) >= 10**15:
        return f"an integer of {len(str(abs(v)))} digits"
    return repr(v)


def quantity_rule(lo: float, hi: float, unit: str) -> str:
    """The words of a quantity's range: `from 0.05 to 50 kg`."""
    return f"from {lo:g} to {hi:g}{' ' + unit if unit else ' (no unit)'}"


def quantity(lo: float, hi: float, unit: str) -> Any:
    """The type of a quantity in [lo, hi] `unit` (see the module docstring): a strict finite
    float (an int is accepted as a float), 0 or at least `MIN_MAGNITUDE` in size."""
    rule = quantity_rule(lo, hi, unit)

    def check(v: Any) -> Any:
        if isinstance(v, bool) or not isinstance(v, int | float):
            return v  # the strict float type reports it
        if isinstance(v, float) and not math.isfinite(v):
            return v  # allow_inf_nan reports it
        if not lo <= v <= hi:
            raise ValueError(f"must be {rule}, got {_shown(v)}")
        if v != 0 and abs(v) < MIN_MAGNITUDE:
            raise ValueError(f"must be 0 or at least {MIN_MAGNITUDE:g} in size ({rule}), "
                             f"got {_shown(v)}")
        return v

    small = f"; 0 or at least {MIN_MAGNITUDE:g} in size" if lo <= 0 <= hi else ""
    # the sizes between 0 and MIN_MAGNITUDE (either side) that the range holds are refused
    bands = [{"exclusiveMinimum": a, "exclusiveMaximum": b}
             for a, b in ((-MIN_MAGNITUDE, 0.0), (0.0, MIN_MAGNITUDE)) if lo < b and a < hi]
    extra = {"not": {"anyOf": bands}} if bands else None
    return Annotated[float, Field(ge=lo, le=hi, description=rule + small,
                                  json_schema_extra=extra),
                     BeforeValidator(check)]


def count(lo: int, hi: int, unit: str) -> Any:
    """The type of a whole number of `unit` (knots, links, evaluations) in [lo, hi]: a strict
    int, refused out of range with the unit and the range in the message."""
    rule = f"from {lo} to {hi} {unit}"

    def check(v: Any) -> Any:
        if isinstance(v, int) and not isinstance(v, bool) and not lo <= v <= hi:
            raise ValueError(f"must be {rule}, got {_shown(v)}")
        return v  # anything but an int: the strict int type reports it

    return Annotated[int, Field(ge=lo, le=hi, description=rule), BeforeValidator(check)]

