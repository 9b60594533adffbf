"""A BVH clip as a motion (sim.motion_import), checked on real CMU clips against the clip's
sagittal bone angles computed by an independent route: joint positions by the `bvh` library
from PyPI (tests/bvh_helpers.py), the rest pose by summing offsets, and a projection written
here. Exported (sim.export) and imported back, a simulated motion's angles round-trip."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from bvh_helpers import read as read_with_library
from bvh_helpers import world_points

from sim.character import load_character
from sim.errors import SimError
from sim.export import MotionSamples, bvh_text, sample_motion
from sim.motion_import import ImportOptions, MotionImportError, import_motion, load_map
from sim.rollout import Rollout
from sim.spec import load_spec, parse_spec

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT / "tests" / "data"
WALK = DATA / "cmu_02_01_walk.bvh"
BEND = DATA / "cmu_02_06_bend.bvh"
CC3 = DATA / "cc3_map.yaml"
EXAMPLE = ROOT / "examples" / "motion_bend.yaml"
#: The documented default map of CMU names (docs/motion.md), segment -> (from, to): a bone end
#: is a joint, the mean of two, or a joint's End Site.
CMU_BONES = {
    "pelvis": ("Hips", ("LeftUpLeg", "RightUpLeg")), "trunk": ("LowerBack", "Neck"),
    "head": ("Neck", "Head/end"),
    "thigh_r": ("RightUpLeg", "RightLeg"), "shank_r": ("RightLeg", "RightFoot"),
    "foot_r": ("RightFoot", "RightToeBase"),
    "thigh_l": ("LeftUpLeg", "LeftLeg"), "shank_l": ("LeftLeg", "LeftFoot"),
    "foot_l": ("LeftFoot", "LeftToeBase"),
    "upperarm_r": ("RightArm", "RightForeArm"), "forearm_r": ("RightForeArm", "RightHand"),
    "upperarm_l": ("LeftArm", "LeftForeArm"), "forearm_l": ("LeftForeArm", "LeftHand"),
}
RAW = ImportOptions(cutoff=0.0, legs="each", rate=None)


def _rest_points(mocap) -> dict[str, np.ndarray]:
    """Every joint (and End Site) with all channels 0: the offsets summed down the tree."""
    out: dict[str, np.ndarray] = {}
    for name in mocap.get_joints_names():
        parent = mocap.joint_parent(name)
        base = np.zeros(3) if parent is None else out[parent.name]
        out[name] = base + np.array(mocap.joint_offset(name), dtype=float)
        for child in mocap.get_joint(name).children:
            if child.value[:2] == ["End", "Site"]:
                out[f"{name}/end"] = out[name] + np.array([float(v) for v in child["OFFSET"]])
    return out


def _end(points: dict[str, np.ndarray], ref) -> np.ndarray:
    names = ref if isinstance(ref, tuple) else (ref,)
    return sum(points[n] for n in names) / len(names)


def _sagittal(points: dict[str, np.ndarray], bones: dict, left: str, right: str,
              lateral: np.ndarray | None = None) -> tuple[dict[str, float], dict[str, float],
                                                          np.ndarray]:
    """Per segment its bone's angle in the sagittal plane (atan2(up, forward)) and the share
    of its length in the plane; the plane's normal: left -> right made level (Y up)."""
    if lateral is None:
        line = points[right] - points[left]
        line[1] = 0.0
        lateral = line / np.linalg.norm(line)
    forward = np.array([lateral[2], 0.0, -lateral[0]])  # Y x lateral, written out
    angle, share = {}, {}
    for seg, (a, b) in bones.items():
        d = _end(points, b) - _end(points, a)
        x, y = float(d @ forward), float(d[1])
        angle[seg] = math.atan2(y, x)
        share[seg] = math.hypot(x, y) / float(np.linalg.norm(d))
    return angle, share, lateral


def _own_zero(ch) -> dict[str, float]:
    """The humanoid's segment directions in its zero pose, from its file's geometry: to the
    farthest child joint, or for a segment without one to its farthest outline point, heel,
    toe or geom end."""
    out = {}
    for b, name in enumerate(ch.body_names):
        a = ch.anchor0[b]
        tips = [ch.anchor0[c] for c in range(ch.n_bodies) if ch.parent[c] == b]
        if not tips:
            tips = [ch.point0[i] for i in range(len(ch.point0)) if ch.point_body[i] == b]
            tips += [p for f, foot in enumerate(ch.feet) if foot == b
                     for p in (ch.heel0[f], ch.toe0[f])]
            tips += [np.asarray(p) for g in ch.geoms if g.body == b for p in (g.a, g.b)]
        d = max((np.asarray(t) - a for t in tips), key=lambda v: float(np.hypot(*v)))
        out[name] = math.atan2(d[1], d[0])
    return out


