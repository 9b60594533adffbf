"""The motion out: a simulated clip as BVH (the character's own skeleton) or CSV, at a chosen
frame rate. Pure: text from a `Character` and an `Evaluation` recorded with traces=True (its
1 kHz joint `States` and `Traces`); no ODE, no I/O.

`sample_motion(ev, fps)` resamples the 1 kHz record at `fps` (frame i at t = i / fps, from 0 to
the last recorded state; linear interpolation between the two steps around t, exact where
t is a whole step); `bvh_text` and `csv_text` write the samples; `export_text` does both steps
for a format named by a file extension. The form of the files is in docs/export.md:

- BVH: one JOINT per segment, named after it, in the character's tree (the root segment is the
  ROOT, at its CoM, the point q's root coordinates give); OFFSET from the parent's joint anchor
  to the segment's own in the zero pose; a leaf segment's End Site at its point farthest from
  its anchor (outline points, heel and toe, geoms). The character's plane is BVH's XY plane
  (character x forward -> X, y up -> Y), its hinges turn about BVH's Z axis: root channels
  `Xposition Yposition Zposition Zrotation Xrotation Yrotation`, joint channels
  `Zrotation Xrotation Yrotation`, X and Y rotations always 0. Metres, degrees.
- CSV: t, root_x, root_y, root_angle, one column per hinge (named after it), cm_x, cm_y,
  cop_x (empty without ground contact). Seconds, metres, degrees.
"""

from __future__ import annotations

import csv
import io
import math
import re
from dataclasses import dataclass

import numpy as np

from sim.character import ROOT_DOF, Character
from sim.clip_result import Evaluation
from sim.errors import SimError

#: The file formats by extension.
FORMATS = ("bvh", "csv")
#: Frames per second when none is asked for: what animation tools default to.
DEFAULT_FPS = 60.0
#: Hz: the range of frame rates. Below 1 a clip of a few seconds keeps a handful of poses;
#: above 1000 (the simulation's 1 ms step) frames would only interpolate between steps.
MIN_FPS, MAX_FPS = 1.0, 1000.0
#: Significant digits of an angle in degrees: 12 keep 1e-9 rad at 360 deg, so an importer
#: gets the simulation's angles back well within 1e-6 rad.
ANGLE_DIGITS = 12
#: Significant digits of a position in metres: 10 keep 1e-8 m at 100 m.
POSITION_DIGITS = 10
#: Steps per second of the 1 kHz record (sim.physics.DT = 1 ms), an integer so that a frame
#: that falls on a step is read there exactly.
STEPS_PER_SECOND = 1000
#: Characters a BVH name may keep (the format splits on white space; tools choke on others).
_NAME_OK = re.compile(r"[^A-Za-z0-9_.\-]")


class ExportError(SimError):
    """The clip cannot be written as asked (no recorded states, a frame rate out of range)."""


@dataclass(frozen=True)
class MotionSamples:
    """A clip resampled at `fps`: frame i at t[i] = i / fps.

    q: (n, ndof) root x, y (m), root angle and hinge angles (rad; unwrapped, so continuous
    across +-180 deg); cm: (n, 2) the CM (m); cop: (n,) the CP x (m), NaN without contact.
    """

    fps: float
    t: np.ndarray
    q: np.ndarray
    cm: np.ndarray
    cop: np.ndarray


def check_fps(fps: float) -> float:
    """The frame rate as a float, or ExportError naming the rule."""
    if not isinstance(fps, int | float) or isinstance(fps, bool) or not math.isfinite(fps) \
            or not MIN_FPS <= fps <= MAX_FPS:
        raise ExportError(f"fps: must be a number from {MIN_FPS:g} to {MAX_FPS:g} frames per "
                          f"second, got {fps!r}")
    return float(fps)


