"""The strict base of every spec model (sim.spec and the task types in sim.tasks).

Strict types: a number given as a string ("0.1") or a boolean (true) is rejected, as is an
integer field given 4.0; every float must be finite (NaN, inf and 1e999 are rejected); unknown
fields are rejected; strings may not hold control characters (NUL, newline, escape, ...),
also in mapping keys. Errors name the field (pydantic's location) and the rule.
"""

from __future__ import annotations

import unicodedata
from typing import Any

from pydantic import BaseModel, ConfigDict, field_validator


def _check_text(value: Any) -> None:
    if isinstance(value, str):
        bad = next((ch for ch in value if unicodedata.category(ch) == "Cc"), None)
        if bad is not None:
            raise ValueError(f"control character {bad!r} not allowed in text")
    elif isinstance(value, dict):
        for k, v in value.items():
            _check_text(k)
            _check_text(v)
    elif isinstance(value, list | tuple):
        for v in value:
            _check_text(v)


class StrictModel(BaseModel):
    """Frozen, strict, finite, no extra fields, no control characters in text."""

    model_config = ConfigDict(extra="forbid", frozen=True, strict=True, allow_inf_nan=False)

    @field_validator("*", mode="after")
    @classmethod
    def _no_control_characters(cls, value: Any) -> Any:
        if not isinstance(value, BaseModel):
            _check_text(value)
        return value