def _independent_angles(path: Path, bones: dict, left: str, right: str, zero: str,
                        frames: range) -> tuple[list[str], np.ndarray]:
    """Hinge angles (rad from the humanoid's zero pose) of the clip's frames, by the route of
    the module docstring."""
    ch = load_character("humanoid")
    mocap = read_with_library(path.read_text())
    rest, rest_share, _ = _sagittal(_rest_points(mocap), bones, left, right)
    own = _own_zero(ch)
    lateral = None
    rows = []
    hinges = []
    for f in frames:
        angle, _share, lateral = _sagittal(world_points(mocap, f), bones, left, right, lateral)
        row = []
        for j, hinge in enumerate(ch.hinge_names):
            c, p = ch.body_names[j + 1], ch.body_names[int(ch.parent[j + 1])]
            if zero == "rest" and min(rest_share[c], rest_share[p]) >= 0.5:
                ref = rest[c] - rest[p]
            else:
                ref = own[c] - own[p]
            row.append(angle[c] - angle[p] - ref)
            if f == frames[0]:
                hinges.append(hinge)
        rows.append(row)
    out = np.unwrap((np.array(rows) + np.pi) % (2 * np.pi) - np.pi, axis=0)
    return hinges, out


def _compare(imp, hinges, theirs: np.ndarray, times_theirs: np.ndarray) -> int:
    """Largest difference (degrees) between the written frames and the independent angles
    (interpolated at the written times), where no limit clipped; returns frames compared."""
    ch = load_character("humanoid")
    task = imp.spec["task"]
    written = np.radians(np.array(task["frames"])) + ch.standing_offsets[
        [ch.hinge_index(h) for h in task["joints"]]]
    lo, hi = ch.limits[[ch.hinge_index(h) for h in task["joints"]]].T
    n = 0
    for k, h in enumerate(task["joints"]):
        ref = np.interp(imp.times, times_theirs, theirs[:, hinges.index(h)])
        inside = (ref >= lo[k]) & (ref <= hi[k])
        diff = np.degrees(np.abs(written[inside, k] - ref[inside]))
        assert diff.max() < 0.5, (h, diff.max())
        n += int(inside.sum())
    return n


def test_a_cmu_clip_by_the_default_map_equals_its_sagittal_bone_angles():
    imp = import_motion(WALK, "humanoid", None, ImportOptions(start=0.1, cutoff=0.0,
                                                              legs="each", rate=120))
    assert imp.map_name == "cmu" and len(imp.spec["task"]["joints"]) == 12
    first = imp.first
    hinges, theirs = _independent_angles(WALK, CMU_BONES, "LeftUpLeg", "RightUpLeg", "rest",
                                         range(first, imp.last + 1))
    t = np.arange(len(theirs)) * 0.0083333
    compared = _compare(imp, hinges, theirs, t)
    assert compared >= 0.95 * 12 * len(imp.times)
    # Written as the motion task takes it, the import parses into a spec.
    spec = parse_spec(imp.spec)
    assert spec.task.rate == 120 and spec.task.joints == imp.spec["task"]["joints"]


def test_the_bend_by_its_map_file_equals_its_sagittal_bone_angles():
    smap = load_map(CC3)
    bones = {seg: (a[0] if len(a) == 1 else a, b[0] if len(b) == 1 else b)
             for seg, (a, b) in smap.segments.items()}
    imp = import_motion(BEND, "humanoid", CC3, RAW)
    hinges, theirs = _independent_angles(BEND, bones, "CC_Base_L_Thigh", "CC_Base_R_Thigh",
                                         "character", range(imp.first, imp.last + 1))
    t = np.arange(len(theirs)) * 0.016667
    assert _compare(imp, hinges, theirs, t) >= 0.95 * 12 * len(imp.times)
    # A large upper-body motion: the trunk bends by 50 degrees, an arm rises past 130.
    frames = np.array(imp.spec["task"]["frames"])
    joints = imp.spec["task"]["joints"]
    assert frames[:, joints.index("waist")].min() < -50
    assert frames[:, joints.index("shoulder_r")].max() > 130


