"""The store's contract for named character definitions, on every backend."""

from __future__ import annotations

import threading

import pytest

from cmrt.canonical import document_hash
from store import Conflict, NotFound

DEFINITION = {"reference": {"height": 1.8, "mass": 75.0}, "root": "pelvis",
              "segments": [{"name": "pelvis", "mass": 10.5, "com": [0.0, 1.0]}]}


def test_add_get_and_list_by_name(repo):
    rec = repo.add_character("mine", DEFINITION)
    assert rec.name == "mine" and rec.definition == DEFINITION
    assert rec.definition_hash == document_hash(DEFINITION)
    got = repo.get_character("mine")
    assert got == rec and got.created_at.tzinfo is not None
    repo.add_character("alpha", {**DEFINITION, "root": "hips"})
    items, total = repo.list_characters()
    assert total == 2 and [r.name for r in items] == ["alpha", "mine"]
    items, total = repo.list_characters(limit=1, offset=1)
    assert total == 2 and [r.name for r in items] == ["mine"]


def test_a_taken_name_is_a_conflict_and_changes_nothing(repo):
    repo.add_character("mine", DEFINITION)
    with pytest.raises(Conflict, match="character 'mine' exists"):
        repo.add_character("mine", {**DEFINITION, "root": "other"})
    assert repo.get_character("mine").definition == DEFINITION
    assert repo.list_characters()[1] == 1


def test_an_unknown_name_is_not_found(repo):
    with pytest.raises(NotFound, match="character 'nobody' not found"):
        repo.get_character("nobody")


def test_what_cannot_be_stored_is_refused(repo):
    with pytest.raises(ValueError, match="name: 1 to 64"):
        repo.add_character("x" * 65, DEFINITION)
    with pytest.raises(ValueError, match="definition: non-finite"):
        repo.add_character("nan", {**DEFINITION, "torque_limit": float("nan")})
    assert repo.list_characters()[1] == 0


def test_two_adds_of_one_name_at_once_store_one(repo):
    outcomes: list[str] = []
    barrier = threading.Barrier(4)

    def add(k: int) -> None:
        barrier.wait()
        try:
            repo.add_character("race", {**DEFINITION, "root": f"r{k}"})
            outcomes.append("added")
        except Conflict:
            outcomes.append("conflict")

    threads = [threading.Thread(target=add, args=(k,)) for k in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert sorted(outcomes) == ["added", "conflict", "conflict", "conflict"]
    assert repo.list_characters()[1] == 1
