"""optimize(): the loop, stop rules from the spec, checkpoints and resume, result files."""

from __future__ import annotations

import json

import numpy as np
import pytest
from synthetic import RaiseAbove, Sphere

from optim.errors import CheckpointError, EvaluationError, ResultFileError
from optim.executors import PoolExecutor, SerialExecutor
from optim.result import OptimizationResult
from optim.run import CANCELLED, load_checkpoint, optimize
from optim.spline import decode, flat_params


class KilledError(Exception):
    """Stands in for the process being killed after a checkpoint was written."""


def killer(after: int):
    def progress(stats):
        if stats.iteration == after:
            raise KilledError

    return progress


def same_result(a: OptimizationResult, b: OptimizationResult) -> None:
    da, db = a.to_dict(), b.to_dict()
    da.pop("wall_seconds")
    db.pop("wall_seconds")
    assert da == db


@pytest.fixture
def small(make_spec):
    return make_spec(min_evaluations=60, window=5, max_evaluations=120, threshold=1e-6)


def test_optimize_sphere_result_fields(small, tmp_path):
    fn = Sphere(centre=0.3, fall_above=0.4)
    res = optimize(small, SerialExecutor(), seed=3, objective=fn)
    assert res.stop_rule in {"max_evaluations", "slow_convergence", "threshold"}
    assert res.dimension == 8 and len(res.params) == 8
    assert res.evaluations == res.iterations * 10 == len(res.history) * 10
    assert res.objective == pytest.approx(min(h["best"] for h in res.history))
    assert res.baseline_objective == pytest.approx(8 * 0.2**2) and res.baseline_fell is False
    assert res.objective < res.baseline_objective and res.improvement > 0
    spline = decode(small, res.params)
    np.testing.assert_allclose(res.knot_times, spline.knot_times)
    np.testing.assert_allclose(res.curve["dx"], spline.sample(res.curve["t"]))
    assert len(res.curve["t"]) == 100 and res.seed == 3 and res.basis_id is None
    path = tmp_path / "r" / "res.json"
    res.save(path)
    back = OptimizationResult.load(path)
    same_result(back, res)
    assert back.task_parameters() == {"duration": 0.4}
    assert back.family == "bend"


def test_threshold_from_spec_stops_early(make_spec):
    spec = make_spec(threshold=0.05, max_evaluations=5000)
    res = optimize(spec, SerialExecutor(), seed=1, objective=Sphere(centre=0.4))
    assert res.stop_rule == "threshold" and res.objective <= 0.05


@pytest.mark.parametrize("k", [1, 4])
def test_resume_after_kill_equals_uninterrupted(small, tmp_path, k):
    fn = Sphere(centre=0.35)
    ref = optimize(small, SerialExecutor(), seed=9, objective=fn, checkpoint=tmp_path / "a.ckpt")
    ckpt = tmp_path / "b.ckpt"
    with pytest.raises(KilledError):
        optimize(small, SerialExecutor(), seed=9, objective=fn, checkpoint=ckpt, progress=killer(k))
    assert len(load_checkpoint(ckpt)["history"]) == k
    resumed = optimize(small, SerialExecutor(), seed=9, objective=fn, checkpoint=ckpt, resume=True)
    same_result(resumed, ref)
    # resuming a finished run just rebuilds the same result
    again = optimize(small, SerialExecutor(), seed=9, objective=fn, checkpoint=ckpt, resume=True)
    same_result(again, ref)


def test_resume_rejects_other_seed_or_spec(small, make_spec, tmp_path):
    ckpt = tmp_path / "c.ckpt"
    with pytest.raises(KilledError):
        optimize(
            small, SerialExecutor(), seed=1, objective=Sphere(), checkpoint=ckpt, progress=killer(1)
        )
    with pytest.raises(CheckpointError, match="different seed"):
        optimize(small, SerialExecutor(), seed=2, objective=Sphere(), checkpoint=ckpt, resume=True)
    other = make_spec(name="other", min_evaluations=60, window=5, max_evaluations=120)
    with pytest.raises(CheckpointError, match="different spec"):
        optimize(other, SerialExecutor(), seed=1, objective=Sphere(), checkpoint=ckpt, resume=True)
    (tmp_path / "junk.ckpt").write_bytes(b"\x00garbage")
    with pytest.raises(CheckpointError):
        optimize(
            small,
            SerialExecutor(),
            seed=1,
            objective=Sphere(),
            checkpoint=tmp_path / "junk.ckpt",
            resume=True,
        )


