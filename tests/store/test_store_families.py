"""Contract: families (a request whose runs are jobs), job start points and result documents."""

from __future__ import annotations

import threading

import pytest

from store.errors import NotFound
from store.records import CANCELLED, FAILED, FAMILY_DONE, FAMILY_RUNNING, JobStart
from store.repository import SqlRepository

SPEC = {"spec": {"name": "d"}, "param": "task.mass", "values": [30.0, 40.0]}


def _job(name: str = "d_mass30") -> dict:
    return {"spec": {"name": name}, "name": name, "family": "domino", "task": "domino",
            "seed": 1, "start": JobStart("member-up-30", (0.5, 0.25))}


def test_family_round_trip_and_runs(repo: SqlRepository) -> None:
    f = repo.create_family(SPEC, family="domino", param="task.mass")
    assert (f.status, f.family, f.param, f.runs, f.cancel_requested) == (
        FAMILY_RUNNING, "domino", "task.mass", {}, False)
    a = repo.add_family_run(f.id, "member-up-30", **_job())
    again = repo.add_family_run(f.id, "member-up-30", **_job("other"))
    assert again.id == a.id and again.name == "d_mass30"  # idempotent: the first job stays
    assert a.start == JobStart("member-up-30", (0.5, 0.25))
    assert a.start.to_json() == {"from": "member-up-30", "x0": [0.5, 0.25]}
    b = repo.add_family_run(f.id, "reference-40", **_job("d_mass40"))
    got = repo.get_family(f.id)
    assert got.runs == {"member-up-30": a.id, "reference-40": b.id}
    assert {k: j.id for k, j in repo.family_jobs(f.id).items()} == got.runs
    scan = repo.family_scan(f.id)
    assert (scan.family, scan.results, scan.probes) == (got, {}, None)
    assert {k: j.id for k, j in scan.jobs.items()} == got.runs
    repo.set_job_result(a.id, {"objective": 1.5, "params": [0.1]})
    assert repo.job_result(a.id) == {"objective": 1.5, "params": [0.1]}
    assert repo.job_result(b.id) is None
    assert repo.family_scan(f.id).results == {}  # a result is read once its job is finished
    repo.set_job_status(a.id, "running")
    repo.set_job_status(a.id, "converged")
    repo.set_job_status(b.id, FAILED, error="boom")
    scan = repo.family_scan(f.id)
    assert scan.results == {"member-up-30": {"objective": 1.5, "params": [0.1]}}
    assert scan.jobs["reference-40"].error == "boom"
    assert repo.family_scan(f.id, known={"member-up-30"}).results == {}  # the caller has it
    repo.set_family_probes(f.id, [[35.0, {"objective": 2.0}]])
    assert repo.family_scan(f.id).probes == [[35.0, {"objective": 2.0}]]
    with pytest.raises(NotFound):
        repo.get_family("nope")
    with pytest.raises(NotFound):
        repo.family_scan("nope")
    with pytest.raises(NotFound):
        repo.add_family_run("nope", "x", **_job())
    with pytest.raises(NotFound):
        repo.job_result("nope")


def test_concurrent_run_creation_makes_one_job(repo: SqlRepository) -> None:
    f = repo.create_family(SPEC, family="domino", param="task.mass")
    ids: list[str] = []
    barrier = threading.Barrier(4)

    def add() -> None:
        barrier.wait()
        ids.append(repo.add_family_run(f.id, "member-up-30", **_job()).id)

    threads = [threading.Thread(target=add) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len(set(ids)) == 1 and repo.list_jobs()[1] == 1


def test_probes_report_finish_and_cancel(repo: SqlRepository) -> None:
    f = repo.create_family(SPEC, family="domino", param="task.mass")
    assert repo.family_probes(f.id) is None and repo.family_report(f.id) is None
    repo.set_family_probes(f.id, [[35.0, {"objective": 2.0}]])
    assert repo.family_probes(f.id) == [[35.0, {"objective": 2.0}]]
    assert [x.id for x in repo.active_families()] == [f.id]
    done = repo.finish_family(f.id, FAMILY_DONE, report={"checks": {"k": 3}})
    assert done.status == FAMILY_DONE and done.finished_at is not None
    assert repo.family_report(f.id) == {"checks": {"k": 3}}
    assert repo.finish_family(f.id, FAILED, error="late").status == FAMILY_DONE  # stays done
    assert repo.request_family_cancel(f.id).cancel_requested is False
    assert repo.active_families() == []
    g = repo.create_family(SPEC, family="domino", param="task.mass")
    assert repo.request_family_cancel(g.id).cancel_requested is True
    assert repo.finish_family(g.id, CANCELLED).status == CANCELLED
    items, total = repo.list_families()
    assert total == 2 and [x.id for x in items] == [g.id, f.id]
    assert [x.id for x in repo.list_families(status=CANCELLED)[0]] == [g.id]
    with pytest.raises(ValueError):
        repo.finish_family(g.id, FAMILY_RUNNING)
