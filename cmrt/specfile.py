"""What a command line does to a spec file before anyone parses it: a character given as a file
(`character: {file: my_character.yaml}`, relative to the spec file) is read and put into the
spec as its `definition`, so that what is simulated, stored or sent holds the character itself
(a worker on another host never reads a user's file; the spec hash covers the definition).

Shared by every reader of spec files (`sim.load_spec`, `cmrt.client`, `cmrt family`); the
service never reads a file (a request naming one is refused by the spec's own check).
"""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import yaml

#: Largest character file read (bytes): the shipped ones are 5-9 kB.
MAX_CHARACTER_FILE_BYTES = 1_000_000
#: A character name (the spec's `character.model`) made from the file's name when it fits.
_NAME = re.compile(r"[a-z0-9_]{1,64}")


class CharacterFileError(ValueError):
    """A character file that cannot be read; the message names `character.file`."""


def inline_character_file(spec: Any, base: Path) -> Any:
    """`spec` with `character.file` (relative to `base`, the spec file's folder) replaced by
    the file's content as `character.definition`, and `character.model` the file's name when
    the spec gives none and the name fits (`my_character.yaml` -> `my_character`). A spec
    without `character.file` is returned as it is. CharacterFileError when the file is
    missing, unreadable, too large or not a YAML/JSON mapping (its rules are the parser's)."""
    if not isinstance(spec, dict) or not isinstance(spec.get("character"), dict):
        return spec
    character = dict(spec["character"])
    if "file" not in character:
        return spec
    name = character.pop("file")
    if "definition" in character:
        raise CharacterFileError("character.file: give a file or a definition, not both")
    if not isinstance(name, str) or not name or "\0" in name:
        raise CharacterFileError(f"character.file: must be a file name, got {name!r}")
    character["definition"] = _read_definition(base / name, name)
    stem = Path(name).stem
    if "model" not in character and _NAME.fullmatch(stem):
        character["model"] = stem
    return {**spec, "character": character}


def _read_definition(path: Path, name: str) -> dict[str, Any]:
    """The mapping in a YAML or JSON character file (module docstring)."""
    where = f"character.file: {name}"
    try:
        with path.open("rb") as f:
            raw = f.read(MAX_CHARACTER_FILE_BYTES + 1)
    except FileNotFoundError:
        raise CharacterFileError(f"{where}: no such file (relative to the spec file's "
                                 f"folder, {path.parent})") from None
    except OSError as err:
        raise CharacterFileError(f"{where}: cannot read ({err.strerror})") from None
    if len(raw) > MAX_CHARACTER_FILE_BYTES:
        raise CharacterFileError(f"{where}: larger than {MAX_CHARACTER_FILE_BYTES} bytes")
    try:
        text = raw.decode("utf-8")
        data = json.loads(text) if path.suffix == ".json" else yaml.safe_load(text)
    except (UnicodeDecodeError, yaml.YAMLError, json.JSONDecodeError) as err:
        first = str(err).splitlines()[0] if str(err) else type(err).__name__
        raise CharacterFileError(f"{where}: not valid YAML/JSON ({first})") from None
    if not isinstance(data, dict):
        raise CharacterFileError(f"{where}: a character is a mapping (reference, root, "
                                 f"segments, ...), got {type(data).__name__}")
    return data