def sample_motion(ev: Evaluation, fps: float = DEFAULT_FPS) -> MotionSamples:
    """The clip's record resampled at `fps` (see the module's docstring)."""
    fps = check_fps(fps)
    if ev.states is None or ev.traces is None or len(ev.states.t) == 0:
        raise ExportError("the clip was not recorded (simulate it with traces=True)")
    q = np.array(ev.states.q, dtype=float)
    q[:, 2:] = np.unwrap(q[:, 2:], axis=0)  # angles continuous before they are interpolated
    n = len(q)
    # Frame i at step s = i x 1000 / fps; frames up to the last recorded state (step n - 1).
    count = int(math.floor((n - 1) * fps / STEPS_PER_SECOND + 1e-9)) + 1
    s = np.arange(count) * (STEPS_PER_SECOND / fps)
    whole = np.abs(s - np.round(s)) < 1e-9
    s[whole] = np.round(s[whole])
    k0 = np.minimum(np.floor(s).astype(int), n - 1)
    k1 = np.minimum(k0 + 1, n - 1)
    w = (s - k0)[:, None]
    cm = np.asarray(ev.traces.cm, dtype=float)
    # The CP of the step that ends at the frame's time (none at t = 0), as the replay shows it.
    rows = np.round(s).astype(int) - 1
    cp = np.asarray(ev.traces.cp, dtype=float)
    cop = np.array([cp[k] if 0 <= k < len(cp) else math.nan for k in rows])
    return MotionSamples(fps=fps, t=np.arange(count) / fps, q=(1 - w) * q[k0] + w * q[k1],
                         cm=(1 - w) * cm[k0] + w * cm[k1], cop=cop)


def bvh_names(ch: Character) -> list[str]:
    """The segments' names as BVH joint names: white space and other characters a BVH reader
    may not take become `_`; a clash gets `_2`, `_3`, ..."""
    out: list[str] = []
    for b, name in enumerate(ch.body_names):
        base = _NAME_OK.sub("_", name) or f"segment{b}"
        cand, k = base, 2
        while cand in out:
            cand, k = f"{base}_{k}", k + 1
        out.append(cand)
    return out


def end_site(ch: Character, b: int) -> np.ndarray:
    """A leaf segment's End Site in the zero pose (m): its point farthest from its anchor among
    its outline points, heel and toe, and geoms' ends (its CoM when it has none of them)."""
    pts = [ch.point0[i] for i in np.flatnonzero(ch.point_body == b)]
    for f, foot in enumerate(ch.feet):
        if foot == b:
            pts += [ch.heel0[f], ch.toe0[f]]
    for g in ch.geoms:
        if g.body == b:
            pts += [np.asarray(g.a), np.asarray(g.b)]
    if not pts:
        return np.asarray(ch.com0[b], dtype=float)
    anchor = ch.anchor0[b]
    dist = [float(np.hypot(*(np.asarray(p) - anchor))) for p in pts]
    return np.asarray(pts[int(np.argmax(dist))], dtype=float)


def _num(v: float, digits: int) -> str:
    out = f"{v:.{digits}g}"
    return "0" if out in ("0", "-0") else out


def _hierarchy(ch: Character) -> tuple[list[str], list[int]]:
    """The HIERARCHY section's lines and the segments in its (depth-first) order."""
    names = bvh_names(ch)
    children = {b: [c for c in range(ch.n_bodies) if ch.parent[c] == b]
                for b in range(ch.n_bodies)}
    root = 0  # sim.character: the root is body 0, body b > 0 hangs on hinge b - 1
    lines = ["HIERARCHY"]
    order: list[int] = []

    def offset(v: np.ndarray) -> str:
        return " ".join(_num(float(x), POSITION_DIGITS) for x in (v[0], v[1], 0.0))

    def joint(b: int, depth: int) -> None:
        pad = "  " * depth
        order.append(b)
        if b == root:
            lines.append(f"ROOT {names[b]}")
            lines.append("{")
            lines.append(f"{pad}  OFFSET 0 0 0")
            lines.append(f"{pad}  CHANNELS 6 Xposition Yposition Zposition Zrotation "
                         "Xrotation Yrotation")
        else:
            lines.append(f"{pad}JOINT {names[b]}")
            lines.append(f"{pad}{{")
            lines.append(f"{pad}  OFFSET {offset(ch.anchor0[b] - ch.anchor0[ch.parent[b]])}")
            lines.append(f"{pad}  CHANNELS 3 Zrotation Xrotation Yrotation")
        for c in children[b]:
            joint(c, depth + 1)
        if not children[b]:
            lines.extend([f"{pad}  End Site", f"{pad}  {{",
                          f"{pad}    OFFSET {offset(end_site(ch, b) - ch.anchor0[b])}",
                          f"{pad}  }}"])
        lines.append(f"{pad}}}")

    joint(root, 0)
    return lines, order


