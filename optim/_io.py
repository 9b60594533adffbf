"""Small file helpers shared by the optim modules."""

from __future__ import annotations

import contextlib
import json
import os
import tempfile
from pathlib import Path
from typing import Any


def atomic_write_bytes(path: str | Path, data: bytes) -> None:
    """Write `data` to `path` atomically: temp file in the same folder, fsync, os.replace.

    A reader sees either the old file or the complete new one, never a partial write, even if
    the process is killed mid-way. The parent folder is created if missing.
    """
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, target)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise
    try:  # make the rename itself durable
        dfd = os.open(target.parent, os.O_RDONLY)
    except OSError:
        return
    try:
        with contextlib.suppress(OSError):
            os.fsync(dfd)
    finally:
        os.close(dfd)


def atomic_write_text(path: str | Path, text: str) -> None:
    """`atomic_write_bytes` for UTF-8 text."""
    atomic_write_bytes(path, text.encode("utf-8"))


def read_json_file(path: str | Path, what: str) -> Any:
    """The JSON document in `path`; ResultFileError naming the file when it cannot be read or
    is not JSON (`what`: "result file", "basis file", ...)."""
    from optim.errors import ResultFileError

    p = Path(path)
    try:
        return json.loads(p.read_text())
    except OSError as err:
        raise ResultFileError(f"{p}: cannot read {what} ({err.strerror})") from None
    except json.JSONDecodeError as err:
        raise ResultFileError(f"{p}: not valid JSON ({err})") from None

