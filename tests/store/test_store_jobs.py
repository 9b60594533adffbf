"""Contract: jobs, their state machine, listing, cancellation and driver leases."""

from __future__ import annotations

import threading
from datetime import UTC

import pytest
from sqlalchemy import text
from sqlalchemy.exc import OperationalError

from store import open_repository
from store.errors import Conflict, InvalidTransition, NotFound
from store.records import JOB_STATUSES, TERMINAL_STATUSES, TRANSITIONS
from store.repository import SqlRepository

SPEC = {"name": "fast_bend", "task": "pose_change", "clip": {"duration": 0.4}}


def new_job(repo: SqlRepository, family: str = "bend", **kw):
    kw = {"name": "fast_bend", "family": family, "task": "pose_change", "seed": 1, **kw}
    return repo.create_job(SPEC, **kw)


def test_create_and_get_round_trip(repo: SqlRepository) -> None:
    job = new_job(repo, workers=3)
    assert job.status == "queued" and not job.terminal
    got = repo.get_job(job.id)
    assert got == job
    assert got.spec == SPEC and got.seed == 1 and got.workers == 3
    assert got.created_at.tzinfo is UTC
    assert (got.evaluations, got.iterations, got.best_objective) == (0, 0, None)
    assert got.cancel_requested is False and got.driver_owner is None


def test_spec_is_stored_with_the_hash_of_its_canonical_text(repo: SqlRepository) -> None:
    """The boundary's hash is kept as given; without one the store hashes the document by the
    same rule (cmrt.canonical), so both keys name the same spec in every process."""
    from cmrt.canonical import document_hash

    computed = new_job(repo)
    assert computed.spec_hash == document_hash(SPEC) == repo.get_job(computed.id).spec_hash
    given = new_job(repo, spec_hash="a" * 64)
    assert repo.get_job(given.id).spec_hash == "a" * 64
    fam = repo.create_family({"spec": SPEC, "values": [0.3]}, family="bend", param="clip.x")
    assert repo.get_family(fam.id).spec_hash == document_hash({"spec": SPEC, "values": [0.3]})


def test_ping_reads_the_jobs_table(repo: SqlRepository, tmp_path) -> None:
    repo.ping()  # no job: still fine
    new_job(repo)
    repo.ping()
    gone = open_repository(f"sqlite:///{tmp_path}/gone.db")
    with gone.engine.begin() as conn:  # the schema lost: the ping says so
        conn.execute(text("DROP TABLE jobs"))
    with pytest.raises(OperationalError, match="no such table"):
        gone.ping()
    gone.engine.dispose()


def test_unknown_job_is_not_found(repo: SqlRepository) -> None:
    for call in (
        lambda: repo.get_job("nope"),
        lambda: repo.set_job_status("nope", "running"),
        lambda: repo.request_cancel("nope"),
        lambda: repo.acquire_driver_lease("nope", "a", 10),
    ):
        with pytest.raises(NotFound):
            call()


def test_lifecycle_sets_timestamps_and_stop_rule(repo: SqlRepository) -> None:
    job = new_job(repo)
    running = repo.set_job_status(job.id, "running")
    assert running.status == "running" and running.started_at is not None
    assert running.finished_at is None
    done = repo.set_job_status(job.id, "converged", stop_rule="threshold")
    assert done.status == "converged" and done.terminal
    assert done.stop_rule == "threshold" and done.finished_at >= done.started_at
    assert repo.get_job(job.id) == done


def test_failed_keeps_error(repo: SqlRepository) -> None:
    job = new_job(repo)
    repo.set_job_status(job.id, "running")
    failed = repo.set_job_status(job.id, "failed", error="candidate 3 killed its worker")
    assert failed.error == "candidate 3 killed its worker"


LEGAL = [(a, b) for a in JOB_STATUSES for b in JOB_STATUSES if b in TRANSITIONS[a]]
ILLEGAL = [
    (a, b) for a in JOB_STATUSES for b in JOB_STATUSES if b not in TRANSITIONS[a] and a != b
]


