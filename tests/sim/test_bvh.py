"""The BVH reader (sim.bvh): real CMU clips read and their joints placed as an independent
reader places them (the `bvh` library from PyPI, tests/bvh_helpers.py); every kind of bad file
one BvhError naming the line, never anything else."""

from __future__ import annotations

import contextlib
from pathlib import Path

import numpy as np
import pytest
from bvh_helpers import read as read_with_library
from bvh_helpers import world_points

from sim import bvh as bvh_module
from sim.bvh import BvhError, parse_bvh, read_bvh

DATA = Path(__file__).resolve().parents[1] / "data"
WALK = DATA / "cmu_02_01_walk.bvh"
BEND = DATA / "cmu_02_06_bend.bvh"

TINY = """HIERARCHY
ROOT Hips
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
  JOINT Spine
  {
    OFFSET 0 10 0
    CHANNELS 3 Zrotation Xrotation Yrotation
    End Site
    {
      OFFSET 0 5 0
    }
  }
}
MOTION
Frames: 2
Frame Time: 0.5
0 90 0 0 0 0 0 0 0
1 90 0 90 0 0 -90 0 0
"""


def test_real_clips_are_read():
    walk, bend = read_bvh(WALK), read_bvh(BEND)
    assert (len(walk.joints), walk.frames, walk.frame_time) == (31, 121, 0.0083333)
    assert walk.names[:3] == ["Hips", "LHipJoint", "LeftUpLeg"]
    assert (len(bend.joints), bend.frames) == (24, 181)
    assert bend.motion.shape == (181, 6 + 23 * 3)


@pytest.mark.parametrize("path", [WALK, BEND], ids=lambda p: p.stem)
def test_joints_are_where_an_independent_reader_puts_them(path):
    clip = read_bvh(path)
    other = read_with_library(path.read_text())
    frames = [0, clip.frames // 3, clip.frames - 1]
    pos, ends = clip.positions(np.array(frames))
    for k, f in enumerate(frames):
        theirs = world_points(other, f)
        for i, name in enumerate(clip.names):
            assert np.allclose(pos[k, i], theirs[name], atol=1e-9), (f, name)
            if clip.joints[i].end_site is not None:
                assert np.allclose(ends[k, i], theirs[f"{name}/end"], atol=1e-9), (f, name)


def test_forward_kinematics_by_hand():
    clip = parse_bvh(TINY)
    pos, ends = clip.positions()
    # Frame 0: upright at (0, 90, 0). Frame 1: the root turned +90 about Z (x -> y), the
    # spine -90 about Z back: the spine's joint is 10 along the root's y, i.e. -x.
    assert np.allclose(pos[0], [[0, 90, 0], [0, 100, 0]])
    assert np.allclose(ends[0, 1], [0, 105, 0])
    assert np.allclose(pos[1], [[1, 90, 0], [-9, 90, 0]])
    assert np.allclose(ends[1, 1], [-9, 95, 0])
    rest, rest_ends = clip.positions(rest=True)
    assert np.allclose(rest[0], [[0, 0, 0], [0, 10, 0]]) and np.allclose(rest_ends[0, 1],
                                                                         [0, 15, 0])


def _bad(text: str, words: str, line: int | None = None) -> None:
    with pytest.raises(BvhError) as err:
        parse_bvh(text, "bad.bvh")
    msg = str(err.value)
    assert msg.startswith("bad.bvh: ") and words in msg, msg
    if line is not None:
        assert f"line {line}:" in msg, msg


def test_each_kind_of_bad_file_names_the_line():
    lines = TINY.splitlines()

    def with_line(n: int, text: str) -> str:
        return "\n".join([*lines[:n - 1], text, *lines[n:]]) + "\n"

    _bad("HIERARCHIE\n", "expected HIERARCHY", 1)
    _bad(with_line(4, "  OFFSET 0 x 0"), "'x' is not a number", 4)
    _bad(with_line(4, "  OFFSET 0 1e999 0"), "finite", 4)
    _bad(with_line(5, "  CHANNELS 5 Xposition Yposition Zposition Zrotation Xrotation "
                      "Yrotation"), "CHANNELS says 5 and names 6", 5)
    _bad(with_line(9, "    CHANNELS 3 Zrotation Wrotation Yrotation"), "channels must be", 9)
    _bad(with_line(6, "  JOINT Hips"), "named twice", 6)
    _bad(with_line(6, "  JOINT two words"), "expected JOINT, End Site", 6)
    _bad(with_line(17, "Frames: 3"), "the file ends where frame 3 of 3", None)
    _bad(with_line(17, "Frames: 1"), "more frames than the 1", 20)
    _bad(with_line(17, "Frames: 999999"), "Frames: must be from 1 to 72000", 17)
    _bad(with_line(18, "Frame Time: 0"), "Frame Time: must be from", 18)
    _bad(with_line(19, "0 90 0 0 0"), "frame 1 has 5 values; the hierarchy has 9", 19)
    _bad(with_line(19, "0 90 0 0 0 0 nan 0 0"), "finite", 19)
    _bad(with_line(19, "0 90 0 0 0 0 1e9 0 0"), "finite", 19)
    _bad(with_line(19, "0 90 0 0 0 0 zero 0 0"), "'zero' is not a number", 19)
    _bad(TINY.replace("End Site", "End Site\n{\nOFFSET 0 1 0\n}\nEnd Site"), "two End Sites")
    _bad(TINY[:120], "the file ends where")
    deep = "HIERARCHY\nROOT r\n{\nOFFSET 0 0 0\nCHANNELS 0\n" + "".join(
        f"JOINT j{i}\n{{\nOFFSET 0 1 0\nCHANNELS 0\n" for i in range(200))
    _bad(deep, "nests deeper than 128")


def test_no_file_crashes_the_reader(tmp_path, monkeypatch):
    """Truncations and byte garbage of a real clip: a BvhError or a clip, nothing else."""
    text = BEND.read_text()[:40_000]
    rng = np.random.default_rng(5)
    for n in rng.integers(1, len(text), 40):
        with contextlib.suppress(BvhError):
            parse_bvh(text[:n], "cut.bvh")
    raw = bytearray(text[:20_000].encode())
    for _ in range(40):
        b = raw.copy()
        for k in rng.integers(0, len(b), 30):
            b[k] = int(rng.integers(0, 256))
        with contextlib.suppress(BvhError):
            parse_bvh(b.decode("latin-1"), "noise.bvh")
    with pytest.raises(BvhError, match="no such file"):
        read_bvh(tmp_path / "none.bvh")
    monkeypatch.setattr(bvh_module, "MAX_BVH_BYTES", 1000)
    with pytest.raises(BvhError, match="larger than 1000 bytes"):
        read_bvh(WALK)
