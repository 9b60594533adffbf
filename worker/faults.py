"""Fault-injection hooks for the fault-tolerance tests (and for drills on a staging cluster).

Read only by evaluation worker processes, never by the API, and not part of any task spec.
With both variables unset (the default) this module does nothing.

- `CMRT_FAULT_CRASH_ON`: a comma-separated list of `NAME:GENERATION:INDEX` patterns (`*`
  matches anything, NAME is the spec's `name`); an evaluation task whose candidate matches
  kills its own process with SIGKILL before evaluating, exactly like a segfault in the
  simulator would. Example: `CMRT_FAULT_CRASH_ON=poison:0:1` makes candidate 1 of generation 0
  of every job whose spec is named `poison` kill its worker on every attempt, so the job must
  fail after CMRT_MAX_ATTEMPTS attempts while other jobs finish.
- `CMRT_FAULT_DELAY_ON`: `NAME:GENERATION:INDEX:SECONDS` patterns; a matching candidate sleeps
  that long before evaluating, like a slow machine or a long clip. It holds a generation open
  for a known time, so a drill can kill or restart something while the generation is half done
  (with clips of a few tens of milliseconds that window is otherwise too short to hit).
"""

from __future__ import annotations

import fnmatch
import os
import signal
import time

ENV = "CMRT_FAULT_CRASH_ON"
DELAY_ENV = "CMRT_FAULT_DELAY_ON"
#: Every variable of this module: what a launcher strips from a process that must run clean.
ENV_VARS = (ENV, DELAY_ENV)
MAX_DELAY_S = 600.0  # s, a longer sleep would only trip the task's time limit


def _patterns(env: str, fields: int, form: str) -> list[list[str]]:
    raw = os.environ.get(env, "").strip()
    out = []
    for item in filter(None, (p.strip() for p in raw.split(","))):
        parts = item.split(":")
        if len(parts) != fields:
            raise ValueError(f"{env}: {item!r} is not {form}")
        out.append(parts)
    return out


def _matches(pattern: list[str], name: str, generation: int, index: int) -> bool:
    n, g, i = pattern[:3]
    return (fnmatch.fnmatchcase(name, n) and fnmatch.fnmatchcase(str(generation), g)
            and fnmatch.fnmatchcase(str(index), i))


def should_crash(name: str, generation: int, index: int) -> bool:
    return any(_matches(p, name, generation, index)
               for p in _patterns(ENV, 3, "NAME:GENERATION:INDEX"))


def delay_for(name: str, generation: int, index: int) -> float:
    """Seconds the candidate must sleep before evaluating (0 when no pattern matches)."""
    total = 0.0
    for p in _patterns(DELAY_ENV, 4, "NAME:GENERATION:INDEX:SECONDS"):
        try:
            seconds = float(p[3])
        except ValueError:
            raise ValueError(f"{DELAY_ENV}: SECONDS {p[3]!r} is not a number") from None
        if not 0.0 <= seconds <= MAX_DELAY_S:
            raise ValueError(f"{DELAY_ENV}: SECONDS must be in [0, {MAX_DELAY_S:g}], got {p[3]}")
        if _matches(p, name, generation, index):
            total += seconds
    return total


def maybe_crash(name: str, generation: int, index: int) -> None:
    """Kill this process (SIGKILL) if the candidate matches CMRT_FAULT_CRASH_ON."""
    if should_crash(name, generation, index):
        os.kill(os.getpid(), signal.SIGKILL)


def maybe_delay(name: str, generation: int, index: int) -> None:
    """Sleep if the candidate matches CMRT_FAULT_DELAY_ON."""
    seconds = delay_for(name, generation, index)
    if seconds > 0.0:
        time.sleep(seconds)
