"""The humanoid's data: structure, mass, scaling, and validation of bad character files."""

from __future__ import annotations

import copy
import re

import numpy as np
import pytest
import yaml

from sim.character import DATA_DIR, load_character, parse_character
from sim.errors import CharacterError

REF_HEIGHT, REF_MASS = 1.75, 70.0


@pytest.fixture(scope="module")
def raw() -> dict:
    return yaml.safe_load((DATA_DIR / "humanoid.yaml").read_text())


@pytest.fixture(scope="module")
def ch():
    return load_character()


def test_humanoid_structure(ch):
    assert ch.n_bodies == 13
    assert ch.n_hinges == 12
    assert ch.ndof == 15
    # 70 kg exactly by construction of the table (sum of Winter's segment masses).
    assert ch.total_mass == pytest.approx(70.0, abs=1e-9)
    assert ch.height == REF_HEIGHT
    assert ch.parent[0] == -1
    assert all(0 <= ch.parent[b] < b for b in range(1, ch.n_bodies))
    assert [ch.body_names[f] for f in ch.feet] == ["foot_r", "foot_l"]
    # The spec layer validates joint names against the loaded character (its file's names).
    assert len(set(ch.hinge_names)) == 12
    assert ch.hinge_names[:3] == ("waist", "neck", "hip_r")
    assert np.all(ch.mass > 0) and np.all(ch.inertia > 0)
    # Every hinge range contains the zero pose and the standing pose.
    assert np.all(ch.limits[:, 0] <= 0) and np.all(ch.limits[:, 1] >= 0)
    assert np.all(ch.limits[:, 0] <= ch.standing_offsets)
    assert np.all(ch.standing_offsets <= ch.limits[:, 1])
    # Soles on the ground in the zero pose, toe ahead of heel; the head's top at the height.
    assert np.allclose(ch.heel0[:, 1], 0.0) and np.allclose(ch.toe0[:, 1], 0.0)
    assert np.all(ch.toe0[:, 0] > ch.heel0[:, 0])
    top = ch.point0[:, 1] + ch.point_radius
    assert top.max() == pytest.approx(REF_HEIGHT, abs=1e-12)


def test_scaling_to_190cm_90kg(ch):
    big = load_character("humanoid", 1.9, 90.0)
    ls, ms = 1.9 / REF_HEIGHT, 90.0 / REF_MASS
    assert big.total_mass == pytest.approx(90.0, rel=1e-12)
    assert big.height == 1.9
    # Documented: lengths scale with height, masses with mass, inertias with mass * height^2.
    np.testing.assert_allclose(big.mass, ch.mass * ms, rtol=1e-12)
    np.testing.assert_allclose(big.inertia, ch.inertia * ms * ls**2, rtol=1e-12)
    for attr in ("com0", "anchor0", "heel0", "toe0", "point0", "point_radius"):
        np.testing.assert_allclose(getattr(big, attr), getattr(ch, attr) * ls, rtol=1e-12,
                                   err_msg=attr)
    # Angles do not scale.
    np.testing.assert_array_equal(big.limits, ch.limits)
    np.testing.assert_array_equal(big.standing_offsets, ch.standing_offsets)
    top = big.point0[:, 1] + big.point_radius
    assert top.max() == pytest.approx(1.9, abs=1e-12)


def test_parse_character_of_the_file_equals_load(raw, ch):
    parsed = parse_character(copy.deepcopy(raw), name="humanoid")
    np.testing.assert_array_equal(parsed.mass, ch.mass)
    np.testing.assert_array_equal(parsed.com0, ch.com0)
    assert parsed.hinge_names == ch.hinge_names


def _seg(data: dict, name: str) -> tuple[int, dict]:
    for i, s in enumerate(data["segments"]):
        if s["name"] == name:
            return i, s
    raise KeyError(name)


def _missing_mass(d):
    i, s = _seg(d, "thigh_r")
    del s["mass"]
    return rf"segments\[{i}\]\.mass: must be a positive number"


def _negative_inertia(d):
    i, s = _seg(d, "shank_l")
    s["inertia"] = -0.055
    return rf"segments\[{i}\]\.inertia: must be a positive number, got -0\.055"


def _zero_mass(d):
    i, s = _seg(d, "head")
    s["mass"] = 0
    return rf"segments\[{i}\]\.mass: must be a positive number"


def _unknown_parent(d):
    i, s = _seg(d, "forearm_r")
    s["parent"] = "upperarm_x"
    return rf"segments\[{i}\]\.parent: 'upperarm_x' must name a segment listed before"


def _parent_listed_after(d):
    i, s = _seg(d, "thigh_r")
    s["parent"] = "shank_r"  # listed after thigh_r: not a tree in file order
    return rf"segments\[{i}\]\.parent: 'shank_r' must name a segment listed before"


