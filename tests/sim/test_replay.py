"""The replay document (sim.replay): shapes to scale from the character file, one frame per
1/rate s of the clip, and values that are the evaluation's (rounded to 0.1 mm / 1e-4 rad)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from optim.spline import CmrtSpline
from sim import parse_spec
from sim.character import DATA_DIR
from sim.physics import DT
from sim.recording import FRAME_EVERY
from sim.replay import SCHEMA, ReplayClip, build_replay, prop_shapes
from sim.rollout import evaluate

ROOT = Path(__file__).resolve().parents[2]
RATE = 1.0 / (FRAME_EVERY * DT)
BEND = {"name": "bend_small", "family": "bend", "character": {"height": 1.5, "mass": 60.0},
        "clip": {"preparation": 0.3, "duration": 0.3, "decay": 0.2},
        "task": {"type": "pose_change", "target": {"waist": -40, "shoulder_r": 60}}}
POSE_TOL = 0.5e-4 + 1e-12  # half the last kept decimal


def _world(pose, local):
    x, y, a = pose
    c, s = math.cos(a), math.sin(a)
    return np.array([x + c * local[0] - s * local[1], y + s * local[0] + c * local[1]])


@pytest.fixture(scope="module")
def bend():
    spec = parse_spec(BEND)
    cmrt = CmrtSpline(spec.clip.length, [0.2, 0.4, 0.55, 0.7], [-0.004, 0.008, 0.006, -0.002])
    ev = evaluate(spec, cmrt, traces=True)
    flat = evaluate(spec, None, traces=True)
    doc = build_replay(spec, [ReplayClip("flat", flat), ReplayClip("cmrt", ev, cmrt, {"x": 1})])
    return spec, cmrt, ev, flat, doc


def test_shapes_are_the_character_files_to_scale(bend):
    spec, _, _, _, doc = bend
    raw = yaml.safe_load((DATA_DIR / "humanoid.yaml").read_text())
    k = 1.5 / raw["reference"]["height"]
    ch = spec.load_character()
    segs = {s["name"]: s for s in doc["character"]["segments"]}
    assert list(segs) == [s["name"] for s in raw["segments"]]
    for seg in raw["segments"]:
        com = np.array(seg["com"]) * k
        shapes = segs[seg["name"]]["shapes"]
        ends = [np.array(s[e]) + com for s in shapes if s["kind"] == "capsule" for e in "ab"]
        radii = {s["rb"] for s in shapes if s["kind"] == "capsule" and s.get("geom", 0) == 0}
        for x, y, r in seg.get("points", []):
            p = np.array([x, y]) * k
            reached = any(np.allclose(e, p, atol=1e-5) for e in ends)
            at_hub = "joint" in seg and np.allclose(np.array(seg["joint"]["anchor"]) * k, p)
            assert reached or at_hub, (seg["name"], p)
            assert round(r * k, 5) in radii | {0.0}
        if "foot" in seg:
            (poly,) = [s for s in shapes if s["kind"] == "polygon"]
            heel, toe = np.array(poly["points"][0]) + com, np.array(poly["points"][1]) + com
            assert heel == pytest.approx(np.array(seg["foot"]["heel"]) * k, abs=1e-5)
            assert toe == pytest.approx(np.array(seg["foot"]["toe"]) * k, abs=1e-5)
        for g in seg.get("geoms", []):
            (s,) = [s for s in shapes if s.get("geom", 0) == g.get("name")
                    and s["kind"] == ("circle" if g["shape"] == "sphere" else "capsule")][:1]
            assert (s["r"] if g["shape"] == "sphere" else s["ra"]) == pytest.approx(
                g["radius"] * k, abs=1e-5)
    assert doc["character"]["height"] == 1.5 and ch.height == 1.5


def test_shapes_follow_the_recorded_poses(bend):
    """Drawn with the frames' poses, each hinge anchor lands at the same place from the body
    and from its parent (ODE's joint error: under a millimetre), and the soles start on the
    ground: the local frames are the ones the poses are in."""
    spec, _, _, _, doc = bend
    ch = spec.load_character()
    clip = doc["clips"][1]
    worst = 0.0
    for row in clip["poses"]:
        poses = [row[3 * b:3 * b + 3] for b in range(ch.n_bodies)]
        for b in range(1, ch.n_bodies):
            p = ch.parent[b]
            a_child = _world(poses[b], ch.anchor0[b] - ch.com0[b])
            a_parent = _world(poses[p], ch.anchor0[b] - ch.com0[p])
            worst = max(worst, float(np.hypot(*(a_child - a_parent))))
    assert worst < 1e-3, worst
    segs = doc["character"]["segments"]
    for f in ch.feet:
        (poly,) = [s for s in segs[f]["shapes"] if s["kind"] == "polygon"]
        for q in poly["points"][:2]:  # heel and toe
            assert abs(_world(clip["poses"][0][3 * f:3 * f + 3], q)[1]) < 2e-3


def test_frame_count_and_values_match_the_evaluation(bend):
    spec, cmrt, ev, flat, doc = bend
    assert doc["schema"] == SCHEMA and doc["rate"] == RATE
    assert doc["bodies"] == ev.frames.names
    n = round(spec.clip.length * RATE)
    for clip, e in zip(doc["clips"], (flat, ev), strict=True):
        assert clip["frames"] == len(clip["t"]) == len(clip["poses"]) == n
        assert clip["t"][1] - clip["t"][0] == pytest.approx(1.0 / RATE)
        poses = np.array(clip["poses"])
        assert np.abs(poses - np.array(e.frames.poses).reshape(n, -1)).max() <= POSE_TOL
        assert np.abs(np.array(clip["cm"]) - np.array(e.frames.cm)).max() <= POSE_TOL
        assert np.abs(np.array(clip["cm_ref"]) - np.array(e.frames.cm_ref)).max() <= POSE_TOL
        assert np.abs(np.array(clip["support"]) - np.array(e.frames.support)).max() <= POSE_TOL
        # e(t) at a frame is the 1 kHz trace's CP error of the step ending at that time.
        for i in (10, n // 2, n - 1):
            k = round(clip["t"][i] / DT) - 1
            assert clip["plots"]["error"][i] == pytest.approx(e.traces.error[k], abs=1e-5)
        assert clip["outcome"]["objective"] == pytest.approx(e.objective, abs=1e-6)
        assert clip["outcome"]["fell"] == e.fell
    dx = doc["clips"][1]["plots"]["cmrt_dx"]
    assert dx == pytest.approx([cmrt(t) for t in ev.frames.t], abs=1e-5)
    assert doc["clips"][0]["plots"]["cmrt_dx"] == [0.0] * n
    # The controller's reference is the support centre plus the CMRT displacement, as the
    # controller last refreshed it (every few steps: within 1 mm of the CMRT at the frame).
    c = doc["clips"][1]
    for i in (20, 40, 60):
        centre = 0.5 * (c["support"][i][0] + c["support"][i][1])
        assert c["cm_ref"][i][0] - centre == pytest.approx(dx[i], abs=1e-3)
    assert doc["clips"][1]["cmrt"] == {"x": 1} and doc["clips"][0]["cmrt"] is None
    json.dumps(doc, allow_nan=False)  # strict JSON: no NaN


def test_a_fall_ends_the_frames_and_is_reported():
    spec = parse_spec({"name": "shove", "clip": {"preparation": 0.3, "duration": 0.2,
                                                  "decay": 0.5},
                       "task": {"type": "push", "force": 1000, "direction": "forward"}})
    ev = evaluate(spec, None, traces=True)
    assert ev.fell and ev.steps < spec.clip.length / DT  # a body touched the ground
    (clip,) = build_replay(spec, [ReplayClip("shove", ev)])["clips"]
    assert clip["frames"] == math.ceil(ev.steps / FRAME_EVERY)
    o = clip["outcome"]
    assert o["fell"] and o["fall_time"] == pytest.approx(ev.fall_time)
    assert o["fall_direction"] == ev.fall_direction == "forward"
    assert o["fall_reason"] == ev.fall_reason


def test_props_are_drawn_from_their_defs():
    spec = parse_spec(yaml.safe_load((ROOT / "examples" / "catch.yaml").read_text()))
    props = spec.task.build(spec, spec.load_character()).props
    assert props  # the catch has a ball
    doc_props = prop_shapes(props)
    assert [p["name"] for p in doc_props] == [p.name for p in props]
    for d, p in zip(doc_props, props, strict=True):
        assert d["shape"] == p.shape and d["size"] == pytest.approx(list(p.size))
