"""Contract: the CMRT library (queries by task parameter) and PCA bases."""

from __future__ import annotations

import numpy as np
import pytest
from store_helpers import cmrt_families, list_bases

from store.errors import Conflict, NotFound
from store.records import CmrtEntry
from store.repository import SqlRepository

HUMANOID = {"model": "humanoid", "height": 1.75, "mass": 70.0}


def add(repo: SqlRepository, family: str = "push", objective: float = 1.0, **params) -> str:
    kw = dict(
        family=family, character=HUMANOID, task_parameters=params, preparation=1.0,
        duration=params.get("duration", 0.4), decay=1.0,
        params=[0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8], knots=[0.2, 0.5, 0.8, 1.2],
        values=[0.01, -0.02, 0.03, 0.0], curve={"t": [0.0, 0.5, 1.0], "x": [0.0, 0.01, 0.0]},
        objective=objective, objective_without=objective * 3, fell=False, fell_without=True,
    )  # fmt: skip
    return repo.add_cmrt(CmrtEntry(**kw))


def test_cmrt_round_trip(repo: SqlRepository) -> None:
    job = repo.create_job({"name": "p"}, name="p", family="push", task="push", seed=1)
    cid = repo.add_cmrt(CmrtEntry(
        family="push", character=HUMANOID, task_parameters={"duration": 0.2, "force": -250.0},
        preparation=1.0, duration=0.2, decay=1.5, params=np.linspace(0, 1, 8),
        knots=[0.1, 0.4, 0.9, 1.3], values=[[0.01, 0.0], [0.02, -0.01], [0.0, 0.0], [0, 0]],
        curve={"t": [0.0, 0.1], "x": [0.0, 0.001]}, objective=2.5, objective_without=8.0,
        fell=False, fell_without=True, job_id=job.id, spec={"name": "p", "task": "push"},
        winner="flat",
    ))  # fmt: skip
    rec = repo.get_cmrt(cid)
    assert rec.id == cid and rec.family == "push" and rec.job_id == job.id
    assert rec.character == HUMANOID
    assert rec.task_parameters == {"duration": 0.2, "force": -250.0}
    assert (rec.preparation, rec.duration, rec.decay) == (1.0, 0.2, 1.5)
    assert rec.params == pytest.approx(list(np.linspace(0, 1, 8)))
    assert rec.values[1] == [0.02, -0.01] and rec.curve["x"] == [0.0, 0.001]
    assert (rec.objective, rec.objective_without, rec.fell, rec.fell_without) == (
        2.5, 8.0, False, True,
    )  # fmt: skip
    assert rec.spec == {"name": "p", "task": "push"} and rec.created_at.tzinfo is not None
    assert rec.winner == "flat" and repo.job_cmrt(job.id) == rec
    assert repo.job_cmrt("no-such-job") is None
    with pytest.raises(NotFound):
        repo.get_cmrt("nope")


def test_cmrt_input_checks(repo: SqlRepository) -> None:
    with pytest.raises(Conflict):
        repo.add_cmrt(CmrtEntry(**{**_minimal(), "job_id": "missing"}))
    with pytest.raises(ValueError):
        repo.add_cmrt(CmrtEntry(**{**_minimal(), "task_parameters": {"force": float("nan")}}))
    with pytest.raises(ValueError):
        repo.add_cmrt(CmrtEntry(**{**_minimal(), "task_parameters": {"": 1.0}}))
    with pytest.raises(ValueError, match="winner"):
        repo.add_cmrt(CmrtEntry(**{**_minimal(), "winner": "lucky"}))
    assert repo.list_cmrts() == ([], 0)


def _minimal() -> dict:
    return dict(
        family="f", character=HUMANOID, task_parameters={"duration": 0.4}, preparation=1.0,
        duration=0.4, decay=1.0, params=[0.5], knots=[0.1], values=[0.0], curve=[],
        objective=1.0,
    )  # fmt: skip


def test_find_exact(repo: SqlRepository) -> None:
    a = add(repo, duration=0.4, force=100.0)
    b = add(repo, duration=0.4, force=200.0)
    c = add(repo, duration=0.3, force=100.0)
    add(repo, family="bend", duration=0.4)

    assert [r.id for r in repo.find_cmrts("push", {"duration": 0.4, "force": 100.0})] == [a]
    assert {r.id for r in repo.find_cmrts("push", {"duration": 0.4})} == {a, b}
    assert {r.id for r in repo.find_cmrts("push", {"force": 100.0})} == {a, c}
    assert repo.find_cmrts("push", {"duration": 0.5}) == []
    assert repo.find_cmrts("push", {"mass": 70.0}) == []  # no CMRT has that parameter
    # a value computed differently but equal to within rounding still matches
    assert [r.id for r in repo.find_cmrts("push", {"duration": 0.1 * 3})] == [c]


