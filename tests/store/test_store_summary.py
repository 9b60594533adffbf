"""Contract: the dashboard's reads, `evaluation_summary` (counts per generation in one query)
and `list_bases`, on SQLite and PostgreSQL."""

from __future__ import annotations

import pytest

from store.errors import NotFound
from store.repository import SqlRepository


def test_evaluation_summary_counts_states_attempts_and_repeats(repo: SqlRepository) -> None:
    job = repo.create_job({"name": "j"}, name="j", family="f", task="push", seed=1)
    repo.set_job_status(job.id, "running")
    for g in (0, 1, 2):
        repo.put_pending_evaluations(job.id, g, [[0.1], [0.2], [0.3]])
    repo.put_pending_evaluations(job.id, -1, [[0.5], [0.1]])  # the final pair
    for i in range(3):
        repo.store_result(job.id, 0, i, objective=1.0 + i, fell=False, cpu_seconds=0.1)
    for _ in range(3):  # started three times (two crashes), then done
        repo.claim_evaluation(job.id, 1, 0)
    repo.store_result(job.id, 1, 0, objective=2.0, fell=False, cpu_seconds=0.1)
    repo.claim_evaluation(job.id, 1, 1)
    repo.fail_evaluation(job.id, 1, 1, "its worker process died every time")
    repo.claim_evaluation(job.id, 1, 2)  # running now
    out = repo.evaluation_summary(job.id)
    assert out == [
        {"generation": -1, "population": 2, "done": 0, "pending": 2, "failed": 0,
         "attempts": 0, "repeated": 0},
        {"generation": 0, "population": 3, "done": 3, "pending": 0, "failed": 0,
         "attempts": 3, "repeated": 0},
        {"generation": 1, "population": 3, "done": 1, "pending": 1, "failed": 1,
         "attempts": 5, "repeated": 2},
        {"generation": 2, "population": 3, "done": 0, "pending": 3, "failed": 0,
         "attempts": 0, "repeated": 0},
    ]
    assert [r["generation"] for r in repo.evaluation_summary(job.id, after=1)] == [-1, 2]
    assert repo.evaluation_summary(job.id, after=5) == out[:1]
    with pytest.raises(NotFound):
        repo.evaluation_summary("nope")


def test_list_bases_newest_first_by_family(repo: SqlRepository, clock) -> None:
    def basis(family: str) -> str:
        clock.advance(1.0)
        return repo.add_basis(family=family, k=1, mean=[0.5, 0.5], components=[[1.0, 0.0]],
                              variance_explained=[0.9, 0.1], members=["a", "b"])

    a, b, c = basis("bend"), basis("push"), basis("bend")
    items, total = repo.list_bases("bend")
    assert total == 2 and [x.id for x in items] == [c, a]
    assert items[0].variance_explained == [0.9, 0.1] and items[0].members == ["a", "b"]
    items, total = repo.list_bases(limit=1, offset=1)
    assert total == 3 and [x.id for x in items] == [b]
    assert repo.list_bases("nope") == ([], 0)
