"""A BVH clip as a `motion` task spec: the clip's 3-D pose projected onto the sagittal plane by
bone directions, mapped onto a character's hinges, resampled, kept inside the joint limits.

    cmrt motion import CLIP.bvh --character humanoid [--map MAP.yaml] [--start S --end E]
                       [--rate FPS] --out motion.yaml

How (docs/motion.md):
1. Forward kinematics gives every joint's world position at every frame of the section
   (`sim.bvh`), and in the rest pose (every channel 0).
2. The sagittal plane: its normal is the line from the map's left to its right joint (the hip
   joints), made level, at the first frame of the section; forward is up x that normal. A map
   may instead fix the file's XY plane (`plane: xy`: BVH's Z is the planar axis), as the
   identity map of a file written by `sim.export` does.
3. Each mapped segment has a bone (from one joint, or the mean of several, to another, or to an
   End Site); its sagittal angle is atan2 of its direction's up and forward components.
4. A hinge's angle is the child bone's sagittal angle minus the parent's, minus the same in
   the rest pose, so that the rest pose is the character's zero pose. Where the rest pose holds
   a bone out of the plane (a T-pose's arms), the hinge's zero is the character's own zero
   pose instead (its segments' directions from `sim.character`). Angles are unwrapped in time.
5. The angles are low-pass filtered (zero phase, 6 Hz by default: a clip's jitter would be
   hundreds of rad/s^2 in the spline's acceleration), resampled at the chosen rate (linear
   between the clip's frames), the legs averaged left and right so that both feet stay planted
   (a planar character stands only if its legs agree), clipped to the character's joint limits
   (reported: which joint, how many frames, by how much), and written relative to the standing
   pose, as every task's pose targets.

Maps: the identity map when the file's joints carry the character's segment names (what
`sim.export` writes), else the built-in maps of `sim/data/maps/` (CMU, Mixamo) that the file's
joint names match, else a map file (`--map`, the same form). Untrusted input: `sim.bvh`'s
bounds, a map file's size and form, and every problem one `MotionImportError` or `BvhError`
naming the file and the field or line.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from cmrt.specfile import SpecReadError, read_document
from sim.bvh import BvhClip, read_bvh
from sim.character import DATA_DIR, DEFAULT_CHARACTER, Character, load_character
from sim.errors import SimError
from sim.export import bvh_names, end_site
from sim.tasks.base import MAX_CLIP_SECONDS, MAX_TARGET_DEGREES
from sim.tasks.motion import MAX_FRAMES, MAX_RATE

#: The built-in maps (one YAML file each).
MAPS_DIR = DATA_DIR / "maps"
#: Largest map file (bytes).
MAX_MAP_BYTES = 100_000
#: Frames per second written when none is asked for (the clip's own if lower): enough for a
#: body's motion, half the size of 120 Hz mocap.
DEFAULT_RATE = 60.0
#: A bone whose sagittal projection is shorter than this fraction of its length (more than
#: 60 degrees out of the plane) has an unreliable sagittal angle: reported.
MIN_PROJECTION = 0.5
#: Degrees the left-right line may turn over the section before the report warns.
MAX_TURN_DEGREES = 30.0
#: Seconds before the motion (where a CMRT anticipates it) and after it, in the written spec.
PREPARATION_SECONDS = 1.0
DECAY_SECONDS = 1.0
#: Decimals of the written angles (degrees): 1e-6 degrees is 2e-8 rad.
ANGLE_DECIMALS = 6
#: Hz: the default low-pass cutoff, the usual one for human movement kinematics. A clip's
#: frame-to-frame jitter becomes accelerations of hundreds of rad/s^2 in the spline's
#: second derivative, which the controller takes as a feed-forward; filtered, the reference
#: keeps the motion (the report gives the largest change) without the jitter.
DEFAULT_CUTOFF = 6.0
#: Order of the Butterworth filter (run forward and backward: zero phase, twice the order).
FILTER_ORDER = 2

_SPEC_NAME = re.compile(r"[^A-Za-z0-9_.\-]")


class MotionImportError(SimError, ValueError):
    """A clip that cannot be imported as asked (a bad map, section or rate); the message names
    the file and the field."""


@dataclass(frozen=True)
class SkeletonMap:
    """Which bone of the clip each character segment follows: segment -> (from, to), each end a
    tuple of joint names (their mean) or one `JOINT/end` (its End Site). `plane`: the (left,
    right) joints whose line is the sagittal plane's normal, or None for the file's XY plane;
    `up`: the file's vertical axis (0 X, 1 Y, 2 Z)."""

    name: str
    segments: dict[str, tuple[tuple[str, ...], tuple[str, ...]]]
    plane: tuple[str, str] | None = None
    up: int = 1
    detect: tuple[str, ...] = ()
    #: "rest": each hinge's zero is its angle in the file's rest pose (every channel 0);
    #: "character": the character's zero pose, for files whose rest pose is no pose at all.
    zero: str = "rest"