def test_find_nearest_within_tolerance(repo: SqlRepository) -> None:
    near = add(repo, duration=0.40, force=150.0)
    mid = add(repo, duration=0.45, force=150.0)
    far = add(repo, duration=0.70, force=150.0)
    other = add(repo, duration=0.42, force=400.0)

    found = repo.find_cmrts("push", {"duration": 0.41}, tolerance=0.1)
    assert [r.id for r in found] == [near, other, mid]
    assert far not in {r.id for r in found}
    assert [r.id for r in repo.find_cmrts("push", {"duration": 0.41}, tolerance=0.1, limit=1)] == [
        near
    ]
    # per-parameter tolerances; distance is scaled by each tolerance
    found = repo.find_cmrts(
        "push", {"duration": 0.44, "force": 160.0}, tolerance={"duration": 0.1, "force": 50.0}
    )
    assert [r.id for r in found] == [mid, near]
    # names missing from the mapping must match exactly
    found = repo.find_cmrts("push", {"duration": 0.44, "force": 150.0}, tolerance={"duration": 1})
    assert [r.id for r in found] == [mid, near, far]
    with pytest.raises(ValueError):
        repo.find_cmrts("push", {"duration": 0.4}, tolerance=-1.0)


def test_find_ties_prefer_lower_objective_and_character_filter(repo: SqlRepository) -> None:
    worse = add(repo, objective=5.0, duration=0.4)
    better = add(repo, objective=2.0, duration=0.4)
    tall_humanoid = {**HUMANOID, "height": 1.9}
    tall = repo.add_cmrt(CmrtEntry(
        **{**_minimal(), "family": "push", "objective": 9.0, "character": tall_humanoid}
    ))
    assert [r.id for r in repo.find_cmrts("push", {"duration": 0.4})] == [better, worse, tall]
    found = repo.find_cmrts("push", {"duration": 0.4}, character={"height": 1.9})
    assert [r.id for r in found] == [tall]


def test_many_entries_nearest_order(repo: SqlRepository) -> None:
    ids = {i: add(repo, family="sweep", duration=0.01 * i) for i in range(1, 61)}
    found = repo.find_cmrts("sweep", {"duration": 0.302}, tolerance=0.02)
    assert [r.id for r in found] == [ids[30], ids[31], ids[29], ids[32]]
    assert [r.id for r in repo.find_cmrts("sweep", {"duration": 0.3})] == [ids[30]]


def test_list_cmrts_and_families(repo: SqlRepository) -> None:
    ids = [add(repo, duration=0.1 * i) for i in range(1, 6)]
    add(repo, family="bend", duration=0.4)
    items, total = repo.list_cmrts("push")
    assert total == 5 and {r.id for r in items} == set(ids)
    page, total = repo.list_cmrts("push", limit=2, offset=4)
    assert total == 5 and len(page) == 1
    assert repo.list_cmrts()[1] == 6
    assert cmrt_families(repo) == {"bend": 1, "push": 5}
    assert repo.cmrt_families() == [("bend", 1), ("push", 5)]


def test_cmrt_keys(repo: SqlRepository) -> None:
    a = add(repo, duration=0.3, force=10.0, objective=2.0)
    b = repo.add_cmrt(CmrtEntry(**{**_minimal(), "family": "push", "spec": {"name": "s"},
                                   "values": [[0.0, 0.1], [0.1, 0.0]], "knots": [0.2, 0.4]}))
    add(repo, family="bend", duration=0.4)
    keys = repo.cmrt_keys("push")
    listed, _ = repo.list_cmrts("push")
    assert [k.id for k in keys] == [r.id for r in listed]  # the same order, newest first
    by_id = {k.id: k for k in keys}
    assert by_id[a].task_parameters == {"duration": 0.3, "force": 10.0}
    assert (by_id[a].objective, by_id[a].knots, by_id[a].vertical) == (2.0, 4, False)
    assert not by_id[a].has_spec and by_id[b].has_spec
    assert (by_id[b].knots, by_id[b].vertical) == (2, True)
    assert by_id[a].created_at == repo.get_cmrt(a).created_at
    assert repo.cmrt_keys("nobody") == []


