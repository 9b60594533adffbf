"""Fault-injection hook for the fault-tolerance tests (and for drills on a staging cluster).

`CMRT_FAULT_CRASH_ON` is read only by evaluation worker processes, never by the API, and is not
part of any task spec. It holds a comma-separated list of `NAME:GENERATION:INDEX` patterns
(`*` matches anything, NAME is the spec's `name`); an evaluation task whose candidate matches
kills its own process with SIGKILL before evaluating, exactly like a segfault in the simulator
would. With it unset (the default) this module does nothing.

Example: `CMRT_FAULT_CRASH_ON=poison:0:1` makes candidate 1 of generation 0 of every job whose
spec is named `poison` kill its worker on every attempt, so the job must fail after
CMRT_MAX_ATTEMPTS attempts while other jobs finish.
"""

from __future__ import annotations

import fnmatch
import os
import signal

ENV = "CMRT_FAULT_CRASH_ON"


def _patterns() -> list[tuple[str, str, str]]:
    raw = os.environ.get(ENV, "").strip()
    out = []
    for item in filter(None, (p.strip() for p in raw.split(","))):
        parts = item.split(":")
        if len(parts) != 3:
            raise ValueError(f"{ENV}: {item!r} is not NAME:GENERATION:INDEX")
        out.append((parts[0], parts[1], parts[2]))
    return out


def should_crash(name: str, generation: int, index: int) -> bool:
    return any(
        fnmatch.fnmatchcase(name, n)
        and fnmatch.fnmatchcase(str(generation), g)
        and fnmatch.fnmatchcase(str(index), i)
        for n, g, i in _patterns()
    )


def maybe_crash(name: str, generation: int, index: int) -> None:
    """Kill this process (SIGKILL) if the candidate matches CMRT_FAULT_CRASH_ON."""
    if should_crash(name, generation, index):
        os.kill(os.getpid(), signal.SIGKILL)
