"""Process helpers shared by the tests that start servers and workers in their own sessions."""
from __future__ import annotations

import contextlib
import os
import signal
import socket
import subprocess
from pathlib import Path

#: The checkout: the product's packages, and tests/ beside them.
ROOT = Path(__file__).resolve().parents[1]
#: s: how long a process group gets to finish after SIGTERM before it is killed.
TERM_GRACE_S = 30.0
#: s: how long the wait after SIGKILL may take.
KILL_WAIT_S = 10.0


def child_env() -> dict[str, str]:
    """This environment for a Python child that imports the tests' helpers (`synthetic`): the
    checkout and tests/ on its path, in pytest's order (the product's `store` before the tests'
    `store/` folder)."""
    return {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), str(ROOT / "tests")])}


def stop_group(proc: subprocess.Popen, grace: float = TERM_GRACE_S) -> None:
    """Stop `proc`'s process group (started with ``start_new_session=True``): SIGTERM, then
    SIGKILL if it has not exited within `grace` seconds. A group already gone is fine."""
    if proc.poll() is not None:
        return
    with contextlib.suppress(ProcessLookupError):
        os.killpg(proc.pid, signal.SIGTERM)
    try:
        proc.wait(grace)
    except subprocess.TimeoutExpired:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(KILL_WAIT_S)


def free_port() -> int:
    """A TCP port free on loopback now (for a server a test starts)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def tiny_bend(name: str, duration: float, optimize: dict) -> dict:
    """A bend spec of a fraction of a second, for jobs that must end in seconds."""
    return {"name": name, "family": "bend",
            "clip": {"preparation": 0.3, "duration": duration, "decay": 0.2},
            "task": {"type": "pose_change", "target": {"waist": -30}},
            "optimize": dict(optimize)}