def parse_map(data: Any, source: str) -> SkeletonMap:
    """A map from its YAML mapping (form: sim/data/maps/cmu.yaml); MotionImportError naming
    the field."""
    def bad(where: str, rule: str) -> MotionImportError:
        return MotionImportError(f"{source}: {where}: {rule}")

    if not isinstance(data, dict):
        raise bad("map", "must be a mapping with `segments`")
    unknown = set(data) - {"name", "detect", "plane", "up", "zero", "segments"}
    if unknown:
        raise bad(sorted(unknown)[0], "unknown field; fields are name, detect, plane, up, "
                  "zero, segments")
    zero = data.get("zero", "rest")
    if zero not in ("rest", "character"):
        raise bad("zero", f"must be rest or character, got {zero!r}")
    segs = data.get("segments")
    if not isinstance(segs, dict) or not segs or len(segs) > 256:
        raise bad("segments", "must map 1 to 256 segment names to [from, to] bones")
    out: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {}
    for seg, bone in segs.items():
        if not isinstance(bone, list) or len(bone) != 2:
            raise bad(f"segments.{seg}", "must be [from, to]: each a joint name, a list of "
                      "joint names (their mean) or JOINT/end (its End Site)")
        out[str(seg)] = (_end(bone[0], bad, f"segments.{seg}.0"),
                         _end(bone[1], bad, f"segments.{seg}.1"))
    plane = data.get("plane", "xy")
    if plane == "xy":
        sides = None
    elif isinstance(plane, dict) and set(plane) == {"left", "right"} and all(
            isinstance(v, str) and v for v in plane.values()):
        sides = (plane["left"], plane["right"])
    else:
        raise bad("plane", "must be xy or {left: JOINT, right: JOINT}")
    up = data.get("up", "y")
    if up not in ("x", "y", "z"):
        raise bad("up", f"must be x, y or z, got {up!r}")
    detect = data.get("detect", [])
    if not isinstance(detect, list) or not all(isinstance(d, str) for d in detect):
        raise bad("detect", "must be a list of joint names")
    return SkeletonMap(str(data.get("name", Path(source).stem)), out, sides, "xyz".index(up),
                       tuple(detect), zero)


def _end(value: Any, bad: Any, where: str) -> tuple[str, ...]:
    names = value if isinstance(value, list) else [value]
    if not names or len(names) > 16 or not all(isinstance(n, str) and 0 < len(n) <= 140
                                               for n in names):
        raise bad(where, "must be a joint name or a list of 1 to 16 joint names")
    if len(names) > 1 and any(n.endswith("/end") for n in names):
        raise bad(where, "an End Site (JOINT/end) stands alone, not in a list")
    return tuple(names)


def load_map(path: str | Path) -> SkeletonMap:
    """A map file (YAML), bounded in size."""
    try:
        data = read_document(path, "the map", MAX_MAP_BYTES)
    except SpecReadError as err:
        raise MotionImportError(str(err)) from None
    return parse_map(data, str(path))


def builtin_maps() -> list[SkeletonMap]:
    """The maps of sim/data/maps/, by name."""
    return [load_map(p) for p in sorted(MAPS_DIR.glob("*.yaml"))]