PATHS = {
    "queued": [],
    "running": ["running"],
    "cancelled": ["cancelled"],
    "failed": ["failed"],
    "converged": ["running", "converged"],
    "stopped": ["running", "stopped"],
}


def _bring_to(repo: SqlRepository, status: str):
    job = new_job(repo)
    for step in PATHS[status]:
        job = repo.set_job_status(job.id, step)
    return job


def test_transition_table_is_the_designed_one() -> None:
    assert TRANSITIONS["queued"] == {"running", "failed", "cancelled"}
    assert TRANSITIONS["running"] == {"converged", "stopped", "failed", "cancelled"}
    assert all(not TRANSITIONS[t] for t in TERMINAL_STATUSES)


@pytest.mark.parametrize(("start", "end"), LEGAL)
def test_legal_transitions(repo: SqlRepository, start: str, end: str) -> None:
    job = _bring_to(repo, start)
    assert job.status == start
    assert repo.set_job_status(job.id, end).status == end


@pytest.mark.parametrize(("start", "end"), ILLEGAL)
def test_illegal_transitions_raise(repo: SqlRepository, start: str, end: str) -> None:
    job = _bring_to(repo, start)
    with pytest.raises(InvalidTransition) as info:
        repo.set_job_status(job.id, end)
    assert (info.value.current, info.value.requested) == (start, end)
    assert repo.get_job(job.id).status == start


def test_same_status_is_a_no_op_and_unknown_status_refused(repo: SqlRepository) -> None:
    job = new_job(repo)
    running = repo.set_job_status(job.id, "running")
    assert repo.set_job_status(job.id, "running") == running
    with pytest.raises(ValueError, match="unknown job status"):
        repo.set_job_status(job.id, "paused")


def test_racing_transitions_only_one_wins(repo: SqlRepository) -> None:
    job = new_job(repo)
    repo.set_job_status(job.id, "running")
    results: list[str] = []
    barrier = threading.Barrier(2)

    def finish(status: str) -> None:
        barrier.wait()
        try:
            repo.set_job_status(job.id, status)
            results.append(status)
        except InvalidTransition:
            results.append("refused")

    threads = [threading.Thread(target=finish, args=(s,)) for s in ("converged", "cancelled")]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert sorted(results).count("refused") == 1
    assert repo.get_job(job.id).status in results


def test_request_cancel(repo: SqlRepository) -> None:
    queued = new_job(repo)
    cancelled = repo.request_cancel(queued.id)
    assert cancelled.status == "cancelled" and cancelled.finished_at is not None

    running = new_job(repo)
    repo.set_job_status(running.id, "running")
    assert repo.cancel_requested(running.id) is False
    flagged = repo.request_cancel(running.id)
    assert flagged.status == "running" and flagged.cancel_requested
    assert repo.cancel_requested(running.id) is True
    with pytest.raises(NotFound):
        repo.cancel_requested("no-such-job")
    assert repo.set_job_status(running.id, "cancelled").status == "cancelled"
    # the flags of several jobs in one read; an unknown job is left out
    other = new_job(repo)
    assert repo.cancel_flags([running.id, other.id, "no-such-job"]) == {
        running.id: True, other.id: False}
    assert repo.cancel_flags([]) == {}

    finished = new_job(repo)
    repo.set_job_status(finished.id, "running")
    repo.set_job_status(finished.id, "stopped", stop_rule="max_evaluations")
    assert repo.request_cancel(finished.id).status == "stopped"


