"""The motion out (sim.export): the fast bend's clip as BVH and CSV, read back by an
independent BVH library (`bvh` from PyPI, tests/bvh_helpers.py), against the simulation's own
record: the skeleton is the character's, the angles the 1 kHz states', the positions ODE's."""

from __future__ import annotations

import csv
import dataclasses
import io
import math
from pathlib import Path

import numpy as np
import pytest
from bvh_helpers import read, world, world_points

from optim.spline import CmrtSpline
from sim import load_spec
from sim.export import (
    MAX_FPS,
    ExportError,
    bvh_names,
    bvh_text,
    csv_text,
    end_site,
    export_text,
    sample_motion,
)
from sim.physics import DT
from sim.rollout import evaluate

ROOT = Path(__file__).resolve().parents[2]
#: Times (s) of the compared frames: each is a replay frame (100 Hz) and a 60 fps frame.
CHECK_TIMES = (1.0, 1.5, 2.0)


@pytest.fixture(scope="module")
def bend():
    spec = load_spec(ROOT / "examples" / "fast_bend.yaml")
    cmrt = CmrtSpline(spec.clip.length, [0.2, 0.4, 0.55, 0.7], [-0.004, 0.008, 0.006, -0.002])
    ev = evaluate(spec, cmrt, traces=True)
    return spec.load_character(), ev


def _frame_count(steps: int, fps: float) -> int:
    """Frames i / fps from 0 up to the last recorded state, (steps - 1) ms."""
    return int(math.floor((steps - 1) * DT * fps + 1e-9)) + 1


def test_the_hierarchy_is_the_characters_skeleton(bend):
    ch, ev = bend
    mocap = read(export_text(ch, ev, "bvh"))
    names = mocap.get_joints_names()
    assert sorted(names) == sorted(ch.body_names) and names[0] == ch.body_names[0]
    for b, name in enumerate(ch.body_names):
        if b == 0:
            assert mocap.joint_channels(name) == ["Xposition", "Yposition", "Zposition",
                                                  "Zrotation", "Xrotation", "Yrotation"]
            assert mocap.joint_offset(name) == (0.0, 0.0, 0.0)
            continue
        parent = ch.body_names[ch.parent[b]]
        assert mocap.joint_parent(name).name == parent
        assert mocap.joint_channels(name) == ["Zrotation", "Xrotation", "Yrotation"]
        np.testing.assert_allclose(mocap.joint_offset(name)[:2],
                                   ch.anchor0[b] - ch.anchor0[ch.parent[b]], atol=1e-12)
    # End Sites on the leaves: the head's top, the forearms' far outline point, the toes.
    leaves = {ch.body_names[b] for b in range(ch.n_bodies) if b not in ch.parent}
    ends = {n for n in world_points(mocap, 0) if n.endswith("/end")}
    assert ends == {f"{n}/end" for n in leaves}
    head, forearm, foot = (ch.body_index(n) for n in ("head", "forearm_r", "foot_r"))
    assert end_site(ch, head).tolist() == [0.0, ch.height]  # the top of the head
    assert end_site(ch, forearm)[1] < ch.geom("hand_r").a[1]  # beyond the hand's centre
    assert end_site(ch, foot).tolist() == ch.toe0[list(ch.feet).index(foot)].tolist()


@pytest.mark.parametrize("fps", [60.0, 50.0, 24.0])
def test_frames_count_and_rate_and_the_angles_are_the_states(bend, fps):
    ch, ev = bend
    mocap = read(export_text(ch, ev, "bvh", fps))
    assert mocap.nframes == _frame_count(ev.steps, fps)
    assert mocap.frame_time == pytest.approx(1.0 / fps, rel=1e-9)
    q = ev.states.q
    root = ch.body_names[0]
    for i in range(mocap.nframes):
        s = i * 1000.0 / fps  # the frame's time in steps
        k = int(round(s))
        exact = abs(s - k) < 1e-9
        x, y, z, rz, rx, ry = (float(v) for v in mocap.frame_joint_channels(
            i, root, mocap.joint_channels(root)))
        assert (z, rx, ry) == (0.0, 0.0, 0.0)
        if exact:  # a frame on a step: the state itself, to the written digits
            assert (x, y) == pytest.approx((q[k, 0], q[k, 1]), abs=1e-9)
            assert math.radians(rz) == pytest.approx(q[k, 2], abs=1e-10)
        for b in range(1, ch.n_bodies):
            name = ch.body_names[b]
            rz, rx, ry = (float(v) for v in mocap.frame_joint_channels(
                i, name, ["Zrotation", "Xrotation", "Yrotation"]))
            assert (rx, ry) == (0.0, 0.0)
            lo, hi = sorted((q[int(s), 2 + b], q[min(int(s) + 1, len(q) - 1), 2 + b]))
            if exact:  # round trip of an angle: within 1e-6 rad (here far within)
                assert math.radians(rz) == pytest.approx(q[k, 2 + b], abs=1e-10)
            else:  # between the two steps around the frame
                assert lo - 1e-10 <= math.radians(rz) <= hi + 1e-10


