"""The `motion` task: a dense joint-angle trajectory as the controller's reference.

The spline through the frames (sim.trajectory.FrameTrack) passes through every frame, is C2
inside and C1 with the holds before and after; the reference the controllers read is the
standing pose plus the frames; `speed` and `scale` are library parameters; a bad block is
refused naming the field and the rule.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from sim.character import ROOT_DOF
from sim.errors import SpecError
from sim.rollout import Rollout
from sim.spec import numeric_fields, parse_spec
from sim.trajectory import FrameTrack, PoseTrajectory

JOINTS = ["waist", "shoulder_r", "shoulder_l", "elbow_r"]
#: A bend with the arms reaching forward and back up, one frame every 0.1 s (degrees from the
#: standing pose).
FRAMES = [[0, 0, 0, 0], [-5, 8, 8, 2], [-20, 25, 25, 10], [-45, 50, 45, 20], [-60, 70, 60, 25],
          [-62, 72, 62, 25], [-50, 60, 55, 20], [-30, 35, 30, 12], [-10, 12, 10, 5],
          [0, 0, 0, 0]]


def motion_doc(**task) -> dict:
    block = {"type": "motion", "rate": 10, "joints": JOINTS, "frames": FRAMES, **task}
    return {"name": "reach", "clip": {"preparation": 1.0, "duration": 0.9, "decay": 1.0},
            "task": block}


def _rng_track(n=9, k=3, h=0.05, seed=3):
    rng = np.random.default_rng(seed)
    return FrameTrack(0.5, h, list(range(k)), rng.normal(size=(n, k))), rng


def test_the_spline_passes_through_every_frame_and_holds_the_ends():
    track, _ = _rng_track()
    y = np.random.default_rng(3).normal(size=(9, 3))
    for i in range(9):
        q, qd, _ = track(0.5 + i * 0.05)
        assert np.allclose(q, y[i], atol=1e-12)
    q, qd, qdd = track(0.2)  # before the start: the first frame, held
    assert np.array_equal(q, y[0]) and not qd.any() and not qdd.any()
    q, qd, qdd = track(0.5 + 8 * 0.05 + 1.0)  # after the end: the last frame, held
    assert np.array_equal(q, y[-1]) and not qd.any() and not qdd.any()


def test_the_spline_is_c2_inside_and_c1_with_the_holds():
    track, _ = _rng_track()
    eps = 1e-9
    for i in range(1, 8):  # every inner knot: q, qd, qdd the same from both sides
        t = 0.5 + i * 0.05
        left, right = track(t - eps), track(t + eps)
        for a, b, tol in zip(left, right, (1e-7, 1e-5, 1e-2), strict=True):
            assert np.allclose(a, b, atol=tol), (i, a, b)
    for t in (0.5, 0.9):  # both ends: zero velocity, so the holds join it C1
        for u in (t - eps, t + eps):  # the velocity eps from a knot: at most eps x |qdd|
            _, qd, qdd = track(min(max(u, 0.5 + eps), 0.9 - eps))
            assert np.all(np.abs(qd) <= 2 * eps * np.abs(qdd) + 1e-12), (t, qd, qdd)
    # The rates and accelerations are the offsets' derivatives (central differences, within
    # the pieces: across a knot the jerk steps).
    h = 1e-6
    for t in 0.5 + (np.arange(8) + 0.37) * 0.05:
        q0, qd0, qdd0 = track(t)
        assert np.allclose((track(t + h)[0] - track(t - h)[0]) / (2 * h), qd0, atol=1e-5)
        assert np.allclose((track(t + h)[1] - track(t - h)[1]) / (2 * h), qdd0, atol=1e-3)


def test_a_track_is_added_to_the_pose_trajectory():
    standing = np.array([0.1, -0.2, 0.3])
    track = FrameTrack(1.0, 0.5, [0, 2], np.array([[0.0, 0.0], [0.4, -0.2], [0.2, 0.1]]))
    traj = PoseTrajectory(standing, [], [track])
    q, qd, _ = traj(2.0)
    assert np.allclose(q, [0.3, -0.2, 0.4]) and not qd.any()
    q, _, _ = traj(1.5)
    assert np.allclose(q, [0.5, -0.2, 0.1])
    assert np.array_equal(PoseTrajectory(standing, [])(1.5)[0], standing)  # no track, no change


def test_the_reference_is_the_standing_pose_plus_the_frames():
    spec = parse_spec(motion_doc(start=1.2))
    sim = Rollout(spec)
    try:
        ch = sim.character
        idx = [ch.hinge_index(n) for n in JOINTS]
        q0 = sim.q0[ROOT_DOF:]
        # The clip starts in the first frame (here the standing pose) ...
        assert np.allclose(q0[idx], ch.standing_offsets[idx])
        # ... and every frame is the reference at its time, relative to that start.
        for i, row in enumerate(FRAMES):
            q, _, _ = sim.trajectory(1.2 + i / 10)
            assert np.allclose(q[idx], q0[idx] + np.radians(row), atol=1e-12), i
        before, _, _ = sim.trajectory(1.1)
        assert np.array_equal(before, q0)
        ev = sim.run(None)
        again = sim.run(None)
    finally:
        sim.close()
    assert not ev.fell and repr(ev.objective) == repr(again.objective)


def test_the_first_frame_is_the_initial_pose():
    frames = [[r[0] - 10, r[1] + 20, r[2], r[3]] for r in FRAMES]
    spec = parse_spec(motion_doc(frames=frames))
    sim = Rollout(spec)
    try:
        ch = sim.character
        waist, arm = ch.hinge_index("waist"), ch.hinge_index("shoulder_r")
        q0 = sim.q0[ROOT_DOF:]
        assert math.isclose(q0[waist], ch.standing_offsets[waist] + math.radians(-10))
        assert math.isclose(q0[arm], ch.standing_offsets[arm] + math.radians(20))
        q, _, _ = sim.trajectory(1.0 + 0.4)
        assert math.isclose(q[waist], q0[waist] + math.radians(frames[4][0] + 10))
    finally:
        sim.close()


def test_a_still_motion_is_the_quiet_stance_bit_for_bit():
    still = motion_doc(frames=[[0.0] * 4] * 10)
    quiet = {"name": "reach", "clip": still["clip"], "task": {"type": "quiet_stance"}}
    out = []
    for doc in (still, quiet):
        sim = Rollout(parse_spec(doc))
        try:
            out.append(sim.run(None).to_dict())
        finally:
            sim.close()
    for key in ("objective", "error_norm", "max_abs_error", "fell"):
        assert repr(out[0][key]) == repr(out[1][key]), key


def test_speed_and_scale_are_library_parameters():
    spec = parse_spec(motion_doc())
    assert spec.task_parameters() == {"duration": 0.9, "speed": 1.0, "scale": 1.0}
    assert spec.library_key("task.speed") == "speed"
    fast = parse_spec(spec.with_parameter("speed", 2.0))
    half = parse_spec(spec.with_parameter("scale", 0.5))
    assert fast.task.speed == 2.0 and fast.task.motion_seconds == pytest.approx(0.45)
    for s in (fast, half):
        sim = Rollout(s)
        try:
            idx = [sim.character.hinge_index(n) for n in JOINTS]
            q0 = sim.q0[ROOT_DOF:][idx]
            for i, row in enumerate(FRAMES):
                t = 1.0 + i * s.task.interval
                q = sim.trajectory(t)[0][idx]
                assert np.allclose(q - q0, s.task.scale * np.radians(row), atol=1e-12)
        finally:
            sim.close()


def _expect(doc: dict, where: str, words: str) -> None:
    with pytest.raises(SpecError) as err:
        parse_spec(doc)
    msg = str(err.value)
    assert f": {where}: " in msg and words in msg, msg


def test_a_bad_motion_names_the_field_and_the_rule():
    _expect(motion_doc(joints=["waist", "wrist", "elbow_r", "neck"]), "task.joints.1",
            "unknown joint 'wrist'")
    _expect(motion_doc(joints=["waist", "waist", "elbow_r", "neck"]), "task.joints.1",
            "named twice")
    _expect(motion_doc(frames=[*FRAMES[:3], [1.0, 2.0]]), "task.frames.3", "has 2 angles")
    _expect(motion_doc(frames=[[0, 0, 0, 0], [0, 0, 0, float("nan")]]), "task.frames.1.3",
            "finite")
    _expect(motion_doc(frames=[[0, 0, 0, 0], [0, 0, 0, 200]]), "task.frames.1.3",
            "from -180 to 180 degrees")
    _expect(motion_doc(frames=[[0, 0, 0, 0], [-130, 0, 0, 0]]), "task.frames.1.0",
            "outside its limits [-120, 30]")
    _expect(motion_doc(frames=[[0, 0, 0, 0], [-100, 0, 0, 0]], scale=1.5), "task.frames.1.0",
            "outside its limits")
    _expect(motion_doc(frames=[[0, 0, 0, 0]]), "task.frames", "at least 2")
    _expect(motion_doc(frames=[[0, 0, 0, 0]] * 4801), "task.frames", "at most 4800")
    _expect(motion_doc(speed=0.2), "task.frames", "end after the clip")
    _expect(motion_doc(start=2.5), "task.frames", "end after the clip")
    _expect(motion_doc(rate=1000), "task.rate", "from 1 to 240 frames per s")
    _expect(motion_doc(speed=0.0), "task.speed", "from 0.1 to 10")
    _expect(motion_doc(file="bend.yaml"), "task", "`file` is read by the command line")


def test_the_frames_count_once_among_the_numbers_of_a_spec():
    names = [f.name for f in numeric_fields(parse_spec(motion_doc()))]
    assert [n for n in names if n.startswith("task.frames")] == [
        f"task.frames.0.{k}" for k in range(len(JOINTS))]
    assert {"task.rate", "task.start", "task.speed", "task.scale"} <= set(names)