def test_list_jobs_filters_and_pagination(repo: SqlRepository) -> None:
    bends = [new_job(repo, "bend") for _ in range(5)]
    pushes = [new_job(repo, "push") for _ in range(3)]
    for j in bends[:2]:
        repo.set_job_status(j.id, "running")

    items, total = repo.list_jobs()
    assert total == 8 and len(items) == 8
    assert [j.created_at for j in items] == sorted((j.created_at for j in items), reverse=True)

    items, total = repo.list_jobs(family="push")
    assert total == 3 and {j.id for j in items} == {j.id for j in pushes}

    items, total = repo.list_jobs(status="running")
    assert total == 2 and {j.id for j in items} == {j.id for j in bends[:2]}

    items, total = repo.list_jobs(status=["running", "queued"], family="bend")
    assert total == 5

    pages = [repo.list_jobs(family="bend", limit=2, offset=o) for o in (0, 2, 4)]
    assert [len(p[0]) for p in pages] == [2, 2, 1] and all(p[1] == 5 for p in pages)
    seen = [j.id for p in pages for j in p[0]]
    assert len(set(seen)) == 5 and set(seen) == {j.id for j in bends}
    assert repo.list_jobs(family="none") == ([], 0)


def test_basis_reference_must_exist(repo: SqlRepository) -> None:
    with pytest.raises(Conflict):
        new_job(repo, basis_id="missing")
    basis_id = repo.add_basis(
        family="bend", k=1, mean=[0.5, 0.5], components=[[1.0, 0.0]],
        variance_explained=[0.9], members=[],
    )  # fmt: skip
    assert new_job(repo, basis_id=basis_id).basis_id == basis_id


# ---- driver lease ------------------------------------------------------------------------
def test_lease_exclusive_renew_and_takeover_after_expiry(repo: SqlRepository, clock) -> None:
    job = new_job(repo)
    assert repo.acquire_driver_lease(job.id, "driver-a", 30)
    assert repo.acquire_driver_lease(job.id, "driver-a", 30)  # re-entrant
    assert not repo.acquire_driver_lease(job.id, "driver-b", 30)
    rec = repo.get_job(job.id)
    assert rec.driver_owner == "driver-a" and rec.lease_expires_at > rec.heartbeat_at
    assert repo.orphaned_jobs() == []

    clock.advance(20)
    assert repo.renew_driver_lease(job.id, "driver-a", 30)
    clock.advance(20)  # still within the renewed lease
    assert not repo.acquire_driver_lease(job.id, "driver-b", 30)

    clock.advance(15)  # driver-a died: its lease ran out
    assert [j.id for j in repo.orphaned_jobs()] == [job.id]
    assert repo.acquire_driver_lease(job.id, "driver-b", 30)
    assert repo.get_job(job.id).driver_owner == "driver-b"
    assert not repo.renew_driver_lease(job.id, "driver-a", 30)  # a notices it lost the job

    repo.release_driver_lease(job.id, "driver-a")  # not the holder: no effect
    assert repo.get_job(job.id).driver_owner == "driver-b"
    repo.release_driver_lease(job.id, "driver-b")
    assert repo.get_job(job.id).driver_owner is None
    assert repo.acquire_driver_lease(job.id, "driver-c", 30)


def test_finished_job_has_no_lease(repo: SqlRepository) -> None:
    job = new_job(repo)
    assert repo.acquire_driver_lease(job.id, "a", 30)
    repo.set_job_status(job.id, "running")
    done = repo.set_job_status(job.id, "converged")
    assert done.driver_owner is None
    assert not repo.acquire_driver_lease(job.id, "a", 30)
    assert repo.orphaned_jobs() == []


def test_concurrent_lease_acquisition_has_one_winner(repo: SqlRepository) -> None:
    job = new_job(repo)
    barrier = threading.Barrier(4)
    won: list[str] = []

    def grab(owner: str) -> None:
        barrier.wait()
        if repo.acquire_driver_lease(job.id, owner, 30):
            won.append(owner)

    threads = [threading.Thread(target=grab, args=(f"d{i}",)) for i in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len(won) == 1 and repo.get_job(job.id).driver_owner == won[0]
