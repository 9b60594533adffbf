"""A job's budget (simulated seconds) and the server's ceiling on it."""

from __future__ import annotations

import pytest

from application.admission import Budget, BudgetExceeded, budget, check, default_popsize
from cmrt.settings import Settings
from sim.spec import parse_spec


def _spec(popsize=None, max_evaluations=400, duration=0.4):
    opt = {"max_evaluations": max_evaluations}
    if popsize is not None:
        opt["popsize"] = popsize
    return parse_spec({"name": "b", "family": "bend",
                       "clip": {"preparation": 1.0, "duration": duration, "decay": 1.2},
                       "task": {"type": "pose_change", "target": {"waist": -90}}, "optimize": opt})


def test_budget_counts_the_overshoot_and_the_final_pair():
    b = budget(_spec(popsize=8, max_evaluations=400))
    assert isinstance(b, Budget) and b.evaluations == 400 + 7 + 2
    assert (b.clip_seconds, b.sim_seconds) == pytest.approx((2.6, 409 * 2.6), rel=1e-12)
    assert default_popsize(8) == 10  # pycma: 4 + floor(3 ln 8)
    assert budget(_spec(max_evaluations=100)).evaluations == 100 + 9 + 2
    assert budget(_spec(max_evaluations=100), dimension=3).evaluations == 100 + 6 + 2


def test_the_issue_s_huge_job_is_refused_naming_the_field_and_the_ceiling(tmp_path):
    settings = Settings(data_dir=tmp_path)
    huge = parse_spec({"name": "huge", "family": "bend",
                       "clip": {"preparation": 1.0, "duration": 10.0, "decay": 9.0},
                       "task": {"type": "pose_change", "target": {"waist": -90}},
                       "optimize": {"popsize": 60, "max_evaluations": 100_000}})
    with pytest.raises(BudgetExceeded, match=r"optimize\.max_evaluations: .*2,001,220 s.*"
                       r"ceiling of 50,000 simulated seconds.*CMRT_MAX_JOB_SIM_SECONDS.*"
                       r"at most 2439"):
        check(huge, settings)
    ok = check(_spec(popsize=8), settings)
    assert ok.ceiling_sim_seconds == 50_000 and ok.sim_seconds < 50_000
    tight = settings.model_copy(update={"max_job_sim_seconds": 1000.0})
    with pytest.raises(BudgetExceeded):
        check(_spec(popsize=8), tight)
    check(_spec(popsize=8, max_evaluations=375), tight)  # (375 + 7 + 2) x 2.6 = 998.4 s


def test_a_robust_job_counts_k_clips_per_candidate_each_as_long_as_the_longest(tmp_path):
    doc = _spec(popsize=8, max_evaluations=400).model_dump(mode="json")
    doc["optimize"]["robust"] = {"vary": {"clip.duration": [0.3, 0.5]}, "samples": 3}
    robust = parse_spec(doc)
    b = budget(robust)
    assert b.evaluations == (400 + 7 + 2) * 3  # candidates x variants
    assert b.clip_seconds == pytest.approx(1.0 + 0.5 + 1.2, rel=1e-12)  # the longest variant
    doc["optimize"]["max_evaluations"] = 10_000
    settings = Settings(data_dir=tmp_path)
    with pytest.raises(BudgetExceeded, match=r"3 variants per candidate.*at most (\d+)") as err:
        check(parse_spec(doc), settings)
    most = int(err.value.args[0].rsplit("at most ", 1)[1].split()[0])
    doc["optimize"]["max_evaluations"] = most
    assert check(parse_spec(doc), settings).sim_seconds <= settings.max_job_sim_seconds
    doc["optimize"]["max_evaluations"] = most + 8
    with pytest.raises(BudgetExceeded):
        check(parse_spec(doc), settings)