def test_the_legs_are_averaged_so_both_feet_stay_planted():
    each = import_motion(WALK, "humanoid", None, ImportOptions(start=0.1, cutoff=0.0,
                                                               legs="each"))
    both = import_motion(WALK, "humanoid", None, ImportOptions(start=0.1, cutoff=0.0))
    j = both.spec["task"]["joints"]
    a, b = np.array(each.spec["task"]["frames"]), np.array(both.spec["task"]["frames"])
    for r, left in (("hip_r", "hip_l"), ("knee_r", "knee_l"), ("ankle_r", "ankle_l")):
        mean = 0.5 * (a[:, j.index(r)] + a[:, j.index(left)])
        assert np.allclose(b[:, j.index(r)], mean, atol=2e-6)
        assert np.array_equal(b[:, j.index(r)], b[:, j.index(left)])
    assert any(line.startswith("legs: ankle_r/ankle_l, knee_r/knee_l, hip_r/hip_l averaged")
               for line in both.report)


def test_the_filter_and_the_rate():
    raw = import_motion(BEND, "humanoid", CC3, ImportOptions(cutoff=0.0))
    smooth = import_motion(BEND, "humanoid", CC3)
    a, b = np.array(raw.spec["task"]["frames"]), np.array(smooth.spec["task"]["frames"])
    assert 0.1 < np.abs(a - b).max() < 2.5  # degrees: the jitter, not the motion
    # The spline's acceleration (what the controller takes as feed-forward) drops; measured
    # inside the motion (at its ends the clamped spline stops the clip's motion in one frame).
    def peak_acceleration(imp) -> float:
        sim = Rollout(parse_spec(imp.spec))
        try:
            ts = np.arange(1.1, 3.9, 0.002)
            return max(float(np.abs(sim.task.track(t)[2]).max()) for t in ts)
        finally:
            sim.close()
    assert peak_acceleration(smooth) < 0.1 * peak_acceleration(raw)
    half = import_motion(BEND, "humanoid", CC3, ImportOptions(cutoff=0.0, rate=30))
    assert half.spec["task"]["rate"] == 30 and len(half.times) == 91
    assert np.allclose(np.array(half.spec["task"]["frames"]), a[::2], atol=0.6)


def test_exported_and_imported_back_the_angles_round_trip(tmp_path):
    """The example's motion simulated, exported as BVH (sim.export) and imported by the
    identity map: every hinge angle of every frame back within 1e-6 rad."""
    spec = load_spec(EXAMPLE)
    sim = Rollout(spec)
    try:
        ev = sim.run(None, traces=True)
    finally:
        sim.close()
    ch = sim.character
    path = tmp_path / "bend_out.bvh"
    path.write_text(bvh_text(ch, sample_motion(ev, 60.0)))
    imp = import_motion(path, "humanoid", None, ImportOptions(cutoff=0.0, legs="each",
                                                              rate=60))
    assert imp.map_name == "identity" and imp.clipped == {}
    assert imp.spec["task"]["joints"] == list(ch.hinge_names)
    q = sample_motion(ev, 60.0).q[:, 3:]
    back = np.radians(np.array(imp.spec["task"]["frames"])) + ch.standing_offsets
    assert back.shape == q.shape
    assert np.abs(back - q).max() < 1e-6
    assert np.abs(imp.angles - q).max() < 1e-8  # before the file's rounding to 1e-6 degrees


def test_what_is_clipped_is_reported(tmp_path):
    """An elbow bent backwards for a third of the clip: clipped to its limit, and said."""
    ch = load_character("humanoid")
    n = 30
    q = np.zeros((n, ch.ndof))
    q[:, 1] = 1.0
    q[:, 3:] = ch.standing_offsets
    elbow = 3 + ch.hinge_index("elbow_r")
    q[10:20, elbow] = np.radians(-20.0)
    m = MotionSamples(30.0, np.arange(n) / 30.0, q, np.zeros((n, 2)), np.zeros(n))
    path = tmp_path / "elbow.bvh"
    path.write_text(bvh_text(ch, m))
    imp = import_motion(path, "humanoid", None, ImportOptions(cutoff=0.0, legs="each"))
    frames, excess = imp.clipped["elbow_r"]
    assert frames == 10 and excess == pytest.approx(20.0, abs=1e-6)
    assert ("clipped: elbow_r: 10 of 30 frames beyond its limits [0, 150] degrees, by up to "
            "20.00 degrees") in imp.report
    col = imp.spec["task"]["joints"].index("elbow_r")
    assert min(r[col] for r in imp.spec["task"]["frames"]) == pytest.approx(-10.0)  # limit 0


