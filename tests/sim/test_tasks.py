"""The task registry and the task types ported to it (quiet_stance, push, pose_change,
sequence): resolution by name, their cross-field rules, their events on a real ODE world."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sim.errors import SpecError
from sim.physics import Physics
from sim.spec import parse_spec
from sim.tasks import TASK_TYPES, Task
from sim.tasks.push import PushTask

CLIP = {"preparation": 1.0, "duration": 0.2, "decay": 0.3}


def _spec(task: dict, **more):
    return parse_spec({"name": "t", "clip": CLIP, "task": task, **more})


def test_every_type_resolves_to_its_module():
    for name, cls in TASK_TYPES.items():
        assert cls.__module__ == f"sim.tasks.{name}"
    spec = _spec({"type": "push", "force": 10.0})
    assert type(spec.task) is TASK_TYPES["push"]


def test_unknown_type_is_a_clear_error():
    types = ", ".join(TASK_TYPES)
    assert types.startswith("quiet_stance, push, pose_change, sequence")
    with pytest.raises(SpecError, match=rf"task: unknown task type 'boxing'; task types "
                                        rf"are {types}$"):
        _spec({"type": "boxing"})


def test_task_parameters_are_library_keys():
    assert _spec({"type": "quiet_stance"}).task_parameters() == {"duration": 0.2}
    back = _spec({"type": "push", "force": 250.0, "direction": "backward"})
    assert back.task_parameters() == {"duration": 0.2, "force": -250.0}


def test_push_force_is_applied_in_its_window_only():
    """On a real world: inside [start, start + duration) the force is in the torso body's
    ODE force accumulator, outside it is not; the default body is the file's torso."""
    spec = _spec({"type": "push", "force": 80.0, "direction": "backward", "start": 1.05,
                  "duration": 0.1})
    ch = spec.load_character()
    task = spec.task.build(spec, ch)
    assert isinstance(task, PushTask) and task.events
    assert task.body == ch.torso == ch.body_index("trunk")
    ph = Physics(ch)
    try:
        body = ph.bodies[task.body]
        for t, expect in ((1.0, 0.0), (1.05, -80.0), (1.149, -80.0), (1.151, 0.0)):
            body.setForce((0.0, 0.0, 0.0))
            task.before_step(ph, t)
            assert body.getForce()[0] == expect, t
    finally:
        ph.close()


def test_pose_change_and_sequence_motions_use_the_characters_joints():
    target = {"waist": -45.0, "shoulder_l": 30.0}
    spec = _spec({"type": "pose_change", "target": target})
    ch = spec.load_character()
    [(start, dur, offsets)] = spec.task.build(spec, ch).motions
    assert (start, dur) == (1.0, 0.2)
    assert offsets == {ch.hinge_index(k): math.radians(v) for k, v in target.items()}
    seq = _spec({"type": "sequence", "motions": [
        {"start": 0.1, "duration": 0.3, "target": {"waist": -10.0}},
        {"start": 0.5, "duration": 0.4, "target": {"waist": 0.0}}]})
    motions = seq.task.build(seq, ch).motions
    assert [(m[0], m[1]) for m in motions] == [(0.1, 0.3), (0.5, 0.4)]
    assert motions[0][2] == {ch.hinge_index("waist"): math.radians(-10.0)}


def test_cross_field_rules_are_checked_at_parse_time():
    with pytest.raises(SpecError, match=r"task.motions.1: start \+ duration exceeds"):
        _spec({"type": "sequence", "motions": [
            {"start": 0.1, "duration": 0.3, "target": {"waist": -10.0}},
            {"start": 1.4, "duration": 0.4, "target": {"waist": 0.0}}]})
    with pytest.raises(SpecError, match=r"task.motions.0.target: unknown joint 'tail'"):
        _spec({"type": "sequence", "motions": [
            {"start": 0.1, "duration": 0.3, "target": {"tail": -10.0}}]})
    with pytest.raises(SpecError, match=r"task.target: Field required"):
        _spec({"type": "pose_change"})


def test_base_task_has_no_goal_and_no_penalty():
    spec = _spec({"type": "quiet_stance"})
    task = spec.task.build(spec, spec.load_character())
    assert type(task) is Task and not task.events and task.props == ()
    assert task.success(None) is None and task.penalty(None, 1.0) == 0.0
    assert task.motions == []
    assert np.isfinite(spec.cmrt_dimension)
