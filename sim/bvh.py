"""A BVH (Biovision hierarchy) reader: the skeleton, the motion's channels and the joints' world
positions by forward kinematics. Pure Python and numpy.

A BVH file is untrusted input: its size, joint count, depth, channel count, frame count and
every number are bounded; every problem is one `BvhError` naming the line (`clip.bvh: line
42: ...`); nothing in a file can crash the process.

Conventions (the format's): a joint's frame is its parent's, translated by its OFFSET (plus
its position channels, if any) and rotated by its rotation channels in the order listed
(`Zrotation Xrotation Yrotation`: R = Rz Rx Ry, intrinsic). Angles in degrees; lengths in the
file's unit (`BvhClip.positions` gives them as they are).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from cmrt.specfile import SpecReadError, read_bytes
from sim.errors import SimError

#: Largest BVH file read (bytes): a two-minute clip of a 60-joint skeleton at 120 Hz is ~30 MB.
MAX_BVH_BYTES = 64_000_000
#: Most joints (End Sites not counted) and deepest nesting of a hierarchy.
MAX_JOINTS = 512
MAX_DEPTH = 128
#: Most frames of a motion (ten minutes at 120 Hz).
MAX_FRAMES = 72_000
#: Largest |number| in a file: offsets and positions (in any unit) and angles (degrees).
MAX_MAGNITUDE = 1e7
#: Frame time range (s): 10 kHz to 1 Hz.
MIN_FRAME_TIME, MAX_FRAME_TIME = 1e-4, 1.0
#: Largest joint name.
MAX_NAME = 128

CHANNEL_NAMES = ("Xposition", "Yposition", "Zposition", "Xrotation", "Yrotation", "Zrotation")
_NAME = re.compile(r"^[^\s{}]+$")


class BvhError(SimError, ValueError):
    """A BVH file that cannot be read; the message names the file and the line."""


@dataclass(frozen=True)
class BvhJoint:
    """One joint of the hierarchy: its parent's index (-1 for the root), OFFSET, channels (in
    the file's order), End Site offset (None if it has children instead) and the line that
    declares it."""

    name: str
    parent: int
    offset: np.ndarray
    channels: tuple[str, ...]
    end_site: np.ndarray | None
    line: int


@dataclass(frozen=True)
class BvhClip:
    """A BVH file read: joints in file order (a parent before its children), the frame time (s)
    and the motion (frames x channels, the joints' channels in file order)."""

    source: str
    joints: tuple[BvhJoint, ...]
    frame_time: float
    motion: np.ndarray

    @property
    def frames(self) -> int:
        return self.motion.shape[0]

    @property
    def names(self) -> list[str]:
        return [j.name for j in self.joints]

    def index(self, name: str) -> int:
        """The joint's index; BvhError naming the joints there are if it has none."""
        for i, j in enumerate(self.joints):
            if j.name == name:
                return i
        raise BvhError(f"{self.source}: no joint {name!r}; joints are "
                       f"{', '.join(self.names[:40])}{' ...' if len(self.joints) > 40 else ''}")

    def children(self, i: int) -> list[int]:
        return [k for k, j in enumerate(self.joints) if j.parent == i]

    def positions(self, frames: np.ndarray | None = None, rest: bool = False
                  ) -> tuple[np.ndarray, np.ndarray]:
        """World positions of every joint and of every End Site at the given frames (default:
        all; `rest`: one frame with every channel 0, the rest pose, root at its OFFSET):
        (F, joints, 3) and (F, joints, 3), the End Site rows NaN for joints without one."""
        values = (np.zeros((1, self.motion.shape[1])) if rest else
                  self.motion if frames is None else self.motion[frames])
        n = values.shape[0]
        pos = np.empty((n, len(self.joints), 3))
        ends = np.full((n, len(self.joints), 3), np.nan)
        rot = np.empty((n, len(self.joints), 3, 3))
        col = 0
        for i, j in enumerate(self.joints):
            local = np.broadcast_to(j.offset, (n, 3)).copy()
            r_local = np.broadcast_to(np.eye(3), (n, 3, 3)).copy()
            for ch in j.channels:
                v = values[:, col]
                col += 1
                axis = "XYZ".index(ch[0])
                if ch.endswith("position"):
                    local[:, axis] += v
                else:
                    r_local = r_local @ axis_rotations(axis, np.radians(v))
            if j.parent < 0:
                pos[:, i] = local
                rot[:, i] = r_local
            else:
                r_parent = rot[:, j.parent]
                pos[:, i] = pos[:, j.parent] + np.einsum("fab,fb->fa", r_parent, local)
                rot[:, i] = r_parent @ r_local
            if j.end_site is not None:
                ends[:, i] = pos[:, i] + rot[:, i] @ j.end_site
        return pos, ends


def axis_rotations(axis: int, angles: np.ndarray) -> np.ndarray:
    """(n, 3, 3) rotations by `angles` (rad) about axis 0 (X), 1 (Y) or 2 (Z)."""
    c, s = np.cos(angles), np.sin(angles)
    out = np.zeros((len(angles), 3, 3))
    a, b = [k for k in range(3) if k != axis]
    out[:, axis, axis] = 1.0
    out[:, a, a] = c
    out[:, b, b] = c
    # X: (y, z) rows [c -s; s c]; Y: (x, z) [c s; -s c]; Z: (x, y) [c -s; s c].
    sign = -1.0 if axis == 1 else 1.0
    out[:, a, b] = -s * sign
    out[:, b, a] = s * sign
    return out


class _Lines:
    """The file's lines as tokens, with their line numbers, read front to back."""

    def __init__(self, text: str, source: str):
        self.source = source
        self.lines = text.splitlines()
        self.k = 0

    def error(self, msg: str, line: int | None = None) -> BvhError:
        n = self.k if line is None else line
        return BvhError(f"{self.source}: line {n}: {msg}")

    def next(self, what: str) -> list[str]:
        """The next non-blank line's tokens."""
        while self.k < len(self.lines):
            self.k += 1
            tokens = self.lines[self.k - 1].split()
            if tokens:
                return tokens
        raise BvhError(f"{self.source}: the file ends where {what} was expected")

    def number(self, token: str, what: str) -> float:
        try:
            v = float(token)
        except ValueError:
            raise self.error(f"{what}: {token[:40]!r} is not a number") from None
        if not math.isfinite(v) or abs(v) > MAX_MAGNITUDE:
            raise self.error(f"{what}: {token[:40]} is not a finite number of at most "
                             f"{MAX_MAGNITUDE:g} in size")
        return v


def read_bvh(path: str | Path) -> BvhClip:
    """Read a BVH file (module docstring); BvhError for any problem."""
    p = Path(path)
    try:
        raw = read_bytes(p, "the BVH file", MAX_BVH_BYTES)
    except SpecReadError as err:
        raise BvhError(str(err)) from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        text = raw.decode("latin-1")  # names in another 8-bit code page: read as they are
    return parse_bvh(text, str(p))


def parse_bvh(text: str, source: str = "<bvh>") -> BvhClip:
    """Parse a BVH document (module docstring); BvhError for any problem."""
    lines = _Lines(text, source)
    head = lines.next("HIERARCHY")
    if head != ["HIERARCHY"]:
        raise lines.error(f"expected HIERARCHY, got {' '.join(head)[:60]!r}")
    joints = _hierarchy(lines)
    frames, frame_time = _motion_header(lines)
    width = sum(len(j.channels) for j in joints)
    motion = np.empty((frames, width))
    for i in range(frames):
        tokens = lines.next(f"frame {i + 1} of {frames}")
        if len(tokens) != width:
            raise lines.error(f"frame {i + 1} has {len(tokens)} values; the hierarchy has "
                              f"{width} channels")
        try:
            row = np.array(tokens, dtype=float)
        except ValueError:
            bad = next(t for t in tokens if not _is_number(t))
            raise lines.error(f"frame {i + 1}: {bad[:40]!r} is not a number") from None
        if not np.all(np.isfinite(row)) or np.abs(row).max(initial=0.0) > MAX_MAGNITUDE:
            raise lines.error(f"frame {i + 1}: values must be finite and at most "
                              f"{MAX_MAGNITUDE:g} in size")
        motion[i] = row
    while lines.k < len(lines.lines):
        lines.k += 1
        if lines.lines[lines.k - 1].strip():
            raise lines.error(f"more frames than the {frames} that `Frames:` gives")
    return BvhClip(source, tuple(joints), frame_time, motion)


def _is_number(token: str) -> bool:
    try:
        float(token)
    except ValueError:
        return False
    return True


def _hierarchy(lines: _Lines) -> list[BvhJoint]:
    """The joints from ROOT to its closing brace."""
    tokens = lines.next("ROOT")
    if len(tokens) != 2 or tokens[0] != "ROOT":
        raise lines.error("expected `ROOT name`")
    joints: list[BvhJoint] = []
    # A stack of (joint index, its declaring line): a joint's block is read line by line.
    pending = [(tokens[1], -1, lines.k)]
    stack: list[int] = []
    while pending or stack:
        if pending:
            name, parent, line = pending.pop()
            joints.append(_joint_head(lines, name, parent, line, joints))
            stack.append(len(joints) - 1)
            if len(stack) > MAX_DEPTH:
                raise lines.error(f"the hierarchy nests deeper than {MAX_DEPTH} joints")
            continue
        tokens = lines.next("a JOINT, End Site or `}`")
        me = stack[-1]
        if tokens[0] == "}" and len(tokens) == 1:
            stack.pop()
        elif tokens[0] == "JOINT" and len(tokens) == 2:
            if joints[me].end_site is not None:
                raise lines.error(f"joint {joints[me].name!r} has an End Site and children")
            pending.append((tokens[1], me, lines.k))
        elif tokens[:2] == ["End", "Site"] and len(tokens) == 2:
            joints[me] = _end_site(lines, joints[me])
        else:
            raise lines.error(f"expected JOINT, End Site or `}}`, got "
                              f"{' '.join(tokens)[:60]!r}")
    return joints


def _joint_head(lines: _Lines, name: str, parent: int, line: int,
                joints: list[BvhJoint]) -> BvhJoint:
    """A joint's `{`, OFFSET and CHANNELS lines."""
    if len(name) > MAX_NAME or not _NAME.match(name):
        raise lines.error(f"joint name {name[:40]!r}: must be 1 to {MAX_NAME} characters "
                          "without spaces or braces", line)
    if any(j.name == name for j in joints):
        raise lines.error(f"joint {name!r} is named twice", line)
    if len(joints) >= MAX_JOINTS:
        raise lines.error(f"more than {MAX_JOINTS} joints", line)
    if lines.next("`{`") != ["{"]:
        raise lines.error(f"expected `{{` after joint {name!r}")
    offset = _offset(lines, name)
    tokens = lines.next("CHANNELS")
    if tokens[0] != "CHANNELS" or len(tokens) < 2:
        raise lines.error(f"joint {name!r}: expected `CHANNELS n names...`")
    try:
        n = int(tokens[1])
    except ValueError:
        raise lines.error(f"joint {name!r}: the channel count {tokens[1][:20]!r} is not a "
                          "whole number") from None
    channels = tuple(tokens[2:])
    if not 0 <= n <= 6 or len(channels) != n:
        raise lines.error(f"joint {name!r}: CHANNELS says {tokens[1][:20]} and names "
                          f"{len(channels)} (0 to 6)")
    bad = [c for c in channels if c not in CHANNEL_NAMES]
    if bad or len(set(channels)) != n:
        raise lines.error(f"joint {name!r}: channels must be distinct names of "
                          f"{', '.join(CHANNEL_NAMES)}; got {' '.join(channels)[:80]}")
    return BvhJoint(name, parent, offset, channels, None, line)


def _offset(lines: _Lines, name: str) -> np.ndarray:
    tokens = lines.next("OFFSET")
    if tokens[0] != "OFFSET" or len(tokens) != 4:
        raise lines.error(f"joint {name!r}: expected `OFFSET x y z`")
    return np.array([lines.number(t, f"joint {name!r} OFFSET") for t in tokens[1:]])


def _end_site(lines: _Lines, joint: BvhJoint) -> BvhJoint:
    if joint.end_site is not None:
        raise lines.error(f"joint {joint.name!r} has two End Sites")
    if lines.next("`{`") != ["{"]:
        raise lines.error("expected `{` after End Site")
    end = _offset(lines, f"{joint.name}/End Site")
    if lines.next("`}`") != ["}"]:
        raise lines.error("expected `}` closing the End Site")
    return BvhJoint(joint.name, joint.parent, joint.offset, joint.channels, end, joint.line)


def _motion_header(lines: _Lines) -> tuple[int, float]:
    """MOTION, `Frames: n`, `Frame Time: s`."""
    if lines.next("MOTION") != ["MOTION"]:
        raise lines.error("expected MOTION after the hierarchy")
    tokens = lines.next("Frames:")
    if len(tokens) != 2 or tokens[0] != "Frames:" or not tokens[1].isdigit():
        raise lines.error("expected `Frames: n`")
    frames = int(tokens[1])
    if not 1 <= frames <= MAX_FRAMES:
        raise lines.error(f"Frames: must be from 1 to {MAX_FRAMES}, got {tokens[1][:20]}")
    tokens = lines.next("Frame Time:")
    if len(tokens) != 3 or tokens[:2] != ["Frame", "Time:"]:
        raise lines.error("expected `Frame Time: seconds`")
    dt = lines.number(tokens[2], "Frame Time")
    if not MIN_FRAME_TIME <= dt <= MAX_FRAME_TIME:
        raise lines.error(f"Frame Time: must be from {MIN_FRAME_TIME:g} to {MAX_FRAME_TIME:g} "
                          f"s, got {tokens[2][:20]}")
    return frames, dt