def identity_map(character: Character, clip: BvhClip) -> SkeletonMap | None:
    """The map of a file whose joints carry the character's segment names (as `sim.export`
    writes them), in the file's XY plane; None if some segment is missing."""
    names = bvh_names(character)
    have = set(clip.names)
    if not all(n in have for n in names):
        return None
    segments = {}
    for seg, n in zip(character.body_names, names, strict=True):
        i = clip.index(n)
        kids = clip.children(i)
        # The bone: to the child joint farthest away, else to the End Site.
        if kids:
            far = max(kids, key=lambda k: float(np.linalg.norm(clip.joints[k].offset)))
            segments[seg] = ((n,), (clip.joints[far].name,))
        else:
            segments[seg] = ((n,), (f"{n}/end",))
    return SkeletonMap("identity", segments, None, 1)


def choose_map(clip: BvhClip, character: Character, path: str | Path | None) -> SkeletonMap:
    """The map file if given, else the identity map, else the first built-in map whose
    `detect` joints the clip has; MotionImportError if none fits."""
    if path is not None:
        return load_map(path)
    same = identity_map(character, clip)
    if same is not None:
        return same
    have = set(clip.names)
    for m in builtin_maps():
        if m.detect and all(d in have for d in m.detect):
            return m
    raise MotionImportError(
        f"{clip.source}: its skeleton ({', '.join(clip.names[:12])}"
        f"{' ...' if len(clip.names) > 12 else ''}) is none the built-in maps know "
        f"({', '.join(m.name for m in builtin_maps())}) nor the character's own; give a map "
        "file with --map (docs/motion.md)")


@dataclass
class SagittalAngles:
    """The clip's hinge angles (rad, relative to the character's zero pose, unwrapped) at its
    frames `first` .. `last`, and what the projection noticed."""

    hinges: list[str]
    angles: np.ndarray  # (frames, hinges)
    out_of_plane: dict[str, int] = field(default_factory=dict)  # hinge -> frames
    zero_from_character: list[str] = field(default_factory=list)
    turn_degrees: float = 0.0
    unmapped: list[str] = field(default_factory=list)


def _point(clip: BvhClip, pos: np.ndarray, ends: np.ndarray, ref: tuple[str, ...],
           where: str) -> np.ndarray:
    """(F, 3) positions of a bone end: the mean of joints, or one joint's End Site."""
    if len(ref) == 1 and ref[0].endswith("/end"):
        i = clip.index(ref[0][:-4])
        if clip.joints[i].end_site is None:
            raise MotionImportError(f"{clip.source}: {where}: joint {ref[0][:-4]!r} has no "
                                    "End Site")
        return ends[:, i]
    try:
        idx = [clip.index(n) for n in ref]
    except SimError as err:
        raise MotionImportError(f"{where}: {err}") from None
    return pos[:, idx].mean(axis=1)


def _axes(clip: BvhClip, smap: SkeletonMap, pos: np.ndarray) -> tuple[np.ndarray, np.ndarray,
                                                                       np.ndarray]:
    """(forward, up, lateral) unit vectors per frame (F, 3) each; lateral points to the
    character's right, so that (forward, up, lateral) is right-handed like BVH's (X, Y, Z)."""
    n = pos.shape[0]
    up = np.zeros(3)
    up[smap.up] = 1.0
    if smap.plane is None:
        lateral = np.zeros((n, 3))
        lateral[:, (smap.up + 1) % 3] = 1.0  # y up: Z; z up: X (a right-handed turn)
    else:
        left, right = (clip.index(s) for s in smap.plane)
        line = pos[:, right] - pos[:, left]
        line = line - np.outer(line @ up, up)
        size = np.linalg.norm(line, axis=1)
        if np.any(size < 1e-9 * (1.0 + np.abs(pos).max())):
            raise MotionImportError(f"{clip.source}: plane: the line from {smap.plane[0]!r} "
                                    f"to {smap.plane[1]!r} is vertical or empty")
        lateral = line / size[:, None]
    forward = np.cross(np.broadcast_to(up, lateral.shape), lateral)
    return forward, np.broadcast_to(up, lateral.shape), lateral