def test_resume_without_checkpoint_starts_fresh(small, tmp_path):
    a = optimize(
        small,
        SerialExecutor(),
        seed=4,
        objective=Sphere(),
        checkpoint=tmp_path / "none.ckpt",
        resume=True,
    )
    b = optimize(small, SerialExecutor(), seed=4, objective=Sphere())
    same_result(a, b)


def test_progress_can_cancel(small):
    seen = []

    def progress(stats):
        seen.append(stats.iteration)
        return stats.iteration == 2

    res = optimize(small, SerialExecutor(), seed=1, objective=Sphere(), progress=progress)
    assert res.stop_rule == CANCELLED and res.iterations == 2 and seen == [1, 2]


def test_generation_of_errors_raises(small):
    with pytest.raises(EvaluationError, match="every candidate"):
        optimize(small, SerialExecutor(), seed=1, objective=RaiseAbove(limit=-1.0))


def test_warm_start_x0(small):
    x0 = np.full(8, 0.3)
    res = optimize(small, SerialExecutor(), seed=1, x0=x0, objective=Sphere(centre=0.3))
    cold = optimize(small, SerialExecutor(), seed=1, objective=Sphere(centre=0.3))
    assert res.history[0]["best"] < 0.5 * cold.history[0]["best"]  # starts near the warm start


def test_serial_and_pool_optimize_identically(small):
    fn = Sphere(centre=0.6)
    a = optimize(small, SerialExecutor(), seed=21, objective=fn)
    with PoolExecutor(2, timeout=60.0) as pool:
        b = optimize(small, pool, seed=21, objective=fn)
    same_result(a, b)


def test_result_file_errors_name_the_field(small, tmp_path):
    res = optimize(small, SerialExecutor(), seed=1, objective=Sphere())
    good = res.to_dict()
    cases = {
        "params": ("params", "oops"),
        "objective": ("objective", "x"),
        "fell": ("fell", 1),
        "dimension": ("dimension", 9),
        "history[0]": ("history", [{"iteration": 1}]),
        "knot_times": ("knot_times", [2.0, 1.0, 0.5, 0.2]),
        "'fall_direction'": ("fall_direction", "sideways"),
        "'task_success'": ("task_success", 1),
        "baseline_fall_direction": ("baseline_fall_direction", 0),
    }
    for needle, (field, value) in cases.items():
        bad = dict(good, **{field: value})
        with pytest.raises(ResultFileError, match=needle.replace("[", r"\[")):
            OptimizationResult.from_dict(bad, "bad.json")
    missing = dict(good)
    del missing["seed"]
    with pytest.raises(ResultFileError, match="missing field 'seed'"):
        OptimizationResult.from_dict(missing, "bad.json")
    p = tmp_path / "corrupt.json"
    p.write_text(json.dumps(good)[:-20])
    with pytest.raises(ResultFileError, match="not valid JSON"):
        OptimizationResult.load(p)
    with pytest.raises(ResultFileError, match="cannot read"):
        OptimizationResult.load(tmp_path / "absent.json")


def test_result_fall_and_task_verdicts_round_trip_and_old_files_read_as_null(small, tmp_path):
    res = optimize(small, SerialExecutor(), seed=1, objective=Sphere())
    assert res.fall_direction is None and res.task_success is None  # a synthetic objective
    d = dict(res.to_dict(), fall_direction="forward", task_success=True,
             baseline_fall_direction="backward", baseline_task_success=False)
    back = OptimizationResult.from_dict(d, "r.json")
    assert (back.fall_direction, back.task_success) == ("forward", True)
    assert (back.baseline_fall_direction, back.baseline_task_success) == ("backward", False)
    assert back.to_dict() == d
    old = {k: v for k, v in d.items() if "direction" not in k and "success" not in k}
    legacy = OptimizationResult.from_dict(old, "old.json")
    assert legacy.fall_direction is None and legacy.baseline_task_success is None


def test_flat_params_baseline_is_flat_spline(small):
    assert np.all(flat_params(small) == 0.5)
