"""A task spec file as the command line reads it: YAML or JSON, with the blocks it takes from
other files put inline.

    task: {type: motion, file: bend_motion.yaml, speed: 1.5}

A block holding `file` (a path relative to the spec's folder) is replaced by the mapping that
file holds, and the block's own fields (but `file`) are laid over it. The file may hold the
block itself or a whole spec, whose block of the same name is taken (`cmrt motion import`
writes whole specs). Files are not followed further: a block read from a file may not name
another. What leaves the command line (a parsed spec, a request body) therefore carries
everything itself: a stored job or a worker on another host never reads a user's file.

A character is the other block a spec may take from a file, in its own way: the file holds a
character definition (the schema of the shipped characters, docs/characters.md), which becomes
the block's `definition`; the block's `model` (the character's name) is the file's name when
the block gives none and the name fits:

    character: {file: my_character.yaml}  ->  character: {model: my_character, definition: ...}

Every file is untrusted: at most MAX_FILE_BYTES, a mapping where one is expected, and each
problem is one `SpecReadError` naming the file and the field.
"""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import yaml

#: Largest spec or referenced file (bytes): a motion of the longest clip at the highest rate
#: (4,800 frames of a dozen angles) is ~0.5 MB as YAML.
MAX_FILE_BYTES = 8_000_000
#: The blocks a spec may take from a file (`BLOCK: {file: PATH}`).
FILE_BLOCKS = ("task",)

_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)
#: A character's name (a spec's `character.model`), as a file's name may give it.
_CHARACTER_NAME = re.compile(r"[a-z0-9_]{1,64}")


class SpecReadError(ValueError):
    """A spec file, or a file it names, cannot be read; the message names the file (and the
    field naming it)."""


def read_bytes(path: str | Path, what: str, limit: int | None = None) -> bytes:
    """A file's bytes, at most `limit` (None: MAX_FILE_BYTES) of them: every file the command
    line reads is untrusted (a spec, a character, a map, a motion clip). `what` names the file
    in messages."""
    p = Path(path)
    limit = MAX_FILE_BYTES if limit is None else limit
    try:
        with p.open("rb") as f:
            raw = f.read(limit + 1)
    except FileNotFoundError:
        raise SpecReadError(f"{p}: cannot read {what} (no such file)") from None
    except OSError as err:
        raise SpecReadError(f"{p}: cannot read {what} ({err.strerror or err})") from None
    if len(raw) > limit:
        raise SpecReadError(f"{p}: larger than {limit} bytes")
    return raw


def read_document(path: str | Path, what: str = "spec", limit: int | None = None) -> Any:
    """The YAML or JSON document in a file (JSON when its name ends in .json), at most `limit`
    (None: MAX_FILE_BYTES) bytes. `what` names the file in messages (`cannot read spec`)."""
    p = Path(path)
    raw = read_bytes(p, what, limit)
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as err:
        raise SpecReadError(f"{p}: not UTF-8 text (byte {err.start})") from None
    try:
        if p.suffix == ".json":
            return json.loads(text)
        return yaml.load(text, Loader=_LOADER)
    except json.JSONDecodeError as err:
        raise SpecReadError(f"{p}: not valid JSON: {err}") from None
    except yaml.YAMLError as err:
        raise SpecReadError(f"{p}: not valid YAML: {str(err).splitlines()[0]}") from None


def read_spec_file(path: str | Path) -> dict[str, Any]:
    """The spec in a file as a mapping, with its `FILE_BLOCKS` read from the files they name
    (module docstring); not validated (that is `sim.spec.parse_spec`'s, or the server's)."""
    p = Path(path)
    doc = read_document(p)
    if not isinstance(doc, dict):
        raise SpecReadError(f"{p}: a spec must be a mapping, got {type(doc).__name__}")
    for key in FILE_BLOCKS:
        block = doc.get(key)
        if isinstance(block, dict) and "file" in block:
            doc[key] = _inlined(block, key, p)
    character = doc.get("character")
    if isinstance(character, dict) and "file" in character:
        doc["character"] = _character(character, p)
    return doc


def _character(block: dict[str, Any], spec_path: Path) -> dict[str, Any]:
    """The character block with the definition its `file` holds (module docstring)."""
    where = f"{spec_path}: character.file"
    ref = block["file"]
    if not isinstance(ref, str) or not ref.strip() or "\0" in ref:
        raise SpecReadError(f"{where}: must be a file name, got {ref!r}")
    if "definition" in block:
        raise SpecReadError(f"{where}: give a file or a definition, not both")
    target = Path(ref) if Path(ref).is_absolute() else spec_path.parent / ref
    try:
        data = read_document(target, "the file `character.file` names")
    except SpecReadError as err:
        raise SpecReadError(f"{where}: {err}") from None
    if not isinstance(data, dict):
        raise SpecReadError(f"{where}: {target} holds no character (a mapping of reference, "
                            f"root, segments, ...), got {type(data).__name__}")
    out = {k: v for k, v in block.items() if k != "file"}
    out["definition"] = data
    if "model" not in out and _CHARACTER_NAME.fullmatch(target.stem):
        out["model"] = target.stem
    return out


def _inlined(block: dict[str, Any], key: str, spec_path: Path) -> dict[str, Any]:
    """`block` with the mapping its `file` holds under its own fields."""
    where = f"{spec_path}: {key}.file"
    ref = block["file"]
    if not isinstance(ref, str) or not ref.strip() or "\0" in ref:
        raise SpecReadError(f"{where}: must be a file name, got {ref!r}")
    target = Path(ref) if Path(ref).is_absolute() else spec_path.parent / ref
    try:
        data = read_document(target, f"the file `{key}.file` names")
    except SpecReadError as err:
        raise SpecReadError(f"{where}: {err}") from None
    if isinstance(data, dict) and isinstance(data.get(key), dict):
        data = data[key]  # a whole spec: its block
    if not isinstance(data, dict):
        raise SpecReadError(f"{where}: {target} holds no mapping (a {key} block or a spec with "
                            f"one), got {type(data).__name__}")
    if "file" in data:
        raise SpecReadError(f"{where}: {target} names another file; files are not followed "
                            f"further")
    return {**data, **{k: v for k, v in block.items() if k != "file"}}