def _bone_angles(clip: BvhClip, smap: SkeletonMap, pos: np.ndarray, ends: np.ndarray,
                 axes: tuple[np.ndarray, np.ndarray, np.ndarray], segments: list[str]
                 ) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """Per segment: its bone's sagittal angle (F,) in the given axes (each frame's, or the
    first frame's for all) and the fraction of its length that lies in the plane (F,)."""
    forward, up, _ = axes
    angle, inplane = {}, {}
    for seg in segments:
        a_ref, b_ref = smap.segments[seg]
        d = (_point(clip, pos, ends, b_ref, f"segments.{seg}.1")
             - _point(clip, pos, ends, a_ref, f"segments.{seg}.0"))
        x = np.einsum("fa,fa->f", d, forward)
        y = np.einsum("fa,fa->f", d, up)
        length = np.linalg.norm(d, axis=1)
        if np.any(length <= 0.0):
            raise MotionImportError(f"{clip.source}: segments.{seg}: the bone from "
                                    f"{'+'.join(a_ref)} to {'+'.join(b_ref)} has no length")
        angle[seg] = np.arctan2(y, x)
        inplane[seg] = np.hypot(x, y) / length
    return angle, inplane


def character_bone_angles(character: Character) -> np.ndarray:
    """Each segment's direction in the character's zero pose (rad, counter-clockwise from
    forward): from its anchor (the root: its CoM) to its farthest child anchor, a leaf's to
    its End Site as `sim.export` writes it."""
    out = np.empty(character.n_bodies)
    for b in range(character.n_bodies):
        a = character.anchor0[b]
        kids = [c for c in range(character.n_bodies) if character.parent[c] == b]
        tips = [character.anchor0[c] for c in kids] or [end_site(character, b)]
        d = max((np.asarray(t) - a for t in tips), key=lambda v: float(np.hypot(*v)))
        out[b] = math.atan2(d[1], d[0])
    return out


def _wrap(a: np.ndarray) -> np.ndarray:
    return (a + np.pi) % (2.0 * np.pi) - np.pi


def sagittal_angles(clip: BvhClip, character: Character, smap: SkeletonMap, first: int,
                    last: int) -> SagittalAngles:
    """The hinge angles of frames first..last (module docstring, steps 1-4)."""
    unknown = [s for s in smap.segments if s not in character.body_names]
    if unknown:
        raise MotionImportError(f"map {smap.name}: segments.{unknown[0]}: character "
                                f"{character.name!r} has no segment {unknown[0]!r}; its "
                                f"segments are {', '.join(character.body_names)}")
    frames = np.arange(first, last + 1)
    pos, ends = clip.positions(frames)
    rpos, rends = clip.positions(rest=True)
    axes = _axes(clip, smap, pos[:1])
    axes = tuple(np.broadcast_to(a[0], (len(frames), 3)) for a in axes)
    lateral_all = _axes(clip, smap, pos)[2]
    turn = float(np.degrees(np.arccos(np.clip(lateral_all @ axes[2][0], -1.0, 1.0))).max())
    segs = list(smap.segments)
    ang, inplane = _bone_angles(clip, smap, pos, ends, axes, segs)
    rang, rinplane = _bone_angles(clip, smap, rpos, rends, _axes(clip, smap, rpos), segs)
    own = character_bone_angles(character)
    out = SagittalAngles([], np.zeros((len(frames), 0)), turn_degrees=turn)
    columns = []
    for j, hinge in enumerate(character.hinge_names):
        child = j + 1
        parent = int(character.parent[child])
        c, p = character.body_names[child], character.body_names[parent]
        if c not in smap.segments or p not in smap.segments:
            out.unmapped.append(hinge)
            continue
        if smap.zero == "rest" and min(rinplane[c][0], rinplane[p][0]) >= MIN_PROJECTION:
            zero = rang[c][0] - rang[p][0]
        else:  # the rest pose holds a bone out of the plane: the character's zero instead
            zero = own[child] - own[parent]
            if smap.zero == "rest":
                out.zero_from_character.append(hinge)
        columns.append(np.unwrap(_wrap(ang[c] - ang[p] - zero)))
        out.hinges.append(hinge)
        low = np.minimum(inplane[c], inplane[p]) < MIN_PROJECTION
        if low.any():
            out.out_of_plane[hinge] = int(low.sum())
    if not columns:
        raise MotionImportError(f"map {smap.name}: no hinge of character {character.name!r} "
                                "has both its segments mapped")
    out.angles = np.stack(columns, axis=1)
    return out


