"""A process's numeric fingerprint: does this process compute the same bits as another?

The hash of a short reference clip (`REFERENCE_SECONDS` of quiet stance with the default
character, its 1 kHz states and traces to the last bit) together with the versions of the
libraries that compute it (numpy, numba, ODE). Two workers with the same fingerprint give the
same objective to every candidate; two with different ones may not (another glibc whose libm
rounds a sine differently, another ODE build, a CPU without FMA: docs/benchmarks.md, "Same bits
on every worker"). Workers log and report it, evaluations record it (docs/service.md).
"""

from __future__ import annotations

import functools
import hashlib
import os
from dataclasses import dataclass
from typing import Any

#: Seconds of the reference clip: every part of a clip's step (ODE, the model, the momentum
#: QP, inverse dynamics) runs a few hundred times, for ~0.1 s of CPU.
REFERENCE_SECONDS = 0.2
#: Hex digits of the fingerprint (64 bits: two different numerics collide with odds 2^-64).
DIGEST_CHARS = 16


@dataclass(frozen=True)
class Fingerprint:
    """`digest`: the fingerprint; `clip`: the reference clip's hash alone; `versions`: the
    libraries' versions that went into it."""

    digest: str
    clip: str
    versions: dict[str, str]

    def to_dict(self) -> dict[str, Any]:
        """JSON form: {"fingerprint", "clip_sha256", "versions"}."""
        return {"fingerprint": self.digest, "clip_sha256": self.clip,
                "versions": dict(self.versions)}


def _ode_library() -> str:
    """The file name of the ODE library this process has loaded (its version is in it), or
    "unknown" off Linux."""
    try:
        with open(f"/proc/{os.getpid()}/maps") as f:
            paths = {line.split()[-1] for line in f if "libode" in line}
    except OSError:
        return "unknown"
    return ",".join(sorted(os.path.basename(os.path.realpath(p)) for p in paths)) or "unknown"


def library_versions() -> dict[str, str]:
    """numpy's, numba's and ODE's versions (ODE: its loaded library's file name)."""
    import numba
    import numpy as np
    import ode  # noqa: F401 - loaded so that its library is in the process's maps

    return {"numpy": np.__version__, "numba": numba.__version__, "ode": _ode_library()}


def reference_clip_hash() -> str:
    """SHA-256 of the reference clip's states and traces (their float64 bytes)."""
    import numpy as np

    from sim import evaluate, parse_spec

    spec = parse_spec({"name": "fingerprint", "task": {"type": "quiet_stance"},
                       "clip": {"preparation": 0.0, "duration": REFERENCE_SECONDS,
                                "decay": 0.0}})
    ev = evaluate(spec, None, traces=True)
    h = hashlib.sha256(repr((ev.objective, ev.steps, ev.fell)).encode())
    for part in (ev.states, ev.traces):
        for value in vars(part).values():
            h.update(np.ascontiguousarray(np.asarray(value, dtype=float)).tobytes())
    return h.hexdigest()


@functools.cache
def numeric_fingerprint() -> Fingerprint:
    """This process's fingerprint, computed once (the first call simulates the reference clip)."""
    versions = library_versions()
    clip = reference_clip_hash()
    text = clip + "".join(f";{k}={v}" for k, v in sorted(versions.items()))
    return Fingerprint(hashlib.sha256(text.encode()).hexdigest()[:DIGEST_CHARS], clip, versions)