# ---- bases -------------------------------------------------------------------------------
def test_basis_round_trip(repo: SqlRepository) -> None:
    members = [add(repo, duration=0.1 * i) for i in range(1, 4)]
    comps = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 0.6, 0.8, 0.0]])
    bid = repo.add_basis(
        family="push", k=2, mean=np.array([0.5, 0.4, 0.3, 0.2]), components=comps,
        variance_explained=[0.7, 0.25], members=members,
        box={"low": [-1.0, -0.5], "high": [1.0, 0.5]},
    )  # fmt: skip
    b = repo.get_basis(bid)
    assert (b.id, b.family, b.k) == (bid, "push", 2)
    assert b.mean == [0.5, 0.4, 0.3, 0.2] and b.components == comps.tolist()
    assert b.variance_explained == [0.7, 0.25] and b.members == members
    assert b.box == {"low": [-1.0, -0.5], "high": [1.0, 0.5]}
    second = repo.add_basis(
        family="push", k=1, mean=[0.0], components=[[1.0]], variance_explained=[1.0], members=[]
    )
    assert [x.id for x in list_bases(repo, "push")] == [second, bid]
    assert list_bases(repo, "bend") == []
    with pytest.raises(NotFound):
        repo.get_basis("nope")


def test_basis_shape_is_checked(repo: SqlRepository) -> None:
    with pytest.raises(ValueError):
        repo.add_basis(
            family="push", k=2, mean=[0.0, 0.0], components=[[1.0, 0.0]],
            variance_explained=[1.0], members=[],
        )  # fmt: skip
    with pytest.raises(ValueError):
        repo.add_basis(
            family="push", k=1, mean=[0.0, 0.0], components=[[1.0]],
            variance_explained=[1.0], members=[],
        )  # fmt: skip


def test_verification_first_stored_wins(repo: SqlRepository) -> None:
    assert repo.get_verification("s" * 64, "p" * 64) is None
    first = repo.add_verification(
        family="domino", spec_hash="s" * 64, params_hash="p" * 64, source="interpolated",
        members=["a", "b"], outcome={"status": "done", "objective": 1.25, "fell": False,
                                     "fall_direction": None, "task_success": True})
    assert first.source == "interpolated" and first.members == ["a", "b"]
    assert first.outcome["objective"] == 1.25 and first.outcome["task_success"] is True
    # a second outcome for the same (spec, CMRT): the first is kept and given back
    again = repo.add_verification(
        family="domino", spec_hash="s" * 64, params_hash="p" * 64, source="member",
        members=["a"], outcome={"status": "done", "objective": 9.0, "fell": True})
    assert again.id == first.id and again.outcome == first.outcome
    assert repo.get_verification("s" * 64, "p" * 64).id == first.id
    other = repo.add_verification(
        family="domino", spec_hash="s" * 64, params_hash="q" * 64, source="member",
        members=["a"], outcome={"status": "failed", "error": "diverged"})
    assert other.id != first.id and other.outcome["status"] == "failed"


def test_find_keys_are_the_found_cmrts_summaries(repo: SqlRepository) -> None:
    for i, force in enumerate((10.0, 12.0, 15.0, 20.0, 12.0)):
        add(repo, duration=0.3, force=force, objective=2.0 + i)
    add(repo, family="bend", duration=0.3, force=12.0)
    for params, tol, character in (
        ({"force": 12.0}, None, None),
        ({"force": 13.0}, 3.0, None),
        ({"force": 13.0, "duration": 0.3}, {"force": 10.0, "duration": 0.0}, None),
        ({"force": 13.0}, 3.0, {"height": 1.75}),
        ({"force": 13.0}, 3.0, {"height": 1.8}),
    ):
        recs = repo.find_cmrts("push", params, tolerance=tol, character=character)
        keys = repo.find_cmrt_keys("push", params, tolerance=tol, character=character)
        assert [k.id for k in keys] == [r.id for r in recs]
        for k, r in zip(keys, recs, strict=True):
            assert (k.family, k.task_parameters, k.objective, k.objective_without, k.winner,
                    k.fell, k.job_id, k.character, k.created_at) == (
                r.family, r.task_parameters, r.objective, r.objective_without, r.winner,
                r.fell, r.job_id, r.character, r.created_at)
    assert [len(repo.find_cmrt_keys("push", {"force": 13.0}, tolerance=3.0, limit=n))
            for n in (1, 2, 10)] == [1, 2, 4]


def test_what_another_repository_adds_is_read_at_once(repo: SqlRepository) -> None:
    """The library keeps what it read, and still answers with what another process (another
    repository on the same database) has added since."""
    other = SqlRepository(repo.engine)
    a = add(repo, duration=0.3, force=10.0)
    assert [k.id for k in other.cmrt_keys("push")] == [a]
    assert [r.id for r in other.find_cmrts("push", {"force": 11.0}, tolerance=2.0)] == [a]
    b = add(repo, duration=0.3, force=11.0)
    assert [k.id for k in other.cmrt_keys("push")] == [b, a]
    assert [r.id for r in other.find_cmrts("push", {"force": 11.0}, tolerance=2.0)] == [b, a]
    assert [k.id for k in other.find_cmrt_keys("push", {"force": 11.0})] == [b]
    assert other.get_cmrt(b) == repo.get_cmrt(b)
