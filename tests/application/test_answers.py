"""application.answers: every answer says what it is; a verified answer is simulated once and
kept; no average across a strategy switch; the library's parameter names."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from application import answers
from application.library import library_entry
from optim.clips import run_clip
from sim.spec import parse_spec
from store import open_repository


def Q(duration: float) -> answers.LibraryQuery:  # noqa: N802 - a query, named short
    return answers.LibraryQuery("bend", {"duration": duration})


ROOT = Path(__file__).resolve().parents[2]
BASE = np.array([0.25, 0.5, 0.45, 0.55, 0.6, 0.5, 0.75, 0.5])


def _spec(duration: float):
    doc = yaml.safe_load((ROOT / "examples" / "fast_bend.yaml").read_text())
    doc["clip"]["duration"] = duration
    return parse_spec(doc)


@pytest.fixture
def repo(tmp_path):
    repo = open_repository(f"sqlite:///{tmp_path}/lib.db")
    # One strategy at 0.3-0.5 s (params 0.02 apart), another at 0.7 s (0.3 apart).
    for d, shift, obj in [(0.3, 0.0, 2.0), (0.4, 0.02, 2.1), (0.5, 0.04, 2.2),
                          (0.7, 0.3, 2.4)]:
        spec = _spec(d)
        params = np.clip(BASE + shift * np.array([1, -1] * 4), 0, 1)
        assert spec.cmrt_dimension == len(params)
        repo.add_cmrt(library_entry(spec, params, objective=obj, fell=False))
    yield repo
    repo.engine.dispose()


class Counting:
    """The real what-if clip, counted."""

    def __init__(self) -> None:
        self.calls = 0

    def __call__(self, doc, params):
        self.calls += 1
        return run_clip(doc, params, False, False)


def test_plain_answer_says_what_it_is(repo):
    a = answers.serve(repo, Q(0.45))
    assert a.source == "interpolated" and not a.exact
    assert len(a.members) == 2 and [n["duration"] for n in a.neighbours] == [0.4, 0.5]
    assert a.switch["detected"] is False and a.switch["distance"] < 0.15
    assert a.verified is False and a.verdict == "unverified" and a.outcome is None
    assert a.predicted_objective == pytest.approx(2.15)
    assert "not simulated" in a.message
    exact = answers.serve(repo, Q(0.4))
    assert exact.source == "member" and exact.exact and exact.switch is None


def test_no_average_across_a_switch(repo):
    a = answers.serve(repo, Q(0.58))
    assert a.switch["detected"] is True
    assert a.switch["distance"] > answers.SWITCH_DISTANCE
    near = next(n for n in a.neighbours if n["duration"] == 0.5)
    assert a.source == "member" and a.members == [near["id"]]
    rec = repo.get_cmrt(near["id"])
    assert a.knot_times == pytest.approx(rec.knots)
    assert "strategy switch" in a.message and "not their average" in a.message


def test_verified_once_then_kept(repo):
    sim = Counting()
    a = answers.serve(repo, Q(0.45), sim)
    first = sim.calls
    assert first >= 1 and a.verified is True
    o = a.outcome
    assert o["cached"] is False and o["status"] == "done"
    assert isinstance(o["objective"], float) and isinstance(o["fell"], bool)
    assert len(o["spec_hash"]) == 64
    assert a.verdict in ("good", "weak", "falls", "fails_task")
    if a.verdict != "good":  # never presented as good: says so, and tried the members
        assert len(a.tried) == 3
    b = answers.serve(repo, Q(0.45), sim)
    assert sim.calls == first  # nothing simulated again
    assert b.outcome["cached"] is True
    assert {k: v for k, v in b.outcome.items() if k != "cached"} == \
        {k: v for k, v in o.items() if k != "cached"}
    assert b.members == a.members and b.verdict == a.verdict


def test_the_spec_of_the_query_is_the_member_spec_at_the_value(repo):
    spec = _spec(0.4)
    doc = spec.with_parameter("duration", 0.45)
    assert parse_spec(doc).clip.duration == 0.45
    assert spec.library_key("clip.duration") == "duration"
    with pytest.raises(ValueError, match="task.mass"):
        spec.library_key("task.mass")


def test_library_parameter_translates_a_spec_path(repo):
    assert answers.library_parameter(repo, "bend", "duration") == ("duration", None)
    key, note = answers.library_parameter(repo, "bend", "clip.duration")
    assert key == "duration" and "clip.duration" in note
    with pytest.raises(answers.AnswerError, match="^task.mass: "):
        answers.library_parameter(repo, "bend", "task.mass")
    with pytest.raises(answers.AnswerError, match="^family: "):
        answers.library_parameter(repo, "nope", "duration")


@pytest.mark.parametrize("task_doc,key,value,path", [
    ("domino.yaml", "mass", 45.0, ("task", "mass")),
    ("lion_hit.yaml", "mass", 33.0, ("task", "tire", "mass")),
    ("push.yaml", "force", -120.0, ("task", "force")),
])
def test_every_task_parameter_can_be_set(task_doc, key, value, path):
    spec = parse_spec(yaml.safe_load((ROOT / "examples" / task_doc).read_text()))
    got = parse_spec(spec.with_parameter(key, value))
    assert got.task_parameters()[key] == value
    node = got.model_dump(mode="json")
    for p in path:
        node = node[p]
    assert node == abs(value)
    assert spec.library_key(".".join(path)) == key


def test_across_a_switch_the_average_is_served_only_simulated(repo):
    sim = Counting()
    a = answers.serve(repo, Q(0.58), sim)
    assert a.switch["detected"] and a.verified
    sources = [t["source"] for t in a.tried]
    assert sources[0] == "member"  # the nearer member first, never the blind average
    if a.verdict != "good" or len(sources) > 1:
        assert sources == ["member", "member", "interpolated"]
    assert a.source in sources and sim.calls == len(sources)


def test_a_job_never_starts_from_an_average_across_a_switch(repo):
    from application.library import library_start

    within = library_start(repo, _spec(0.45))
    assert within.origin.startswith("library: interpolated along duration between 0.4 and 0.5")
    assert len(within.cmrts) == 2
    across = library_start(repo, _spec(0.58))
    near = next(k.id for k in repo.cmrt_keys("bend") if k.task_parameters["duration"] == 0.5)
    assert across.cmrts == (near,) and "strategy switch" in across.origin
    from application.library import LibraryCmrt
    from optim.spline import encode

    member = LibraryCmrt.of(repo.get_cmrt(near)).spline()  # the member itself, for this clip
    assert across.x0 == pytest.approx(encode(_spec(0.58), member))


def test_a_query_names_one_point_or_is_refused(repo):
    from application.errors import InvalidRequest

    for params, along, msg in [({}, None, "a task parameter to interpolate at is required"),
                               ({"duration": 0.4, "mass": 3.0}, None, "along: required"),
                               ({"duration": 0.4}, "x", "along: 'x' is not among")]:
        with pytest.raises(InvalidRequest, match=f"^{msg}"):
            answers.LibraryQuery("bend", params, along)
    with pytest.raises(answers.AnswerError, match="^parameters: clip.duration: given twice"):
        answers.serve(repo, answers.LibraryQuery("bend", {"duration": 0.4, "clip.duration": 0.4},
                                                 "duration", where="parameters: "))
    with pytest.raises(answers.AnswerError, match="outside the sampled range"):
        answers.serve(repo, Q(0.9))
