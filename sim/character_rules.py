"""The bounds and rules of a character definition that `sim.character.parse_character` applies
to every character, shipped or brought by a user (docs/characters.md lists them field by field).

A user's definition is untrusted input: it must not crash a process, nor make a simulation
that cannot end (a thousand segments), nor ask ODE to integrate bodies it cannot (a 1e-9 kg
segment beside a 25 kg trunk). Every bound here is a named constant with its unit and its
reason; the shipped characters sit well inside each. Errors name the field by its path in the
definition (`segments[3].mass`) and the rule.
"""

from __future__ import annotations

import math
import re
from typing import Any

from sim.errors import CharacterError

#: Height (m) and mass (kg) a character may have: those a spec's `character.height` /
#: `character.mass` may ask for (the range the controller's gains were tuned over); a
#: definition's `reference` must lie in it too, so that its own size is one a spec can use.
HEIGHT_RANGE = (1.0, 2.5)
MASS_RANGE = (20.0, 250.0)
#: Most segments: the controller's QP and the dynamics grow with the cube of the hinges; the
#: lion has 23, twice that still simulates a clip in seconds.
MAX_SEGMENTS = 48
#: Lightest segment (kg, before scaling), and the largest heaviest/lightest ratio: ODE's
#: constraint solve at 1 ms steps loses accuracy on chains of very unequal masses (the shipped
#: characters' ratios are 24 to 76; the lion's tail tip, 0.5 kg, is their lightest segment).
MIN_SEGMENT_MASS = 0.1
MAX_MASS_RATIO = 250.0
#: The segments' masses must add up to `reference.mass` within this fraction: the reference is
#: what a spec's `character.mass` scales, so it must be the body's.
MASS_SUM_TOLERANCE = 0.01
#: A segment's radius of gyration sqrt(inertia / mass) (m, before scaling): a uniform rod of
#: 3.5 cm to 1.7 m. Outside it a segment spins like a point or like a flywheel (the shipped
#: characters' lie in 0.05-0.22 m).
GYRATION_RANGE = (0.01, 0.5)
#: Radius (m) of an outline point (0: a point) or of a contact geom.
MAX_RADIUS = 0.5
#: Heel-to-toe length of a foot (m): the CoP box needs room, and a foot longer than a metre
#: is no foot the controller's support model was made for.
FOOT_LENGTH_RANGE = (0.05, 1.0)
#: The soles lie on the ground in the zero pose: heel and toe within this of y = 0 (m).
SOLE_TOLERANCE = 0.001
#: Joint limits (degrees) lie within +-180: a hinge angle is measured on one turn.
MAX_LIMIT_DEGREES = 180.0
#: Torque limit of a hinge (N m) and tracking weight of a hinge (no unit).
TORQUE_RANGE = (1.0, 10_000.0)
WEIGHT_RANGE = (0.0, 100.0)
#: Outline points and contact geoms per segment, hands per character.
MAX_POINTS = 16
MAX_GEOMS = 8
MAX_HANDS = 8
#: A name (segment, joint, geom): letters, digits, `_`, `.`, `-`, at most 64.
NAME_PATTERN = re.compile(r"[A-Za-z0-9_.\-]{1,64}")
#: Nesting depth and item count of a definition document (the shipped ones: depth 5, ~700
#: items): bounds on the work any document costs before its first rule is checked.
MAX_DEPTH = 8
MAX_ITEMS = 20_000
#: Largest integer a definition may hold (a float cannot hold every larger one).
MAX_INTEGER = 10**15

#: The fields of each block (anything else is refused: a misspelt `intertia` is an error).
TOP_FIELDS = frozenset({"reference", "root", "torso", "torque_limit", "hands", "segments",
                        "standing"})
REFERENCE_FIELDS = frozenset({"height", "mass"})
SEGMENT_FIELDS = frozenset({"name", "parent", "joint", "mass", "inertia", "com", "foot",
                            "points", "geoms"})
JOINT_FIELDS = frozenset({"name", "anchor", "limits", "weight", "torque"})
FOOT_FIELDS = frozenset({"heel", "toe"})
GEOM_FIELDS = frozenset({"name", "shape", "center", "from", "to", "radius"})
STANDING_FIELDS = frozenset({"pose", "balance"})