def test_positions_read_by_an_independent_library_are_odes(bend):
    """The hand's tip, the head's top and the toe, by forward kinematics of the parsed file,
    at three frames against ODE's own body poses of the replay record at those times."""
    ch, ev = bend
    mocap = read(export_text(ch, ev, "bvh"))
    fr = ev.frames
    worst = 0.0
    for t in CHECK_TIMES:
        i, j = int(round(t * 60)), int(round(t * fr.rate))
        assert fr.t[j] == pytest.approx(t, abs=1e-12)
        pts = world_points(mocap, i)
        for seg in ("forearm_r", "head", "foot_l", "trunk"):
            b = ch.body_index(seg)
            sim = world(fr.poses[j][b], ch.com0[b], end_site(ch, b) if b not in ch.parent
                        else ch.anchor0[b])
            got = pts[f"{seg}/end"] if b not in ch.parent else pts[seg]
            worst = max(worst, float(np.max(np.abs(got - sim))))
    # ODE's hinges hold their anchors to its constraint error (CFM 1e-6): well under 1 mm.
    assert worst < 1e-4


def test_the_csv_holds_the_states_cm_and_cp(bend):
    ch, ev = bend
    rows = list(csv.reader(io.StringIO(export_text(ch, ev, "csv", 50.0))))
    head, body = rows[0], rows[1:]
    assert head == ["t", "root_x", "root_y", "root_angle", *ch.hinge_names,
                    "cm_x", "cm_y", "cop_x"]
    assert len(body) == _frame_count(ev.steps, 50.0)
    for i in (0, 1, 50, len(body) - 1):
        k = 20 * i  # 50 fps: every 20th step
        r = body[i]
        assert float(r[0]) == pytest.approx(i / 50.0, abs=1e-12)
        np.testing.assert_allclose([float(v) for v in r[1:3]], ev.states.q[k, :2], atol=1e-9)
        np.testing.assert_allclose(np.radians([float(v) for v in r[3:3 + ch.ndof - 2]]),
                                   ev.states.q[k, 2:], atol=1e-10)
        np.testing.assert_allclose([float(r[-3]), float(r[-2])], ev.traces.cm[k], atol=1e-9)
        if k == 0:
            assert r[-1] == ""  # no step has ended at t = 0: no CP yet
        else:
            assert float(r[-1]) == pytest.approx(ev.traces.cp[k - 1], abs=1e-9)


def test_the_export_is_deterministic_and_the_simulation_unchanged(bend):
    ch, ev = bend
    spec = load_spec(ROOT / "examples" / "fast_bend.yaml")
    again = evaluate(spec, CmrtSpline(spec.clip.length, [0.2, 0.4, 0.55, 0.7],
                                      [-0.004, 0.008, 0.006, -0.002]), traces=False)
    assert repr(again.objective) == repr(ev.objective)
    assert export_text(ch, ev, "bvh") == export_text(ch, ev, "bvh")
    assert "states" not in ev.to_dict(include_traces=True)


def test_bad_requests_are_refused_with_the_rule(bend):
    ch, ev = bend
    for fps in (0.5, MAX_FPS + 1, math.nan, True):
        with pytest.raises(ExportError, match="fps: must be a number from 1 to 1000"):
            sample_motion(ev, fps)
    with pytest.raises(ExportError, match="format: must be one of bvh, csv"):
        export_text(ch, ev, "fbx")
    with pytest.raises(ExportError, match="not recorded"):
        sample_motion(dataclasses.replace(ev, states=None))


def test_names_a_bvh_reader_cannot_split_are_made_safe(bend):
    ch, ev = bend
    odd = dataclasses.replace(ch, body_names=("pelvis", "upper body", "upper_body",
                                              *ch.body_names[3:]))
    names = bvh_names(odd)
    assert names[:3] == ["pelvis", "upper_body", "upper_body_2"]
    mocap = read(bvh_text(odd, sample_motion(ev, 10.0)))
    assert mocap.get_joints_names()[:2] == ["pelvis", "upper_body"]
    assert csv_text(ch, sample_motion(ev, 10.0)).count("\n") == _frame_count(ev.steps, 10) + 1


@pytest.mark.parametrize("model", ["sumo", "lion"])
def test_every_segment_of_another_character_is_where_ode_had_it(model):
    """Nothing in the writer is the humanoid's: the sumo's and the 23-segment lion's files put
    every joint and End Site where ODE had that point of its body, at three frames."""
    from sim import parse_spec

    spec = parse_spec({"name": f"{model}_stand", "character": {"model": model},
                       "clip": {"preparation": 0.2, "duration": 0.1, "decay": 0.2},
                       "task": {"type": "quiet_stance"}})
    ev = evaluate(spec, None, traces=True)
    ch = spec.load_character()
    mocap = read(export_text(ch, ev, "bvh", 50.0))
    assert sorted(mocap.get_joints_names()) == sorted(ch.body_names)
    worst = 0.0
    for i in (0, 10, 20):  # 50 fps frames at 0, 0.2, 0.4 s: replay frames 0, 20, 40
        pts = world_points(mocap, i)
        for b, name in enumerate(ch.body_names):
            leaf = b not in ch.parent
            sim = world(ev.frames.poses[2 * i][b], ch.com0[b],
                        end_site(ch, b) if leaf else ch.anchor0[b])
            worst = max(worst, float(np.max(np.abs(pts[f"{name}/end" if leaf else name]
                                                   - sim))))
    assert worst < 1e-4