def _chosen(sag: SagittalAngles, joints: tuple[str, ...] | None) -> SagittalAngles:
    """Only the asked joints (each mapped), in the order of the character's hinges."""
    if joints is None:
        return sag
    for j in joints:
        if j not in sag.hinges:
            raise MotionImportError(f"--joints: {j!r} is not a mapped joint; mapped joints "
                                    f"are {', '.join(sag.hinges)}")
    cols = [k for k, h in enumerate(sag.hinges) if h in joints]
    left = [h for h in sag.hinges if h not in joints]
    return SagittalAngles([sag.hinges[k] for k in cols], sag.angles[:, cols],
                          {h: n for h, n in sag.out_of_plane.items() if h in joints},
                          [h for h in sag.zero_from_character if h in joints],
                          sag.turn_degrees, sag.unmapped + left)


@dataclass
class MotionImport:
    """An imported clip: the spec document, the report lines, and the numbers behind them."""

    spec: dict[str, Any]
    report: list[str]
    times: np.ndarray  # s, of the written frames
    angles: np.ndarray  # rad from the zero pose, before clipping (written frames x joints)
    clipped: dict[str, tuple[int, float]]  # joint -> (frames, largest excess in degrees)
    source_rate: float
    first: int
    last: int
    map_name: str
    legs_averaged: list[tuple[str, ...]] = field(default_factory=list)
    legs_spread: float = 0.0  # degrees: the largest difference the averaging removed
    filtered: tuple[float, float] = (0.0, 0.0)  # (cutoff Hz, largest change in degrees)
    #: A character given by its file: the spec's block as the command line inlines it.
    inline_character: dict[str, Any] | None = None

    def inline_spec(self) -> dict[str, Any]:
        """The spec as the command line reads it (a character file's definition inline)."""
        if self.inline_character is None:
            return self.spec
        return {**self.spec, "character": self.inline_character}


def _section(clip: BvhClip, start: float | None, end: float | None) -> tuple[int, int]:
    """First and last frame of the clip's section [start, end] s (default: all)."""
    duration = (clip.frames - 1) * clip.frame_time
    s = 0.0 if start is None else start
    e = duration if end is None else end
    for name, v in (("--start", s), ("--end", e)):
        if not math.isfinite(v) or not 0.0 <= v <= duration + 1e-9:
            raise MotionImportError(f"{name}: must be from 0 to the clip's {duration:g} s, "
                                    f"got {v:g}")
    # A frame within a hundredth of a frame of a bound is in: a file's Frame Time is rounded
    # (0.016667 for 60 Hz puts frame 150 at 2.50002 s).
    first = int(math.ceil(s / clip.frame_time - 1e-2))
    last = min(int(math.floor(e / clip.frame_time + 1e-2)), clip.frames - 1)
    if last - first < 1:
        raise MotionImportError(f"--start/--end: the section [{s:g}, {e:g}] s holds fewer "
                                "than 2 frames")
    return first, last


def _rate(clip: BvhClip, rate: float | None) -> float:
    own = 1.0 / clip.frame_time
    if abs(own - round(own)) < 1e-3 * own:
        own = float(round(own))  # a Frame Time written as 0.0083333 or 0.016667
    r = min(own, DEFAULT_RATE) if rate is None else rate
    if not math.isfinite(r) or not 1.0 <= r <= MAX_RATE:
        raise MotionImportError(f"--rate: must be from 1 to {MAX_RATE:g} frames per s, got "
                                f"{r:g}")
    return r