def check_plain(data: Any, where: str = "", depth: int = 0, budget: list[int] | None = None
                ) -> None:
    """The document holds JSON values only (mappings with string keys, lists, strings, finite
    numbers, booleans, null), nested at most `MAX_DEPTH` deep, `MAX_ITEMS` items in all."""
    budget = [MAX_ITEMS] if budget is None else budget
    budget[0] -= 1
    if budget[0] < 0:
        raise CharacterError(f"{where or 'definition'}: more than {MAX_ITEMS} items")
    if depth > MAX_DEPTH:
        raise CharacterError(f"{where}: nested deeper than {MAX_DEPTH} levels")
    if isinstance(data, dict):
        for k, v in data.items():
            if not isinstance(k, str):
                raise CharacterError(f"{where or 'definition'}: keys must be strings, got "
                                     f"{k!r}")
            check_plain(v, f"{where}.{k}" if where else k, depth + 1, budget)
    elif isinstance(data, list):
        for i, v in enumerate(data):
            check_plain(v, f"{where}[{i}]", depth + 1, budget)
    elif isinstance(data, float):
        if not math.isfinite(data):
            raise CharacterError(f"{where}: must be a finite number, got {data!r}")
    elif isinstance(data, int) and not isinstance(data, bool) and abs(data) > MAX_INTEGER:
        raise CharacterError(f"{where}: an integer of {len(str(abs(data)))} digits is no "
                             f"size of a character")
    elif not (data is None or isinstance(data, str | int | bool)):
        raise CharacterError(f"{where}: must be a JSON value (number, text, list, mapping), "
                             f"got {type(data).__name__}")


def check_fields(block: Any, allowed: frozenset[str], where: str) -> None:
    """A mapping block names only its own fields."""
    if isinstance(block, dict):
        extra = sorted(set(block) - allowed)
        if extra:
            field = f"{where}.{extra[0]}" if where else extra[0]
            raise CharacterError(f"{field}: unknown field; the fields here are "
                                 f"{', '.join(sorted(allowed))}")


def check_name(value: Any, where: str) -> str:
    if not isinstance(value, str) or not NAME_PATTERN.fullmatch(value):
        raise CharacterError(f"{where}: must be a name of 1 to 64 letters, digits, `_`, `.` "
                             f"or `-`, got {value!r}")
    return value


def within(value: float, bounds: tuple[float, float], where: str, unit: str) -> float:
    """`value` if it lies in `bounds`, else CharacterError naming the range."""
    lo, hi = bounds
    if not lo <= value <= hi:
        raise CharacterError(f"{where}: must be from {lo:g} to {hi:g} {unit}, got {value:g}")
    return value


def check_counts(data: dict) -> None:
    """Bounds on how many segments, points, geoms and hands a definition holds."""
    segs = data.get("segments")
    hands = data.get("hands")
    if isinstance(hands, list) and len(hands) > MAX_HANDS:
        raise CharacterError(f"hands: at most {MAX_HANDS}, got {len(hands)}")
    for i, seg in enumerate(segs if isinstance(segs, list) else []):
        if not isinstance(seg, dict):
            raise CharacterError(f"segments[{i}]: must be a mapping (name, mass, inertia, ...)")
        for key, most in (("points", MAX_POINTS), ("geoms", MAX_GEOMS)):
            items = seg.get(key)
            if items is not None and not isinstance(items, list):
                raise CharacterError(f"segments[{i}].{key}: must be a list")
            if items and len(items) > most:
                raise CharacterError(f"segments[{i}].{key}: at most {most}, got {len(items)}")


def check_document(data: dict) -> None:
    """What is checked before any value is read: plain JSON, bounded size, known fields."""
    segs = data.get("segments")
    if isinstance(segs, list) and len(segs) > MAX_SEGMENTS:  # before walking them all
        raise CharacterError(f"segments: at most {MAX_SEGMENTS} segments, got {len(segs)}")
    check_plain(data)
    check_fields(data, TOP_FIELDS, "")
    check_fields(data.get("reference"), REFERENCE_FIELDS, "reference")
    check_fields(data.get("standing"), STANDING_FIELDS, "standing")
    check_counts(data)
    for i, seg in enumerate(segs if isinstance(segs, list) else []):
        where = f"segments[{i}]"
        check_fields(seg, SEGMENT_FIELDS, where)
        check_fields(seg.get("joint"), JOINT_FIELDS, f"{where}.joint")
        check_fields(seg.get("foot"), FOOT_FIELDS, f"{where}.foot")
        for k, g in enumerate(seg.get("geoms") or []):
            check_fields(g, GEOM_FIELDS, f"{where}.geoms[{k}]")


