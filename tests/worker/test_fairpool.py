"""FairPool on real processes: round robin between jobs, dropping a stopped job's candidates,
process deaths and the time limit reported per candidate."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest
from proc_helpers import child_env
from synthetic import KillWorker, Sleep, Sphere

from optim.errors import EvaluationError
from optim.outcome import EvalOutcome
from worker.fairpool import FairPool


class StopError(Exception):
    pass


@pytest.fixture
def pool():
    p = FairPool(2, time_limit=5.0)
    # start both slots (imports) before anything is timed
    p.run("warm", Sphere(), [np.zeros(2)] * 2, lambda: None, lambda i, o: None)
    yield p
    p.close()


def test_a_small_job_does_not_wait_for_a_large_one_s_batch(pool):
    order: list[tuple[str, float]] = []
    big = threading.Thread(target=pool.run, args=(
        "big", Sleep(0.3), [np.zeros(2)] * 12, lambda: None,
        lambda i, o: order.append(("big", time.monotonic()))))
    big.start()
    while pool.started.get("big", 0) < 2:  # the big job's 12 are queued, 2 of them running
        time.sleep(0.01)
    got = []
    pool.run("small", Sleep(0.3), [np.zeros(2)] * 2, lambda: None,
             lambda i, o: got.append(o))
    big_before = len(order)  # big results that came before the small job's last one
    big.join(60)
    assert all(isinstance(o, EvalOutcome) for o in got) and len(got) == 2
    assert len(order) == 12
    # first in, first out would finish all 12 big candidates first; round robin starts the
    # small job's candidates as the first and the third slot become free
    assert big_before <= 5, big_before


def test_a_stopped_job_s_candidates_are_dropped_and_others_go_on(pool):
    calls = {"n": 0}

    def check():
        calls["n"] += 1
        if calls["n"] > 3:
            raise StopError

    with pytest.raises(StopError):
        pool.run("cancelled", Sleep(3600.0), [np.zeros(2)] * 6, check, lambda i, o: None)
    assert pool.started["cancelled"] == 2  # the four queued never started
    # the two running were killed: the next job gets both slots at once (not in an hour)
    got = []
    pool.run("next", Sphere(centre=0.0), [np.ones(2)] * 3, lambda: None,
             lambda i, o: got.append((i, o.objective)))
    assert sorted(got) == [(0, 2.0), (1, 2.0), (2, 2.0)]


def test_process_death_and_time_limit_are_per_candidate(tmp_path):
    p = FairPool(1, time_limit=1.0)
    try:
        got = {}
        p.run("j", KillWorker(), [np.zeros(2)], lambda: None,
              lambda i, o: got.setdefault("dead", o))
        assert isinstance(got["dead"], EvaluationError) and "died" in str(got["dead"])
        p.run("j", Sleep(20.0), [np.zeros(2)], lambda: None,
              lambda i, o: got.setdefault("slow", o))
        assert isinstance(got["slow"], EvaluationError) and "time limit" in str(got["slow"])
        p.run("j", Sphere(centre=0.0), [np.ones(3)], lambda: None,
              lambda i, o: got.setdefault("ok", o))
        assert got["ok"].objective == 3.0  # the slot was restarted
    finally:
        p.close()


_OWNER = """
import os, sys, time
import numpy as np
from synthetic import Sleep
from worker.fairpool import FairPool
pool = FairPool(2)
pool.run("j", Sleep(0.0), [np.zeros(2)] * 2, lambda: None, lambda i, o: None)
slots = pool.pids()
print(" ".join(map(str, slots)), flush=True)
time.sleep(600)
"""


def _gone(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat", "rb") as fh:
            return fh.read().rsplit(b")", 1)[1].split()[0] == b"Z"
    except FileNotFoundError:
        return True


def test_slots_end_when_their_server_is_killed_with_sigkill():
    import subprocess
    import sys

    owner = subprocess.Popen([sys.executable, "-c", _OWNER], stdout=subprocess.PIPE, text=True,
                             env=child_env())
    try:
        pids = [int(p) for p in owner.stdout.readline().split()]
        assert len(pids) == 2 and not any(_gone(p) for p in pids)
    finally:
        owner.kill()  # SIGKILL: no clean-up runs in the server
        owner.wait(10)
    t0 = time.monotonic()
    while not all(_gone(p) for p in pids):
        assert time.monotonic() - t0 < 60, f"slot processes {pids} outlived their server"
        time.sleep(0.1)
