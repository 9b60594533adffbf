"""The family driver (worker.family): a family's plan run as the service's jobs gives the same
family (members' objectives and params, every run, the checks) as `cmrt family run`'s runner
with the same seeds, both drivers of the one state machine (optim.family.machine), on the
synthetic family and on a short bend's real simulations; a killed driver resumes; cancel and
a failed run end the family."""

from __future__ import annotations

import threading
import time
from pathlib import Path
from typing import Any

import pytest
from local_pool import local_executor
from synthetic import LineFamily

from optim.executors import PoolExecutor, SerialExecutor
from optim.family.checks import family_checks
from optim.family.plan import plan_runs
from optim.family.spec import member_objective, parse_family
from optim.family_run import run_family
from store.records import CANCELLED, FAILED, FAMILY_DONE, FAMILY_RUNNING
from worker.driver import JobDriver
from worker.family import FamilyDriver

BASE: dict[str, Any] = {
    "name": "fam", "family": "fam", "task": {"type": "quiet_stance"},
    "clip": {"preparation": 1.0, "duration": 0.4, "decay": 1.0},
    "optimize": {"min_evaluations": 0, "window": 3, "improvement": 0.01, "popsize": 4,
                 "max_evaluations": 24},
}


def _family(**kw: Any) -> dict[str, Any]:
    return {"spec": BASE, "param": "clip.decay", "values": [1.0, 1.5, 2.0, 2.5, 3.0],
            "strategy": "continuation", "from": "both", "leave_out": [2.0],
            "warm": {"sigma0": 0.05, "window": 2, "max_evaluations": 12}, "k": 2, "seed": 4,
            **kw}


def _objective(fs: Any, value: float) -> LineFamily:
    return LineFamily(value=value, base=0.1, slope=0.2)


@pytest.fixture(autouse=True)
def members(monkeypatch):
    """Both drivers' members are the synthetic line family, the probes evaluated in this
    process (a test may set another objective)."""
    monkeypatch.setattr("worker.family.PoolExecutor", lambda _workers: SerialExecutor())
    monkeypatch.setattr("worker.family.member_objective", _objective)
    monkeypatch.setattr("optim.family_run.member_objective", _objective)
    return monkeypatch


@pytest.fixture
def executor(config):
    ex = local_executor(config, SerialExecutor(), lambda spec: _objective(None, spec.clip.decay))
    yield ex
    ex.close()


def _drive(repo, config, executor, family_id: str, *, stop_after: int | None = None,
           seconds: float = 60.0) -> str:
    """Advance the family, running each job it starts to its end in this thread (the probes
    are evaluated in the driver's probe thread: a step that starts nothing waits a little)."""
    started: list[str] = []

    def submit(job_id: str) -> None:
        started.append(job_id)
        JobDriver(repo, job_id, executor, config).run()

    driver = FamilyDriver(repo, config, submit=submit)
    status = FAMILY_RUNNING
    deadline = time.monotonic() + seconds
    try:
        while time.monotonic() < deadline:
            before = len(started)
            status = driver.advance(family_id)
            if status != FAMILY_RUNNING or (stop_after is not None
                                            and len(started) >= stop_after):
                break
            if len(started) == before:
                time.sleep(0.01)
    finally:
        driver.close()
    return status


def _create(repo, data: dict[str, Any]) -> str:
    fs = parse_family(data)
    return repo.create_family(fs.to_dict(), family=fs.family, param=fs.param).id


def _family_of(report: dict[str, Any]) -> dict[str, Any]:
    """What must be identical between the two drivers: each member's run, objective and
    params (by repr), every run's outcome (its wall time aside) and the checks."""
    return {
        "members": [(m["value"], m["run"], repr(m["objective"]), [repr(x) for x in m["params"]])
                    for m in report["members"]],
        "runs": [(r["id"], repr(r["objective"]), r["evaluations"], r["stop_rule"], r["curve"])
                 for r in report["runs"]],
        "checks": report["checks"],
    }