def resample(angles: np.ndarray, frame_time: float, rate: float) -> tuple[np.ndarray,
                                                                          np.ndarray]:
    """(times, angles) at `rate` over the section (linear between the clip's frames)."""
    duration = (angles.shape[0] - 1) * frame_time
    n = int(math.floor(duration * rate + 1e-6)) + 1
    times = np.arange(n) / rate
    src = np.arange(angles.shape[0]) * frame_time
    out = np.stack([np.interp(times, src, angles[:, k]) for k in range(angles.shape[1])],
                   axis=1)
    return times, out


def _clip_to_limits(character: Character, hinges: list[str], angles: np.ndarray
                    ) -> tuple[np.ndarray, dict[str, tuple[int, float]]]:
    """The angles inside the joints' limits, and per clipped joint (frames, largest excess in
    degrees)."""
    idx = [character.hinge_index(h) for h in hinges]
    lo, hi = character.limits[idx].T
    kept = np.clip(angles, lo, hi)
    clipped = {}
    for k, h in enumerate(hinges):
        excess = np.abs(angles[:, k] - kept[:, k])
        if (excess > 0).any():
            clipped[h] = (int((excess > 0).sum()), float(np.degrees(excess.max())))
    return kept, clipped


def low_pass(angles: np.ndarray, frame_time: float, cutoff: float) -> np.ndarray:
    """The angles (frames x hinges) low-pass filtered at `cutoff` Hz, zero phase (a
    Butterworth filter run forward and backward); as they are for cutoff 0 or a section too
    short to filter."""
    from scipy.signal import butter, filtfilt

    if cutoff <= 0.0:
        return angles
    nyquist = 0.5 / frame_time
    if cutoff >= nyquist:
        raise MotionImportError(f"--cutoff: must be below half the clip's frame rate "
                                f"({nyquist:g} Hz), got {cutoff:g}")
    b, a = butter(FILTER_ORDER, cutoff / nyquist)
    if angles.shape[0] <= 3 * max(len(a), len(b)):
        return angles
    return filtfilt(b, a, angles, axis=0, padtype="odd")


def leg_chains(character: Character) -> list[list[int]]:
    """Per foot, the hinges from the foot up to the root (ankle, knee, hip for a biped)."""
    chains = []
    for f in character.feet:
        chain, b = [], int(f)
        while b > 0:
            chain.append(b - 1)
            b = int(character.parent[b])
        chains.append(chain)
    return chains


def average_legs(character: Character, hinges: list[str], angles: np.ndarray
                 ) -> tuple[np.ndarray, list[tuple[str, ...]], float]:
    """The legs' angles averaged across the feet, hinge by hinge along their chains (a planar
    character stands on both feet only if its legs agree; a clip's subject may stand with its
    feet apart in depth): (angles, the averaged groups, their largest difference in degrees).
    Chains of different lengths, or not mapped, are left as they are."""
    chains = leg_chains(character)
    if len(chains) < 2 or len({len(c) for c in chains}) != 1:
        return angles, [], 0.0
    out = angles.copy()
    groups, spread = [], 0.0
    for level in range(len(chains[0])):
        names = [character.hinge_names[c[level]] for c in chains]
        if not all(n in hinges for n in names):
            continue
        cols = [hinges.index(n) for n in names]
        mean = angles[:, cols].mean(axis=1)
        spread = max(spread, float(np.degrees(np.ptp(angles[:, cols], axis=1).max())))
        out[:, cols] = mean[:, None]
        groups.append(tuple(names))
    return out, groups, spread


CHARACTER_FILE_SUFFIXES = (".yaml", ".yml", ".json")


def _character(character: str) -> tuple[Character, dict[str, Any], dict[str, Any] | None]:
    """A shipped character by name, or a character file (a name ending .yaml, .yml or .json,
    docs/characters.md): the character, the spec's `character` block (`{model: NAME}` or
    `{file: PATH}`) and, for a file, the block as the command line inlines it."""
    if Path(character).suffix not in CHARACTER_FILE_SUFFIXES:
        return load_character(character), {"model": character}, None
    from sim.spec import CharacterRef

    try:
        data = read_document(character, "the character file")
    except SpecReadError as err:
        raise MotionImportError(f"--character: {err}") from None
    inline: dict[str, Any] = {"definition": data}
    stem = Path(character).stem
    if re.fullmatch(r"[a-z0-9_]{1,64}", stem):  # as the command line names it (cmrt.specfile)
        inline["model"] = stem
    try:
        ref = CharacterRef.model_validate(inline)
    except ValueError as err:
        msg = str(err).splitlines()
        raise MotionImportError(f"--character: {character}: {' '.join(msg[1:3]).strip()}"
                                ) from None
    return ref.load(), {"file": character}, inline