def _limits_without_zero(d):
    i, s = _seg(d, "shank_r")  # the knee_r hinge
    s["joint"]["limits"] = [-150, -5]
    return rf"segments\[{i}\]\.joint\.limits: must include the zero pose"


def _limits_reversed(d):
    i, s = _seg(d, "trunk")
    s["joint"]["limits"] = [30, -120]
    return rf"segments\[{i}\]\.joint\.limits: must be \[lo, hi\] degrees, lo < hi"


def _toe_behind_heel(d):
    i, s = _seg(d, "foot_l")
    s["foot"] = {"heel": [0.176, 0.0], "toe": [-0.09, 0.0]}
    return rf"segments\[{i}\]\.foot: the toe must be ahead \(\+x\) of the heel"


def _bad_com(d):
    i, s = _seg(d, "pelvis")
    s["com"] = [0.0]
    return rf"segments\[{i}\]\.com: must be a list of two finite numbers"


def _duplicate_joint(d):
    i, s = _seg(d, "thigh_l")
    s["joint"]["name"] = "hip_r"
    return rf"segments\[{i}\]\.joint\.name: duplicate joint 'hip_r'"


def _unknown_standing_joint(d):
    d["standing"]["pose"]["wrist_r"] = 5
    return r"standing\.pose: unknown joint 'wrist_r'"


def _bad_reference_mass(d):
    d["reference"]["mass"] = -70
    return r"reference\.mass: must be a positive number"


def _no_feet(d):
    for s in d["segments"]:
        s.pop("foot", None)
    return r"segments: at least one segment needs a foot"


def _negative_weight(d):
    i, s = _seg(d, "trunk")
    s["joint"]["weight"] = -1.0
    return rf"segments\[{i}\]\.joint\.weight: must be a number >= 0"


def _boolean_torque(d):
    i, s = _seg(d, "trunk")
    s["joint"]["torque"] = True
    return rf"segments\[{i}\]\.joint\.torque: must be a positive number"


def _no_torque_limit(d):
    del d["torque_limit"]
    return r"torque_limit: must be a positive number"


def _bad_geom_shape(d):
    i, s = _seg(d, "forearm_r")
    s["geoms"][0]["shape"] = "cube"
    return rf"segments\[{i}\]\.geoms\[0\]\.shape: must be one of sphere, capsule"


def _unknown_hand(d):
    d["hands"] = ["hand_r", "claw"]
    return r"hands: must list geom names"


def _unknown_torso(d):
    d["torso"] = "chest"
    return r"torso: 'chest' is not a segment"


@pytest.mark.parametrize("mutate", [
    _missing_mass, _negative_inertia, _zero_mass, _unknown_parent, _parent_listed_after,
    _limits_without_zero, _limits_reversed, _toe_behind_heel, _bad_com, _duplicate_joint,
    _unknown_standing_joint, _bad_reference_mass, _no_feet, _negative_weight, _boolean_torque,
    _no_torque_limit, _bad_geom_shape, _unknown_hand, _unknown_torso,
], ids=lambda f: f.__name__.strip("_"))
def test_bad_character_names_field(raw, mutate):
    data = copy.deepcopy(raw)
    pattern = mutate(data)
    with pytest.raises(CharacterError, match=pattern):
        parse_character(data)


def test_bad_scale_rejected(raw):
    with pytest.raises(CharacterError, match=re.escape("height: 10.0 m is outside")):
        parse_character(copy.deepcopy(raw), height=10.0)
    with pytest.raises(CharacterError, match="mass: must be positive"):
        parse_character(copy.deepcopy(raw), mass=-1.0)


def test_controller_data_and_contact_geoms_come_from_the_file(raw, ch):
    """Tracking weights, torque limits, hand geoms and the torso are the file's; geoms scale
    with height like every length."""
    for seg in raw["segments"][1:]:
        j = seg["joint"]
        k = ch.hinge_index(j["name"])
        assert ch.tracking_weights[k] == j["weight"]
        assert ch.torque_limits[k] == j.get("torque", raw["torque_limit"])
    assert ch.body_names[ch.torso] == raw["torso"]
    assert ch.hands == tuple(raw["hands"])
    hand = ch.geom(ch.hands[0])
    assert hand.shape == "sphere" and ch.body_names[hand.body].startswith("forearm")
    big = load_character("humanoid", 1.9, 90.0)
    ls = 1.9 / REF_HEIGHT
    assert big.geom(big.hands[0]).radius == pytest.approx(hand.radius * ls, rel=1e-12)
    assert big.geom(big.hands[0]).a == pytest.approx(tuple(np.array(hand.a) * ls), rel=1e-12)
    with pytest.raises(CharacterError, match="unknown geom"):
        ch.geom("claw")
