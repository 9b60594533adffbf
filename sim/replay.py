"""The replay document: one or more recorded clips of a spec as compact, versioned JSON.

`build_replay(spec, [ReplayClip(...), ...])` turns evaluations recorded with `traces=True`
(their `Frames` at 100 Hz and 1 kHz `Traces`) into the document a player draws
(`service/static/replay/`, schema in docs/replay.md): the character's segment shapes to scale
(body-local capsules, circles and foot polygons taken from the character file's `points`,
`foot` and `geoms`), the props' shapes, and per clip the per-frame poses, CM, CM reference,
CP, support edges and the plot traces at frame rate (CP error e(t), CMRT displacement, CM x
against the reference), with the clip's outcome (objective, fall time and direction, task
success) and its motion as BVH and CSV text (`sim.export`, for the player's downloads). Pure:
no I/O, no ODE.

Body-local coordinates: a body's frame has its origin at the body's CoM and is parallel to the
world frame in the zero pose, so a local point p is drawn at (x, y) + R(angle) p for the
body's pose (x, y, angle) of a frame.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from sim.character import Character
from sim.clip_result import Evaluation
from sim.export import DEFAULT_FPS, export_text
from sim.physics import DT
from sim.props import PropDef

#: Version of the document's layout; bumped on any incompatible change (docs/replay.md).
SCHEMA = "cmrt-replay/1"
#: Decimals kept for positions (m) and angles (rad): 1e-4 m = 0.1 mm, 1e-4 rad.
POSE_DECIMALS = 4
#: Decimals of the shapes (m): 0.01 mm, so a shape is the file's to well below a pixel.
SHAPE_DECIMALS = 5
#: Decimals of the plotted traces (m): 0.01 mm.
TRACE_DECIMALS = 5

Cmrt = Callable[[float], "float | tuple[float, float]"]


@dataclass(frozen=True)
class ReplayClip:
    """One clip to replay: its label, its recorded evaluation (run with traces=True), the CMRT
    it ran with (None: no anticipation, the flat spline) and what that CMRT is (free JSON)."""

    label: str
    evaluation: Evaluation
    cmrt: Cmrt | None = None
    about: dict[str, Any] | None = None


def _r(v: float | None, d: int) -> float | None:
    if v is None or not math.isfinite(v):
        return None
    out = round(float(v), d)
    return 0.0 if out == 0.0 else out  # no "-0.0" in the document


def _pt(p: Sequence[float], origin: np.ndarray) -> list[float]:
    return [_r(p[0] - origin[0], SHAPE_DECIMALS), _r(p[1] - origin[1], SHAPE_DECIMALS)]


def segment_shapes(ch: Character) -> list[dict[str, Any]]:
    """Each body's shapes in its local frame (m), from the character file: a capsule from the
    body's hinge anchor (the root: its first point) to each of its `points` and on to each
    child's hinge anchor, with that point's radius (a child anchor: the radius of the body's
    last point) as `{"kind": "capsule", "a", "ra", "b", "rb"}`; a foot's heel, toe and ankle
    as a polygon (`"role": "foot"`); its geoms as capsules and circles (`"geom"`: the geom's
    name, or None)."""
    out = []
    for b, name in enumerate(ch.body_names):
        com = ch.com0[b]
        shapes: list[dict[str, Any]] = []
        pts = [(ch.point0[i], float(ch.point_radius[i]))
               for i in np.flatnonzero(ch.point_body == b)]
        hub = ch.anchor0[b] if ch.parent[b] >= 0 else (pts[0][0] if pts else com)
        r_last = pts[-1][1] if pts else 0.0
        targets = list(pts) + [(ch.anchor0[c], r_last) for c in np.flatnonzero(ch.parent == b)]
        seen = [np.asarray(hub)]
        for p, r in targets:
            if any(float(np.hypot(*(p - q))) < 1e-9 for q in seen):
                continue  # a point at the hub or a child anchor already reached
            seen.append(np.asarray(p))
            shapes.append({"kind": "capsule", "a": _pt(hub, com), "ra": _r(r, SHAPE_DECIMALS),
                           "b": _pt(p, com), "rb": _r(r, SHAPE_DECIMALS)})
        if not shapes and pts:
            shapes.append({"kind": "circle", "c": _pt(hub, com),
                           "r": _r(max(r for _, r in pts), SHAPE_DECIMALS)})
        feet = list(ch.feet)
        if b in feet:
            f = feet.index(b)
            shapes.append({"kind": "polygon", "role": "foot",
                           "points": [_pt(ch.heel0[f], com), _pt(ch.toe0[f], com),
                                      _pt(ch.anchor0[b], com)]})
        for g in ch.geoms:
            if g.body != b:
                continue
            if g.shape == "sphere":
                shapes.append({"kind": "circle", "c": _pt(g.a, com),
                               "r": _r(g.radius, SHAPE_DECIMALS), "geom": g.name})
            else:
                shapes.append({"kind": "capsule", "a": _pt(g.a, com), "b": _pt(g.b, com),
                               "ra": _r(g.radius, SHAPE_DECIMALS),
                               "rb": _r(g.radius, SHAPE_DECIMALS), "geom": g.name})
        out.append({"name": name, "shapes": shapes})
    return out


def prop_shapes(props: Sequence[PropDef]) -> list[dict[str, Any]]:
    """Each prop as drawn: shape and size (m, as `sim.props`: box (w, h), sphere (r,), capsule
    (r, length along local y)), mass, and its hanging anchor and chain links if any."""
    out = []
    for p in props:
        d: dict[str, Any] = {"name": p.name, "shape": p.shape,
                             "size": [_r(s, SHAPE_DECIMALS) for s in p.size], "mass": p.mass,
                             "hanging": None}
        if p.hanging is not None:
            d["hanging"] = {"anchor": [_r(v, SHAPE_DECIMALS) for v in p.hanging.anchor],
                            "links": [f"{p.name}.link{k}" for k in range(p.hanging.links)]}
        out.append(d)
    return out


def _cmrt_xy(cmrt: Cmrt | None, ts: Sequence[float]) -> tuple[list[float], list[float]]:
    if cmrt is None:
        return [0.0] * len(ts), [0.0] * len(ts)
    dx, dy = [], []
    for t in ts:
        v = cmrt(t)
        x, y = (v, 0.0) if isinstance(v, int | float) else (v[0], v[1])
        dx.append(_r(x, TRACE_DECIMALS))
        dy.append(_r(y, TRACE_DECIMALS))
    return dx, dy


def clip_document(clip: ReplayClip, ch: Character) -> dict[str, Any]:
    """One clip's part of the document (see docs/replay.md, "clips"); `ch` is the clip's
    character (its motion files, `sim.export`, are part of the document)."""
    ev = clip.evaluation
    fr = ev.frames
    if fr is None or ev.traces is None:
        raise ValueError(f"clip {clip.label!r}: the evaluation was not recorded (traces=True)")
    P, Tr = POSE_DECIMALS, TRACE_DECIMALS
    ts = [_r(t, 6) for t in fr.t]
    # The 1 kHz trace row that ends at a frame's time: the CP error the frame shows.
    err = ev.traces.error
    rows = [int(round(t / DT)) - 1 for t in fr.t]
    error = [None if k < 0 or k >= len(err) else _r(err[k], Tr) for k in rows]
    dx, dy = _cmrt_xy(clip.cmrt, fr.t)
    return {
        "label": clip.label,
        "cmrt": clip.about,
        "outcome": {
            "objective": _r(ev.objective, 6), "fell": ev.fell,
            "fall_time": _r(ev.fall_time, 6) if ev.fall_time is not None else None,
            "fall_reason": ev.fall_reason, "fall_direction": ev.fall_direction,
            "task_success": ev.task_success, "error_norm": _r(ev.error_norm, 6),
            "max_abs_error": _r(ev.max_abs_error, 6), "sim_seconds": _r(ev.sim_seconds, 6),
        },
        "frames": len(fr.t),
        "t": ts,
        "poses": [[_r(v, P) for pose in row for v in pose] for row in fr.poses],
        "cm": [[_r(x, P), _r(y, P)] for x, y in fr.cm],
        "cm_ref": [[_r(x, P), _r(y, P)] for x, y in fr.cm_ref],
        "cp": [_r(v, P) if v is not None else None for v in fr.cp],
        "support": [[_r(a, P), _r(b, P)] for a, b in fr.support],
        "plots": {
            "error": error,
            "cmrt_dx": dx,
            "cmrt_dy": dy,
            "cm_x": [_r(x, Tr) for x, _ in fr.cm],
            "cm_ref_x": [_r(x, Tr) for x, _ in fr.cm_ref],
        },
        # The files a user downloads from the player: what `cmrt simulate --export` writes.
        "motion": {"fps": DEFAULT_FPS, "bvh": export_text(ch, ev, "bvh", DEFAULT_FPS),
                   "csv": export_text(ch, ev, "csv", DEFAULT_FPS)},
    }


def build_replay(spec: Any, clips: Sequence[ReplayClip]) -> dict[str, Any]:
    """The replay document of `clips` (all of the same TaskSpec `spec`), schema `SCHEMA`."""
    if not clips:
        raise ValueError("a replay needs at least one clip")
    ch = spec.load_character()
    props = spec.task.build(spec, ch).props
    names = clips[0].evaluation.frames.names if clips[0].evaluation.frames else []
    rate = clips[0].evaluation.frames.rate if clips[0].evaluation.frames else None
    c = spec.clip
    return {
        "schema": SCHEMA,
        "spec": {"name": spec.name, "family": spec.family_name, "task_type": spec.task_type,
                 "task_parameters": spec.task_parameters(),
                 "clip": {"preparation": c.preparation, "duration": c.duration,
                          "decay": c.decay, "length": c.length,
                          "task_start": c.task_start, "task_end": c.task_end}},
        "rate": rate,
        "character": {"name": ch.name, "height": ch.height,
                      "segments": segment_shapes(ch)},
        "props": prop_shapes(props),
        "bodies": list(names),
        "clips": [clip_document(k, ch) for k in clips],
    }