@dataclass(frozen=True)
class ImportOptions:
    """What `cmrt motion import` may choose: the section (s of the clip), the rate written,
    the low-pass cutoff (Hz, 0: none), the legs ("average": both feet stay planted,
    `average_legs`; "each": as the clip has them), the joints written (default: every
    mapped one) and the spec's name."""

    start: float | None = None
    end: float | None = None
    rate: float | None = None
    cutoff: float = DEFAULT_CUTOFF
    legs: str = "average"
    joints: tuple[str, ...] | None = None
    name: str | None = None


def import_motion(path: str | Path, character: str | None = None,
                  map_path: str | Path | None = None,
                  options: ImportOptions = ImportOptions()) -> MotionImport:
    """A BVH clip as a `motion` task spec for `character` (a shipped name or a character file;
    None: the package's default character) (module docstring)."""
    character = DEFAULT_CHARACTER if character is None else character
    o = options
    if o.legs not in ("average", "each"):
        raise MotionImportError(f"--legs: must be average or each, got {o.legs!r}")
    if not math.isfinite(o.cutoff) or o.cutoff < 0.0:
        raise MotionImportError(f"--cutoff: must be 0 (none) or a positive number of Hz, got "
                                f"{o.cutoff:g}")
    clip = read_bvh(path)
    ch, block, inline = _character(character)
    smap = choose_map(clip, ch, map_path)
    first, last = _section(clip, o.start, o.end)
    r = _rate(clip, o.rate)
    sag = _chosen(sagittal_angles(clip, ch, smap, first, last), o.joints)
    filtered = low_pass(sag.angles, clip.frame_time, o.cutoff)
    change = float(np.degrees(np.abs(filtered - sag.angles).max()))
    times, angles = resample(filtered, clip.frame_time, r)
    groups: list[tuple[str, ...]] = []
    spread = 0.0
    written = angles
    if o.legs == "average":
        written, groups, spread = average_legs(ch, sag.hinges, angles)
    seconds = float(times[-1])
    limit = MAX_CLIP_SECONDS - PREPARATION_SECONDS - DECAY_SECONDS
    if seconds > limit or len(times) > MAX_FRAMES:
        raise MotionImportError(f"--start/--end: the section lasts {seconds:g} s ("
                                f"{len(times)} frames); a motion lasts at most {limit:g} s "
                                f"and {MAX_FRAMES} frames")
    kept, clipped = _clip_to_limits(ch, sag.hinges, written)
    idx = [ch.hinge_index(h) for h in sag.hinges]
    rel = np.degrees(kept - ch.standing_offsets[idx])
    if np.abs(rel).max() > MAX_TARGET_DEGREES:
        raise MotionImportError(f"character {character!r}: a joint's limit lies more than "
                                f"{MAX_TARGET_DEGREES:g} degrees from its standing pose")
    stem = o.name or _SPEC_NAME.sub("_", Path(path).stem)[:80] or "motion"
    rounded = np.round(rel, ANGLE_DECIMALS) + 0.0  # + 0.0: no -0.0 in the file
    spec = {
        "name": stem,
        "character": block,
        "clip": {"preparation": PREPARATION_SECONDS, "duration": round(seconds, 9),
                 "decay": DECAY_SECONDS},
        "task": {"type": "motion", "rate": r, "start": PREPARATION_SECONDS,
                 "joints": list(sag.hinges),
                 "frames": [[float(v) for v in row] for row in rounded]},
    }
    out = MotionImport(spec, [], times, angles, clipped, 1.0 / clip.frame_time, first, last,
                       smap.name, groups, spread, (o.cutoff, change), inline)
    out.report = _report(clip, smap, sag, out, ch)
    return out