def bvh_text(ch: Character, m: MotionSamples) -> str:
    """The BVH file of the samples `m` of a clip of character `ch` (module docstring)."""
    if m.q.shape[1] != ch.ndof:
        raise ExportError(f"the clip has {m.q.shape[1]} coordinates, character "
                          f"{ch.name!r} {ch.ndof}")
    lines, order = _hierarchy(ch)
    lines += ["MOTION", f"Frames: {len(m.t)}",
              f"Frame Time: {_num(1.0 / m.fps, POSITION_DIGITS)}"]
    deg = np.degrees(m.q[:, ROOT_DOF - 1:])  # root angle, then the hinges
    for i in range(len(m.t)):
        row = [_num(m.q[i, 0], POSITION_DIGITS), _num(m.q[i, 1], POSITION_DIGITS), "0"]
        for b in order:
            # column b of `deg`: the root's angle (b = 0) or hinge b - 1, body b's own
            row += [_num(deg[i, b], ANGLE_DIGITS), "0", "0"]
        lines.append(" ".join(row))
    return "\n".join(lines) + "\n"


def csv_columns(ch: Character) -> list[str]:
    """The CSV header: t, root_x, root_y, root_angle, the hinges by name, cm_x, cm_y, cop_x (a
    hinge named like another column gets `_2`, ...)."""
    cols = ["t", "root_x", "root_y", "root_angle"]
    for name in ch.hinge_names:
        cand, k = name, 2
        while cand in cols or cand in ("cm_x", "cm_y", "cop_x"):
            cand, k = f"{name}_{k}", k + 1
        cols.append(cand)
    return cols + ["cm_x", "cm_y", "cop_x"]


def csv_text(ch: Character, m: MotionSamples) -> str:
    """The CSV table of the samples `m` (module docstring; angles in degrees)."""
    if m.q.shape[1] != ch.ndof:
        raise ExportError(f"the clip has {m.q.shape[1]} coordinates, character "
                          f"{ch.name!r} {ch.ndof}")
    out = io.StringIO()
    w = csv.writer(out, lineterminator="\n")
    w.writerow(csv_columns(ch))
    deg = np.degrees(m.q[:, ROOT_DOF - 1:])
    P, A = POSITION_DIGITS, ANGLE_DIGITS
    for i in range(len(m.t)):
        cop = "" if not math.isfinite(m.cop[i]) else _num(m.cop[i], P)
        w.writerow([_num(m.t[i], P), _num(m.q[i, 0], P), _num(m.q[i, 1], P),
                    *(_num(a, A) for a in deg[i]),
                    _num(m.cm[i, 0], P), _num(m.cm[i, 1], P), cop])
    return out.getvalue()


def export_text(ch: Character, ev: Evaluation, fmt: str, fps: float = DEFAULT_FPS) -> str:
    """The clip as `fmt` ("bvh" or "csv") at `fps`."""
    if fmt not in FORMATS:
        raise ExportError(f"format: must be one of {', '.join(FORMATS)}, got {fmt!r}")
    m = sample_motion(ev, fps)
    return bvh_text(ch, m) if fmt == "bvh" else csv_text(ch, m)
