"""A family request checked once into its command (`SubmitFamily`), admitted and stored, and
its state as the API shows it (`family_detail`), without the web."""

from __future__ import annotations

from typing import Any

import pytest

from application import families
from application.errors import InvalidRequest
from cmrt.settings import Settings

BASE: dict[str, Any] = {
    "name": "fam", "family": "famtest", "task": {"type": "quiet_stance"},
    "clip": {"preparation": 0.5, "duration": 0.4, "decay": 1.0},
    "optimize": {"min_evaluations": 0, "window": 2, "popsize": 4, "max_evaluations": 8},
}
REQUEST: dict[str, Any] = {"spec": BASE, "param": "clip.decay",
                           "values": [1.0, 1.2, 1.4, 1.6, 1.8], "strategy": "continuation",
                           "from": "both", "leave_out": [1.4], "k": 2, "seed": 2}


def test_a_request_is_checked_whole_into_its_command():
    cmd = families.SubmitFamily.parse(REQUEST)
    assert (cmd.spec.family, cmd.spec.param, cmd.spec.k) == ("famtest", "clip.decay", 2)


@pytest.mark.parametrize(("data", "message"), [
    ([REQUEST], "family: a family must be a mapping, got list"),
    ({**REQUEST, "k": 9}, "family: k: 9 components need at least 11 values"),
    ({**REQUEST, "leave_out": [1.5]}, "family: leave_out[0]: 1.5 is not one of the values"),
    ({**REQUEST, "colour": 1}, "family: colour: Extra inputs are not permitted"),
])
def test_a_broken_request_is_refused_naming_the_field(data, message):
    with pytest.raises(InvalidRequest) as err:
        families.SubmitFamily.parse(data)
    assert err.value.message.startswith(message) and err.value.http_status == 422


def test_submitted_and_shown_before_any_run_started(repo, tmp_path):
    settings = Settings(data_dir=tmp_path, database_url=f"sqlite:///{tmp_path}/families.db")
    accepted = families.submit_family_request(repo, settings, REQUEST)
    fam = accepted.family
    assert (fam.family, fam.status, accepted.runs) == ("famtest", "running", 13)
    assert accepted.budget.sim_seconds > 0
    detail = families.family_detail(repo, fam, job_url=lambda job_id: f"/jobs/{job_id}",
                                    curves=True)
    assert detail.spec == fam.spec and detail.members is None and detail.checks is None
    assert detail.progress == families.FamilyProgress(runs=13, done=0, running=0, queued=0,
                                                      not_started=12)
    assert {r.status for r in detail.runs} == {"not started"} and len(detail.runs) == 12
    assert all("curve" not in r.model_fields_set for r in detail.runs)  # no job: no curve