def _report(clip: BvhClip, smap: SkeletonMap, sag: SagittalAngles, imp: MotionImport,
            ch: Character) -> list[str]:
    """What the import did, one line each (printed by the command line)."""
    dt = clip.frame_time
    n = len(imp.times)
    plane = ("the file's XY plane" if smap.plane is None else
             f"normal to {smap.plane[0]} -> {smap.plane[1]} at frame {imp.first}")
    lines = [f"clip: {Path(clip.source).name}: frames {imp.first}-{imp.last} of {clip.frames} "
             f"at {1.0 / dt:g} Hz ({imp.first * dt:g}-{imp.last * dt:g} s); map "
             f"{smap.name}; sagittal plane {plane}",
             f"motion: {len(sag.hinges)} joints ({', '.join(sag.hinges)}), {n} frames at "
             f"{imp.spec['task']['rate']:g} per s ({imp.times[-1]:g} s) from "
             f"{PREPARATION_SECONDS:g} s of the clip"]
    if smap.plane is not None:
        warn = " (more than the plane can follow: check the result)" if (
            sag.turn_degrees > MAX_TURN_DEGREES) else ""
        lines.append(f"turn: the left-right line turns up to {sag.turn_degrees:.1f} degrees "
                     f"over the section{warn}")
    if imp.filtered[0] > 0.0:
        lines.append(f"filter: {imp.filtered[0]:g} Hz low-pass (zero phase); it changed the "
                     f"angles by up to {imp.filtered[1]:.2f} degrees (--cutoff 0: none)")
    if imp.legs_averaged:
        lines.append(f"legs: {', '.join('/'.join(g) for g in imp.legs_averaged)} averaged so "
                     f"that both feet stay planted (they differed by up to "
                     f"{imp.legs_spread:.1f} degrees; --legs each keeps them apart)")
    if imp.clipped:
        for h, (frames, excess) in imp.clipped.items():
            lo, hi = np.degrees(ch.limits[ch.hinge_index(h)])
            lines.append(f"clipped: {h}: {frames} of {n} frames beyond its limits [{lo:g}, "
                         f"{hi:g}] degrees, by up to {excess:.2f} degrees")
    else:
        lines.append("clipped: none (every angle inside its joint's limits)")
    for h, frames in sag.out_of_plane.items():
        lines.append(f"out of plane: {h}: {frames} of {imp.last - imp.first + 1} clip frames "
                     f"with a bone more than 60 degrees out of the sagittal plane")
    if sag.zero_from_character:
        lines.append(f"zero pose: {', '.join(sag.zero_from_character)}: the clip's rest pose "
                     "holds a bone out of the sagittal plane; their zero is the character's "
                     "zero pose")
    if sag.unmapped:
        lines.append(f"standing pose kept (not mapped or not asked for): "
                     f"{', '.join(sag.unmapped)}")
    return lines


def spec_text(imp: MotionImport, command: str) -> str:
    """The spec as YAML: a header saying where it came from, one frame per line."""
    s = imp.spec
    t = s["task"]
    head = [f"# {line}" for line in (f"Made by: {command}", *imp.report)]
    body = [f"name: {s['name']}",
            "character: {" + ", ".join(f"{k}: {v}" for k, v in s["character"].items()) + "}",
            f"clip: {{preparation: {s['clip']['preparation']:g}, duration: "
            f"{s['clip']['duration']!r}, decay: {s['clip']['decay']:g}}}",
            "task:", "  type: motion", f"  rate: {t['rate']:g}", f"  start: {t['start']:g}",
            f"  joints: [{', '.join(t['joints'])}]", "  frames:"]
    body += [f"    - [{', '.join(_num(v) for v in row)}]" for row in t["frames"]]
    return "\n".join(head + body) + "\n"


def _num(v: float) -> str:
    out = f"{v:.{ANGLE_DECIMALS}f}".rstrip("0").rstrip(".")
    return "0" if out in ("", "-0") else out