@pytest.mark.parametrize("text, words", [
    ("[1, 2]", "map: must be a mapping"),
    ("segments: {}", "segments: must map 1 to 256"),
    ("segments: {trunk: Hips}", "segments.trunk: must be [from, to]"),
    ("segments: {trunk: [Hips, [a/end, b]]}", "segments.trunk.1: an End Site"),
    ("segments: {trunk: [Hips, Spine]}\nplane: yz", "plane: must be xy or"),
    ("segments: {trunk: [Hips, Spine]}\nup: w", "up: must be x, y or z"),
    ("segments: {trunk: [Hips, Spine]}\nzero: first", "zero: must be rest or character"),
    ("segments: {trunk: [Hips, Spine]}\nscale: 2", "scale: unknown field"),
])
def test_a_bad_map_names_the_field(tmp_path, text, words):
    path = tmp_path / "m.yaml"
    path.write_text(text)
    with pytest.raises(MotionImportError) as err:
        import_motion(WALK, "humanoid", path)
    assert str(err.value).startswith(f"{path}: ") and words in str(err.value)


def test_a_map_that_does_not_fit_names_what(tmp_path):
    for text, words in (("segments: {tail: [Hips, Spine]}", "segments.tail: character "
                         "'humanoid' has no segment 'tail'"),
                        ("segments: {trunk: [Hips, Chest], pelvis: [Hips, Spine]}",
                         "no joint 'Chest'"),
                        ("segments: {trunk: [Hips, Spine]}", "no hinge of character")):
        path = tmp_path / "m.yaml"
        path.write_text(text)
        with pytest.raises(SimError) as err:
            import_motion(WALK, "humanoid", path)
        assert words in str(err.value), str(err.value)


def test_bad_options_name_the_option():
    for opts, words in ((ImportOptions(start=5.0), "--start: must be from 0 to the clip's 0.99"),
                        (ImportOptions(start=0.5, end=0.5), "fewer than 2 frames"),
                        (ImportOptions(rate=500.0), "--rate: must be from 1 to 240"),
                        (ImportOptions(cutoff=70.0), "--cutoff: must be below half"),
                        (ImportOptions(legs="one"), "--legs: must be average or each"),
                        (ImportOptions(joints=("wrist",)), "--joints: 'wrist' is not a mapped")):
        with pytest.raises(MotionImportError, match=words.replace("[", r"\[")):
            import_motion(WALK, "humanoid", None, opts)


def test_mixamo_names_are_known(tmp_path):
    """The CMU walk with its joints renamed as Mixamo names them: the Mixamo map is chosen
    and gives the CMU map's angles where both follow the same bones."""
    rename = {"Hips": "Hips", "LowerBack": "Spine", "Neck": "Neck", "Head": "Head"}
    for side in ("Left", "Right"):
        for part in ("UpLeg", "Leg", "Foot", "ToeBase", "Arm", "ForeArm", "Hand"):
            rename[f"{side}{part}"] = f"{side}{part}"
    text = WALK.read_text()
    for old, new in rename.items():
        text = text.replace(f"JOINT {old}\n", f"JOINT mixamorig:{new}\n").replace(
            f"ROOT {old}\n", f"ROOT mixamorig:{new}\n")
    path = tmp_path / "walk_mixamo.bvh"
    path.write_text(text)
    opts = ImportOptions(start=0.1, cutoff=0.0, legs="each")
    mix, cmu = import_motion(path, "humanoid", None, opts), import_motion(WALK, "humanoid",
                                                                          None, opts)
    assert mix.map_name == "mixamo" and cmu.map_name == "cmu"
    j = cmu.spec["task"]["joints"]
    a, b = np.array(mix.spec["task"]["frames"]), np.array(cmu.spec["task"]["frames"])
    same = [k for k, h in enumerate(j) if h != "neck"]  # Mixamo's head bone is Neck -> Head
    assert np.array_equal(a[:, same], b[:, same])
