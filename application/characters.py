"""Characters kept by name (POST /characters) and their use in specs.

A stored character is a full definition (the schema of the shipped files, docs/characters.md),
validated once when it is added (every rule of `sim.character_rules`) and kept under a name that
no shipped character has. A spec sent to the service may name it as its `character.model`: the
definition is then put into the spec before it is parsed (`with_stored_character`), so the job
holds the character itself (its hash covers it; a worker reads no library).
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from typing import Any

from application import errors
from sim.character import (
    Character,
    definition_schema,
    parse_character,
    shipped_characters,
    shipped_definition,
)
from sim.errors import CharacterError
from store import CharacterRecord, Conflict, NotFound, Repository

#: A stored character's name: what a spec's `character.model` may hold.
NAME_PATTERN = r"^[a-z0-9_]{1,64}$"
_NAME = re.compile(NAME_PATTERN)


class CharacterNameTakenError(errors.RequestConflict):
    """The name is a shipped character's, or a stored one's (HTTP 409)."""


class InvalidCharacterError(errors.InvalidRequest):
    """The definition breaks a rule; the message names the field (HTTP 422)."""


def check_definition(definition: Any, name: str = "character") -> Character:
    """The character a definition makes at its reference size; InvalidCharacterError naming
    `definition.<field>` and the rule."""
    try:
        return parse_character(definition, name=name)
    except CharacterError as err:
        raise InvalidCharacterError(f"definition: {err}") from None


def add_character(repo: Repository, name: str, definition: Mapping[str, Any]
                  ) -> CharacterRecord:
    """Validate and store a definition under `name`: CharacterNameTakenError when a shipped or
    stored character has the name, InvalidCharacterError for a bad definition (nothing is
    stored then)."""
    if name in shipped_characters():
        raise CharacterNameTakenError(f"name: {name!r} is a shipped character; a stored "
                                      f"character needs a name of its own")
    check_definition(definition, name)
    try:
        return repo.add_character(name, definition)
    except Conflict:
        raise CharacterNameTakenError(f"name: a character named {name!r} exists") from None


def summary(name: str, definition: Mapping[str, Any]) -> dict[str, Any]:
    """What a character is, in a few numbers: reference size, segments, joints, hands, torso."""
    ch = parse_character(definition, name=name)
    return {"height": ch.height, "mass": ch.total_mass, "segments": ch.n_bodies,
            "joints": list(ch.hinge_names), "hands": list(ch.hands),
            "torso": None if ch.torso is None else ch.body_names[ch.torso]}


def with_stored_character(repo: Repository, spec: Any) -> Any:
    """`spec` (a request's raw mapping) with the definition of the stored character its
    `character.model` names put in (`character.definition`); any other spec as it is (a
    shipped model, a definition given, a name nobody stored: the parser says what is wrong)."""
    if not isinstance(spec, dict) or not isinstance(spec.get("character"), dict):
        return spec
    character = spec["character"]
    model = character.get("model")
    if ("definition" in character or "file" in character or not isinstance(model, str)
            or not _NAME.fullmatch(model) or model in shipped_characters()):
        return spec
    try:
        record = repo.get_character(model)
    except NotFound:
        return spec
    return {**spec, "character": {**character, "definition": record.definition}}


def request_with_stored_character(repo: Repository, data: Any) -> Any:
    """A request's raw body with the definition of the stored character its `spec` names put
    in (`with_stored_character`); any other body as it is (the request's model says what is
    wrong with it)."""
    if isinstance(data, dict) and "spec" in data:
        return {**data, "spec": with_stored_character(repo, data["spec"])}
    return data


def shipped_names() -> list[str]:
    """The names of the characters shipped with the simulator."""
    return shipped_characters()


def shipped(name: str) -> dict[str, Any] | None:
    """The definition of the shipped character `name`, or None when no shipped one has it."""
    return shipped_definition(name) if name in shipped_characters() else None


__all__ = ["NAME_PATTERN", "definition_schema", "CharacterNameTakenError", "InvalidCharacterError",
           "add_character", "check_definition", "request_with_stored_character", "shipped",
           "shipped_names", "summary", "with_stored_character"]