def test_service_family_equals_the_command_lines(repo, config, executor, tmp_path: Path):
    fid = _create(repo, _family())
    assert _drive(repo, config, executor, fid) == FAMILY_DONE
    report = repo.family_report(fid)
    fs = parse_family(_family())
    local = run_family(fs, SerialExecutor(), tmp_path / "cli")
    assert _family_of(report) == _family_of(local.report)
    assert report["checks"] == family_checks(fs, local.results, local.probes).to_dict()
    assert len(report["members"]) == 5 and len(report["checks"]["probes"]) == 3
    assert sorted(report["jobs"]) == sorted(r.id for r in plan_runs(fs) if r.id != "probes")
    jobs = repo.family_jobs(fid)
    warm = [j for j in jobs.values() if j.start and j.start.origin.startswith("member-")]
    assert warm and all(len(j.start.x0) == 8 for j in warm)  # warm-started from neighbours
    assert repo.get_family(fid).status == FAMILY_DONE
    # each member landed in the library with its parameter
    decays = {c.decay for c in repo.list_cmrts("fam", limit=100)[0]}
    assert decays == {1.0, 1.5, 2.0, 2.5, 3.0}


#: A short bend whose task duration is the family's parameter (tests/cli/test_family_cli.py's).
BEND: dict[str, Any] = {
    "spec": {"name": "fam_bend", "family": "bend",
             "clip": {"preparation": 0.3, "duration": 0.3, "decay": 0.3},
             "task": {"type": "pose_change",
                      "target": {"waist": -40, "shoulder_r": 40, "shoulder_l": 40}},
             "optimize": {"popsize": 4, "max_evaluations": 8, "min_evaluations": 0}},
    "param": "clip.duration", "values": [0.2, 0.3, 0.4, 0.5], "strategy": "continuation",
    "from": "both", "leave_out": [0.3], "k": 2, "seed": 3,
}


@pytest.mark.slow
def test_the_bend_family_is_the_same_through_both_drivers(repo, config, members,
                                                          tmp_path: Path):
    """Real simulations: the runner in this process over a pool of two, the service's jobs
    over the API's local pool."""
    members.setattr("worker.family.member_objective", member_objective)
    members.setattr("optim.family_run.member_objective", member_objective)
    sims = local_executor(config, SerialExecutor())
    fid = _create(repo, BEND)
    driver = FamilyDriver(repo, config, submit=lambda j: JobDriver(repo, j, sims, config).run())
    status, deadline = FAMILY_RUNNING, time.monotonic() + 600
    try:
        while status == FAMILY_RUNNING and time.monotonic() < deadline:
            status = driver.advance(fid)
            time.sleep(0.01)
    finally:
        driver.close()
        sims.close()
    assert status == FAMILY_DONE, repo.get_family(fid).error
    with PoolExecutor(2) as pool:
        local = run_family(parse_family(BEND), pool, tmp_path / "cli")
    assert _family_of(repo.family_report(fid)) == _family_of(local.report)
    assert [m["value"] for m in local.report["members"]] == [0.2, 0.3, 0.4, 0.5]


def test_a_driver_killed_midway_resumes_to_the_same_family(repo, config, executor):
    ref = _create(repo, _family())
    _drive(repo, config, executor, ref)
    fid = _create(repo, _family())
    assert _drive(repo, config, executor, fid, stop_after=3) == FAMILY_RUNNING
    made = dict(repo.get_family(fid).runs)
    assert _drive(repo, config, executor, fid) == FAMILY_DONE  # a new driver takes over
    assert all(repo.get_family(fid).runs[k] == v for k, v in made.items())  # no run made twice
    assert repo.family_report(fid)["checks"] == repo.family_report(ref)["checks"]


def test_cancel_ends_the_family_and_its_jobs(repo, config, executor):
    fid = _create(repo, _family())
    FamilyDriver(repo, config, submit=lambda _j: None).advance(fid)
    runs = repo.get_family(fid).runs
    assert runs and all(repo.get_job(j).status == "queued" for j in runs.values())
    repo.request_family_cancel(fid)
    assert FamilyDriver(repo, config).advance(fid) == CANCELLED
    assert all(repo.get_job(j).status == CANCELLED for j in runs.values())


