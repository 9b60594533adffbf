"""Robust optimisation (`optim.robust`): a candidate scored at its K scene variants, each its
own evaluation through the executor, aggregated into its objective; the result records each
variant's outcome and the range."""

from __future__ import annotations

import math

import numpy as np
import pytest

from optim.executors import PoolExecutor, SerialExecutor
from optim.objective import SimObjective
from optim.outcome import FAILED_OBJECTIVE, EvalOutcome
from optim.robust import aggregate, cut_allowed, points, split_point
from optim.run import optimize
from sim.robust import variant_document, variant_values
from sim.spec import canonical_spec, parse_spec


def bend(**robust) -> dict:
    doc = {"name": "rbend", "family": "bend",
           "clip": {"preparation": 0.2, "duration": 0.2, "decay": 0.2},
           "task": {"type": "pose_change", "target": {"waist": -30}},
           "optimize": {"popsize": 4, "max_evaluations": 8, "min_evaluations": 0}}
    if robust:
        doc["optimize"]["robust"] = robust
    return doc


ROBUST = {"vary": {"task.target.waist": [-40, -20]}, "samples": 3}


def test_points_carry_the_variant_index_and_split_back() -> None:
    spec = parse_spec(bend(**ROBUST))
    c = [np.full(spec.cmrt_dimension, 0.3), np.full(spec.cmrt_dimension, 0.6)]
    pts = points(spec, c)
    assert len(pts) == 6 and [p[-1] for p in pts] == [0, 1, 2, 0, 1, 2]
    params, k = split_point(spec, pts[4])
    assert k == 1 and np.array_equal(params, c[1])
    assert split_point(spec, c[0])[1] is None  # plain params: the spec's own scene
    with pytest.raises(ValueError, match="variant index 3.0 is not one of the spec's 3"):
        split_point(spec, np.append(c[0], 3.0))
    plain = parse_spec(bend())
    assert points(plain, c) == c and cut_allowed(plain) and not cut_allowed(spec)


def test_mean_and_worst_aggregate_and_any_fall_or_error_counts() -> None:
    outs = [EvalOutcome(1.0), EvalOutcome(4.0, fell=True, fall_time=1.2,
                                          fall_direction="forward", task_success=False),
            EvalOutcome(2.5, task_success=True)]
    mean = aggregate(parse_spec(bend(**ROBUST)), outs)
    assert len(mean) == 1 and mean[0].objective == math.fsum([1.0, 4.0, 2.5]) / 3
    assert mean[0].fell and mean[0].fall_direction == "forward" and mean[0].fall_time == 1.2
    assert mean[0].task_success is False
    worst = aggregate(parse_spec(bend(**ROBUST, aggregate="worst")), outs)
    assert worst[0].objective == 4.0
    failed = aggregate(parse_spec(bend(**ROBUST)), [outs[0], EvalOutcome(
        FAILED_OBJECTIVE, error="SimError: boom"), outs[2]])
    assert failed[0].objective == FAILED_OBJECTIVE and failed[0].error == "SimError: boom"


def test_a_robust_run_scores_each_variant_as_its_own_scene() -> None:
    canonical = canonical_spec(parse_spec(bend(**ROBUST)))
    res = optimize(canonical, SerialExecutor(), seed=3)
    rb = res.robust
    assert rb["vary"] == {"task.target.waist": [-40.0, -20.0]}
    assert (rb["samples"], rb["aggregate"]) == (3, "mean")
    assert [v["values"] for v in rb["variants"]] == variant_values(canonical.spec.optimize.robust)
    assert [v["values"]["task.target.waist"] for v in rb["variants"]] == [-40.0, -30.0, -20.0]
    # each variant's objective is an ordinary simulation of that scene with the best CMRT
    for v, b in zip(rb["variants"], rb["baseline_variants"], strict=True):
        scene = parse_spec(variant_document(canonical.document, v["values"]))
        assert SimObjective(scene)(res.params_array).objective == v["objective"]
        assert SimObjective(scene)(np.full(scene.cmrt_dimension, 0.5)).objective == \
            b["objective"]
    assert res.objective == math.fsum(v["objective"] for v in rb["variants"]) / 3
    assert res.evaluations == 8  # candidates, each simulated at the 3 variants


def test_a_robust_run_is_the_same_on_a_pool_of_two() -> None:
    canonical = canonical_spec(parse_spec(bend(**ROBUST, aggregate="worst")))
    serial = optimize(canonical, SerialExecutor(), seed=5).to_dict()
    with PoolExecutor(2) as pool:
        pooled = optimize(canonical, pool, seed=5).to_dict()
    serial.pop("wall_seconds")
    pooled.pop("wall_seconds")
    assert repr(serial) == repr(pooled)
    assert serial["objective"] == max(v["objective"] for v in serial["robust"]["variants"])
