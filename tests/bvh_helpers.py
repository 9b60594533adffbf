"""Forward kinematics of a BVH file as an independent reader sees it: parsed by the `bvh`
library from PyPI (not by the product's own code), positions from its offsets and channels by
the BVH convention (a joint's frame = its parent's, translated by its OFFSET, rotated by its
rotation channels in the order listed; the root also translated by its position channels)."""

from __future__ import annotations

import math

import numpy as np
from bvh import Bvh


def _axis_rotation(axis: str, deg: float) -> np.ndarray:
    a = math.radians(deg)
    c, s = math.cos(a), math.sin(a)
    if axis == "X":
        return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])
    if axis == "Y":
        return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def _end_site(mocap: Bvh, name: str) -> np.ndarray | None:
    joint = mocap.get_joint(name)
    for child in joint.children:
        if child.value[:2] == ["End", "Site"]:
            return np.array([float(v) for v in child["OFFSET"]])
    return None


def world_points(mocap: Bvh, frame: int) -> dict[str, np.ndarray]:
    """Every joint's world position at `frame` (name -> (3,)), and each End Site's as
    "NAME/end"."""
    out: dict[str, np.ndarray] = {}
    frames: dict[str, tuple[np.ndarray, np.ndarray]] = {}  # name -> (rotation, origin)
    for name in mocap.get_joints_names():
        channels = mocap.joint_channels(name)
        values = [float(v) for v in mocap.frame_joint_channels(frame, name, channels)]
        offset = np.array(mocap.joint_offset(name), dtype=float)
        parent = mocap.joint_parent(name)
        R0, o0 = (np.eye(3), np.zeros(3)) if parent is None else frames[parent.name]
        origin = o0 + R0 @ offset
        R = R0
        for ch, v in zip(channels, values, strict=True):
            if ch.endswith("position"):
                origin = origin + R0 @ np.array([v if ch[0] == ax else 0.0 for ax in "XYZ"])
            else:
                R = R @ _axis_rotation(ch[0], v)
        frames[name] = (R, origin)
        out[name] = origin
        end = _end_site(mocap, name)
        if end is not None:
            out[f"{name}/end"] = origin + R @ end
    return out


def read(path_or_text: str) -> Bvh:
    """The `bvh` library's parse of a file's text."""
    return Bvh(path_or_text)


def world(pose: tuple[float, float, float], com0: np.ndarray, p0: np.ndarray) -> np.ndarray:
    """Where a point p0 of a body (zero-pose world coordinates) is for the body's recorded pose
    (x, y, angle of its CoM, whose zero-pose place is com0), as BVH (x, y, 0)."""
    x, y, a = pose
    c, s = math.cos(a), math.sin(a)
    d = np.asarray(p0, dtype=float) - np.asarray(com0, dtype=float)
    return np.array([x + c * d[0] - s * d[1], y + s * d[0] + c * d[1], 0.0])