def test_a_failed_run_fails_the_family_naming_it(repo, config, executor):
    fid = _create(repo, _family())
    FamilyDriver(repo, config, submit=lambda _j: None).advance(fid)
    run_id, job_id = sorted(repo.get_family(fid).runs.items())[0]
    repo.set_job_status(job_id, FAILED, error="boom")
    assert FamilyDriver(repo, config).advance(fid) == FAILED
    fam = repo.get_family(fid)
    assert run_id in fam.error and "boom" in fam.error


def test_a_family_whose_plan_cannot_be_computed_fails_with_the_reason(repo, config, executor,
                                                                      members):
    """Members that are all the same CMRT (an objective blind to the value): the reduced
    run's basis cannot be made; the family fails naming why instead of retrying for ever."""
    fid = _create(repo, _family(strategy="independent"))

    def same(fs: Any, value: float) -> LineFamily:
        return LineFamily(value=1.0, base=0.1, slope=0.2)

    flat = local_executor(config, SerialExecutor(), lambda spec: same(None, 0.0))
    members.setattr("worker.family.member_objective", same)
    driver = FamilyDriver(repo, config, submit=lambda j: JobDriver(repo, j, flat, config).run())
    status = FAMILY_RUNNING
    for _ in range(50):
        status = driver.advance(fid)
        if status != FAMILY_RUNNING:
            break
    flat.close()
    fam = repo.get_family(fid)
    assert status == FAILED and "identical" in fam.error, fam.error


class Gated:
    """A probe's objective that waits for `gate` (120 s at most) before evaluating `inner`:
    the probes of a family take as long as the test wants; `entered` and `left` tell when a
    probe started and when one stopped waiting."""

    def __init__(self, inner: LineFamily, gate: threading.Event, entered: threading.Event,
                 left: threading.Event) -> None:
        self.inner, self.gate, self.entered, self.left = inner, gate, entered, left

    def __call__(self, x: Any) -> Any:
        self.entered.set()
        self.gate.wait(120)
        self.left.set()
        return self.inner(x)


def test_a_familys_probes_hold_no_other_familys_step(repo, config, executor, members,
                                                     tmp_path: Path):
    """While one family's probes are evaluated (held here), its steps and another family's
    go on; the probes' outcomes are picked up by a later step and the checks are the command
    line's."""
    gate, entered, left = threading.Event(), threading.Event(), threading.Event()

    def gated(fs: Any, value: float) -> Gated:
        return Gated(_objective(fs, value), gate, entered, left)

    members.setattr("worker.family.member_objective", gated)
    driver = FamilyDriver(repo, config,
                          submit=lambda j: JobDriver(repo, j, executor, config).run())
    a = _create(repo, _family())
    try:
        deadline = time.monotonic() + 60
        while not entered.is_set():  # A's members, then its probes handed to the thread
            assert driver.advance(a) == FAMILY_RUNNING and time.monotonic() < deadline
        assert driver.advance(a) == FAMILY_RUNNING  # its own step does not wait either
        b = _create(repo, _family(seed=5))
        assert driver.advance(b) == FAMILY_RUNNING
        made = repo.get_family(b).runs
        assert made and all(repo.get_job(j).terminal for j in made.values())  # B's runs ran
        assert not left.is_set() and repo.family_probes(a) is None  # A's probe still runs
        gate.set()
        status = FAMILY_RUNNING
        while status == FAMILY_RUNNING and time.monotonic() < deadline + 60:
            status = driver.advance(a)
            time.sleep(0.01)
        assert status == FAMILY_DONE and repo.family_probes(a) is not None
    finally:
        gate.set()
        driver.close()
    fs = parse_family(_family())
    local = run_family(fs, SerialExecutor(), tmp_path / "cli")
    assert repo.family_report(a)["checks"] == family_checks(fs, local.results,
                                                            local.probes).to_dict()
