"""A job request checked once into its command (`SubmitJob`), submitted, followed to its best
curve and cancelled, without the web: the refusals are application errors whose class says
the HTTP status and exit code."""

from __future__ import annotations

from dataclasses import replace

import pytest

from application import jobs
from application.bases import build_library_basis
from application.errors import InvalidRequest, Missing, RequestConflict
from cmrt.defaults import DEFAULT_SEED
from cmrt.settings import Settings

SPEC = {"name": "b", "family": "bend",
        "clip": {"preparation": 0.3, "duration": 0.3, "decay": 0.2},
        "task": {"type": "pose_change", "target": {"waist": -30}},
        "optimize": {"popsize": 4, "max_evaluations": 12, "min_evaluations": 0}}


def test_a_request_is_checked_whole_into_its_command():
    cmd = jobs.SubmitJob.parse({"spec": SPEC})
    assert (cmd.seed, cmd.basis, cmd.start) == (DEFAULT_SEED, None, "library")
    assert cmd.spec.spec.name == "b" and cmd.spec.document["family"] == "bend"
    cmd = jobs.SubmitJob.parse({"spec": SPEC, "seed": jobs.MAX_SEED, "start": "cold"})
    assert (cmd.seed, cmd.start) == (2**31 - 1, "cold")


@pytest.mark.parametrize(("data", "message"), [
    (SPEC, jobs.SPEC_REQUIRED),
    ([SPEC], 'body: a job request must be a mapping {"spec": ...}, got list'),
    ({"spec": SPEC, "colour": 1}, "colour: unknown field (allowed: spec, seed, basis, start)"),
    ({"spec": SPEC, "seed": 2**31}, "seed: must be an integer in [0, 2^31)"),
    ({"spec": SPEC, "seed": 1.0}, "seed: must be an integer in [0, 2^31)"),
    ({"spec": SPEC, "basis": "x" * 65}, "basis: must be a basis id (string)"),
    ({"spec": SPEC, "start": "warm"}, "start: must be one of library, cold"),
    ({"spec": {**SPEC, "task": {"type": "juggle"}}}, "spec: task: unknown task type 'juggle'"),
])
def test_a_broken_request_is_refused_naming_the_field(data, message):
    with pytest.raises(InvalidRequest) as err:
        jobs.SubmitJob.parse(data)
    assert err.value.message.startswith(message) and err.value.http_status == 422


def test_submitted_followed_and_cancelled_once(repo, tmp_path):
    settings = Settings(data_dir=tmp_path, database_url=f"sqlite:///{tmp_path}/jobs.db")
    accepted = jobs.submit_request(repo, settings, {"spec": SPEC, "seed": 5})
    job = accepted.job
    assert (job.seed, job.status, accepted.budget.evaluations) == (5, "queued", 12 + 3 + 2)
    assert jobs.best_curve(job) is None  # no generation recorded yet
    best = jobs.best_curve(replace(job, best_params=[0.1] * 8))
    assert best is not None and len(best.knot_times) == len(best.values)
    assert best.vertical_values is None and len(best.curve["t"]) == len(best.curve["dx"])
    assert jobs.cancel_job(repo, job.id).cancel_requested
    repo.set_job_status(job.id, "cancelled")
    with pytest.raises(RequestConflict) as err:
        jobs.cancel_job(repo, job.id)
    assert err.value.message == f"job {job.id} already finished (cancelled)"
    assert err.value.http_status == 409


def test_a_basis_of_a_family_without_library_cmrts_is_missing(repo):
    with pytest.raises(Missing) as err:
        build_library_basis(repo, "nope")
    assert err.value.message == "family: no library CMRTs of family 'nope'"
    assert err.value.http_status == 404