def check_masses(masses: list[float], inertias: list[float], ref_mass: float) -> None:
    """Segment masses and inertias within the bounds ODE integrates well (module constants);
    their sum is the reference mass."""
    for i, (m, inertia) in enumerate(zip(masses, inertias, strict=True)):
        if m < MIN_SEGMENT_MASS:
            raise CharacterError(f"segments[{i}].mass: must be at least {MIN_SEGMENT_MASS:g} "
                                 f"kg, got {m:g}")
        gyration = math.sqrt(inertia / m)
        if not GYRATION_RANGE[0] <= gyration <= GYRATION_RANGE[1]:
            lo, hi = (m * r * r for r in GYRATION_RANGE)
            raise CharacterError(
                f"segments[{i}].inertia: must be from {lo:.3g} to {hi:.3g} kg m^2 for its "
                f"{m:g} kg (a radius of gyration from {GYRATION_RANGE[0]:g} to "
                f"{GYRATION_RANGE[1]:g} m), got {inertia:g}")
    heavy, light = max(masses), min(masses)
    if heavy > MAX_MASS_RATIO * light:
        i = masses.index(light)
        raise CharacterError(f"segments[{i}].mass: the heaviest segment ({heavy:g} kg) may be "
                             f"at most {MAX_MASS_RATIO:g} times the lightest, got {light:g} kg")
    total = sum(masses)
    if abs(total - ref_mass) > MASS_SUM_TOLERANCE * ref_mass:
        raise CharacterError(f"reference.mass: must be the segments' total mass ({total:g} kg) "
                             f"within {100 * MASS_SUM_TOLERANCE:g} %, got {ref_mass:g}")


def check_place(p: Any, radius: float, height: float, where: str) -> None:
    """A point of the zero pose lies in the character's box: |x| up to its height, from the
    ground (its radius included) up to 1.5 times its height."""
    x, y = float(p[0]), float(p[1])
    if not (abs(x) <= height and y - radius >= -SOLE_TOLERANCE and y <= 1.5 * height):
        raise CharacterError(
            f"{where}: must lie above the ground (y - radius >= 0) and within the character's "
            f"box (|x| <= {height:g} m, y <= {1.5 * height:g} m: its reference height and "
            f"1.5 times it), got [{x:g}, {y:g}]")


def check_foot(heel: Any, toe: Any, com: Any, where: str) -> None:
    """The contact points under a foot: heel and toe on the ground (y = 0) in the zero pose, a
    foot length in `FOOT_LENGTH_RANGE`, the foot's CM above the sole and between them."""
    for name, p in (("heel", heel), ("toe", toe)):
        if abs(float(p[1])) > SOLE_TOLERANCE:
            raise CharacterError(f"{where}.foot.{name}: must be on the ground (y = 0) in the "
                                 f"zero pose, got y = {float(p[1]):g}")
    within(float(toe[0] - heel[0]), FOOT_LENGTH_RANGE, f"{where}.foot: heel-to-toe length",
           "m")
    if not (heel[0] <= com[0] <= toe[0] and com[1] > 0.0):
        raise CharacterError(f"{where}.com: a foot's CM must lie above its sole, between heel "
                             f"and toe, got [{float(com[0]):g}, {float(com[1]):g}]")


def check_limits(lim: Any, where: str) -> None:
    """[lo, hi] degrees: numbers, lo < hi, within +-`MAX_LIMIT_DEGREES`, around the zero pose."""
    if (not isinstance(lim, list) or len(lim) != 2
            or not all(isinstance(v, int | float) and not isinstance(v, bool) for v in lim)
            or not lim[0] < lim[1]):
        raise CharacterError(f"{where}: must be [lo, hi] degrees, lo < hi")
    if not (lim[0] >= -MAX_LIMIT_DEGREES and lim[1] <= MAX_LIMIT_DEGREES):
        raise CharacterError(f"{where}: must lie within [-{MAX_LIMIT_DEGREES:g}, "
                             f"{MAX_LIMIT_DEGREES:g}] degrees, got {lim}")
    if not lim[0] <= 0.0 <= lim[1]:
        raise CharacterError(f"{where}: must include the zero pose (0)")
