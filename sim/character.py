"""Characters as data: segments, hinges, feet and standing pose, loaded from YAML and validated.

A character file (see `sim/data/humanoid.yaml`) gives every segment in world coordinates in the
zero pose (upright, facing +x, y up, soles on y = 0). `load_character` checks it and turns it
into flat arrays for the planar dynamics (`sim.dynamics`), scaled to a height and mass:
lengths scale with height, masses with mass, inertias with mass * height^2.

Generalised coordinates: q = [root x, root y, root angle, hinge_1 .. hinge_n], the root being the
CoM of the root segment; hinge order is the file's segment order. Hinge angles are
counter-clockwise about +z, child relative to parent (radians in code, degrees in files).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np

import sim.character_rules as rules
from cmrt.specfile import SpecReadError, read_document
from sim.errors import CharacterError

DATA_DIR = Path(__file__).parent / "data"
#: The character a spec without `character.model` gets: named by the data folder (a data
#: choice, like the characters themselves), read once at import.
DEFAULT_CHARACTER = (DATA_DIR / "default_character").read_text().strip()
ROOT_DOF = 3


GEOM_SHAPES = ("sphere", "capsule")
DEFAULT_TRACKING_WEIGHT = 1.0


@dataclass(frozen=True)
class GeomDef:
    """A contact shape fixed on a body, in world coordinates of the zero pose (m).

    sphere: `a` is the centre; capsule: the segment from `a` to `b`; `radius` for both."""

    name: str | None
    body: int
    shape: str
    a: tuple[float, float]
    b: tuple[float, float]
    radius: float


@dataclass(frozen=True)
class Character:
    """A planar articulated character as arrays (SI units, zero pose in world coordinates)."""

    name: str
    height: float  # m
    body_names: tuple[str, ...]
    hinge_names: tuple[str, ...]
    parent: np.ndarray  # (nb,) int, -1 for the root; body b > 0 is the child of hinge b - 1
    mass: np.ndarray  # (nb,) kg
    inertia: np.ndarray  # (nb,) kg m^2 about the CoM
    com0: np.ndarray  # (nb, 2) m, CoM in the zero pose
    anchor0: np.ndarray  # (nb, 2) m, hinge anchor to the parent in the zero pose (root: its CoM)
    limits: np.ndarray  # (nh, 2) rad
    feet: np.ndarray  # (nf,) body indices of the feet
    heel0: np.ndarray  # (nf, 2) m, heel point in the zero pose
    toe0: np.ndarray  # (nf, 2) m, toe point in the zero pose
    point_body: np.ndarray  # (np,) body index of each outline point (fall detection)
    point0: np.ndarray  # (np, 2) m, outline points in the zero pose
    point_radius: np.ndarray  # (np,) m
    standing_offsets: np.ndarray  # (nh,) rad, standing pose relative to the zero pose
    balance_standing: bool
    tracking_weights: np.ndarray  # (nh,) the balance controller's tracking weight per hinge
    torque_limits: np.ndarray  # (nh,) N m, |hinge torque| is clamped to this
    geoms: tuple[GeomDef, ...] = ()  # contact shapes against props
    hands: tuple[str, ...] = ()  # names of the geoms that can hold an object
    torso: int | None = None  # body a push acts on by default (None: the file names none)

    @property
    def support_length(self) -> float:
        """Heel-to-toe length (m) of the support interval in the zero pose."""
        return float(self.toe0[:, 0].max() - self.heel0[:, 0].min())

    def geom(self, name: str) -> GeomDef:
        for g in self.geoms:
            if g.name == name:
                return g
        raise CharacterError(f"unknown geom {name!r}")

    @property
    def total_mass(self) -> float:
        return float(self.mass.sum())

    @property
    def n_bodies(self) -> int:
        return len(self.body_names)

    @property
    def n_hinges(self) -> int:
        return len(self.hinge_names)

    @property
    def ndof(self) -> int:
        return ROOT_DOF + self.n_hinges

    def hinge_index(self, name: str) -> int:
        try:
            return self.hinge_names.index(name)
        except ValueError:
            raise CharacterError(f"unknown joint {name!r}") from None

    def body_index(self, name: str) -> int:
        try:
            return self.body_names.index(name)
        except ValueError:
            raise CharacterError(f"unknown body {name!r}") from None


def _vec2(value: Any, where: str) -> np.ndarray:
    numbers = isinstance(value, list | tuple) and all(
        isinstance(v, int | float) and not isinstance(v, bool) for v in value)
    arr = np.asarray(value, dtype=float) if numbers else None
    if arr is None or arr.shape != (2,) or not np.all(np.isfinite(arr)):
        raise CharacterError(f"{where}: must be a list of two finite numbers [x, y]")
    return arr


def _positive(value: Any, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not value > 0:
        raise CharacterError(f"{where}: must be a positive number, got {value!r}")
    return float(value)


def _nonnegative(value: Any, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not value >= 0:
        raise CharacterError(f"{where}: must be a number >= 0, got {value!r}")
    return float(value)


def _geom(g: Any, body: int, where: str) -> GeomDef:
    if not isinstance(g, dict) or g.get("shape") not in GEOM_SHAPES:
        raise CharacterError(f"{where}.shape: must be one of {', '.join(GEOM_SHAPES)}")
    name = g.get("name")
    if name is not None:
        rules.check_name(name, f"{where}.name")
    radius = rules.within(_positive(g.get("radius"), f"{where}.radius"),
                          (0.0, rules.MAX_RADIUS), f"{where}.radius", "m")
    if g["shape"] == "sphere":
        a = b = _vec2(g.get("center"), f"{where}.center")
    else:
        a = _vec2(g.get("from"), f"{where}.from")
        b = _vec2(g.get("to"), f"{where}.to")
        if np.allclose(a, b):
            raise CharacterError(f"{where}: a capsule needs two distinct end points")
    return GeomDef(name, body, g["shape"], (float(a[0]), float(a[1])),
                   (float(b[0]), float(b[1])), radius)


@dataclass
class _Segments:
    """What the segment list holds, gathered in file order (unscaled, model units)."""

    body_names: list[str] = field(default_factory=list)
    hinge_names: list[str] = field(default_factory=list)
    parent: list[int] = field(default_factory=list)
    mass: list[float] = field(default_factory=list)
    inertia: list[float] = field(default_factory=list)
    com: list[np.ndarray] = field(default_factory=list)
    anchor: list[np.ndarray] = field(default_factory=list)
    limits: list[np.ndarray] = field(default_factory=list)
    weights: list[float] = field(default_factory=list)
    torques: list[float] = field(default_factory=list)
    feet: list[int] = field(default_factory=list)
    heels: list[np.ndarray] = field(default_factory=list)
    toes: list[np.ndarray] = field(default_factory=list)
    point_body: list[int] = field(default_factory=list)
    points: list[np.ndarray] = field(default_factory=list)
    point_radius: list[float] = field(default_factory=list)
    geoms: list[GeomDef] = field(default_factory=list)


def _segment_list(data: dict) -> list:
    """The `segments` list, at least two, the first being the `root` (a tree's one segment
    without a parent)."""
    segs = data.get("segments")
    if not isinstance(segs, list) or len(segs) < 2:
        raise CharacterError("segments: must be a list of at least two segments")
    root = rules.check_name(data.get("root"), "root")
    if not segs[0] or segs[0].get("name") != root:
        raise CharacterError(f"segments[0]: must be the root segment {root!r}")
    if "parent" in segs[0] or "joint" in segs[0]:
        raise CharacterError("segments[0]: the root has no parent and no joint (a tree has "
                             "one root)")
    return segs


def _parse_body(out: _Segments, seg: Any, where: str) -> None:
    """A segment's body: its unique name, mass, inertia and CoM."""
    if not isinstance(seg, dict) or not isinstance(seg.get("name"), str):
        raise CharacterError(f"{where}.name: every segment needs a name")
    rules.check_name(seg["name"], f"{where}.name")
    if seg["name"] in out.body_names:
        raise CharacterError(f"{where}.name: duplicate segment {seg['name']!r}")
    out.mass.append(_positive(seg.get("mass"), f"{where}.mass"))
    out.inertia.append(_positive(seg.get("inertia"), f"{where}.inertia"))
    out.com.append(_vec2(seg.get("com"), f"{where}.com"))


def _parse_joint(out: _Segments, seg: dict, where: str, torque_limit: float) -> None:
    """A non-root segment's hinge to its parent (listed before it): name, anchor, limits
    (degrees, around the zero pose), tracking weight and torque limit."""
    pname = seg.get("parent")
    if pname is None:
        raise CharacterError(f"{where}.parent: every segment but the root needs a parent (the "
                             f"segments form one connected tree)")
    if pname not in out.body_names:
        raise CharacterError(
            f"{where}.parent: {pname!r} must name a segment listed before {seg['name']!r} "
            f"(a tree listed parents first: no cycle, one root)")
    joint = seg.get("joint")
    if not isinstance(joint, dict) or not isinstance(joint.get("name"), str):
        raise CharacterError(f"{where}.joint: needs a name, an anchor and limits")
    rules.check_name(joint["name"], f"{where}.joint.name")
    if joint["name"] in out.hinge_names:
        raise CharacterError(f"{where}.joint.name: duplicate joint {joint['name']!r}")
    lim = joint.get("limits")
    rules.check_limits(lim, f"{where}.joint.limits")
    weight = _nonnegative(joint.get("weight", DEFAULT_TRACKING_WEIGHT), f"{where}.joint.weight")
    out.weights.append(rules.within(weight, rules.WEIGHT_RANGE, f"{where}.joint.weight",
                                    "(no unit)"))
    torque = _positive(joint.get("torque", torque_limit), f"{where}.joint.torque")
    out.torques.append(rules.within(torque, rules.TORQUE_RANGE, f"{where}.joint.torque", "N m"))
    out.parent.append(out.body_names.index(pname))
    out.anchor.append(_vec2(joint.get("anchor"), f"{where}.joint.anchor"))
    out.hinge_names.append(joint["name"])
    out.limits.append(np.radians(lim))


def _parse_foot(out: _Segments, seg: dict, where: str, body: int) -> None:
    """A segment's foot, if it has one: heel and toe points, the toe ahead."""
    if "foot" not in seg:
        return
    foot = seg["foot"]
    if not isinstance(foot, dict):
        raise CharacterError(f"{where}.foot: must hold heel and toe points")
    heel = _vec2(foot.get("heel"), f"{where}.foot.heel")
    toe = _vec2(foot.get("toe"), f"{where}.foot.toe")
    if not toe[0] > heel[0]:
        raise CharacterError(f"{where}.foot: the toe must be ahead (+x) of the heel")
    out.feet.append(body)
    out.heels.append(heel)
    out.toes.append(toe)


def _parse_contacts(out: _Segments, seg: dict, where: str, body: int) -> None:
    """A segment's outline points (fall detection: [x, y, radius]) and contact geoms."""
    for k, p in enumerate(seg.get("points", []) or []):
        if not isinstance(p, list) or len(p) != 3:
            raise CharacterError(f"{where}.points[{k}]: must be [x, y, radius]")
        out.point_body.append(body)
        out.points.append(_vec2(p[:2], f"{where}.points[{k}]"))
        out.point_radius.append(rules.within(_nonnegative(p[2], f"{where}.points[{k}] radius"),
                                             (0.0, rules.MAX_RADIUS),
                                             f"{where}.points[{k}] radius", "m"))
    for k, g in enumerate(seg.get("geoms", []) or []):
        out.geoms.append(_geom(g, body, f"{where}.geoms[{k}]"))


def _parse_segments(data: dict) -> _Segments:
    """Every segment's body, joint, foot, outline points and geoms; at least one foot."""
    out = _Segments()
    segs = _segment_list(data)
    torque_limit = rules.within(_positive(data.get("torque_limit"), "torque_limit"),
                                rules.TORQUE_RANGE, "torque_limit", "N m")
    for i, seg in enumerate(segs):
        where = f"segments[{i}]"
        _parse_body(out, seg, where)
        if i == 0:
            out.parent.append(-1)
            out.anchor.append(out.com[-1])
        else:
            _parse_joint(out, seg, where, torque_limit)
        out.body_names.append(seg["name"])
        _parse_foot(out, seg, where, i)
        _parse_contacts(out, seg, where, i)
    if not out.feet:
        raise CharacterError("segments: at least one segment needs a foot (heel and toe)")
    return out


def _standing_offsets(standing: Any, segs: _Segments) -> np.ndarray:
    """The standing pose's hinge angles (rad) relative to the zero pose, within the limits."""
    if not isinstance(standing, dict):
        raise CharacterError("standing: must be a mapping (pose, balance)")
    if not isinstance(standing.get("balance", False), bool):
        raise CharacterError("standing.balance: must be true or false")
    pose = standing.get("pose") or {}
    if not isinstance(pose, dict):
        raise CharacterError("standing.pose: must map joint names to degrees")
    offsets = np.zeros(len(segs.hinge_names))
    for jname, deg in pose.items():
        if jname not in segs.hinge_names:
            raise CharacterError(f"standing.pose: unknown joint {jname!r}")
        if isinstance(deg, bool) or not isinstance(deg, int | float):
            raise CharacterError(f"standing.pose.{jname}: must be a number of degrees")
        j = segs.hinge_names.index(jname)
        lo, hi = np.degrees(segs.limits[j])
        if not lo <= deg <= hi:
            raise CharacterError(f"standing.pose.{jname}: must lie within the joint's limits "
                                 f"[{lo:g}, {hi:g}] degrees, got {deg:g}")
        offsets[j] = np.radians(float(deg))
    return offsets


def _hands_and_torso(data: dict, segs: _Segments) -> tuple[list[str], int]:
    """The geoms that can hold an object (unique geom names) and the body a push acts on."""
    geom_names = [g.name for g in segs.geoms if g.name is not None]
    if len(set(geom_names)) != len(geom_names):
        raise CharacterError("geoms: geom names must be unique")
    hands = data.get("hands") or []
    if not isinstance(hands, list) or any(hd not in geom_names for hd in hands):
        raise CharacterError(f"hands: must list geom names, got {hands!r}")
    if len(set(hands)) != len(hands):
        raise CharacterError(f"hands: a geom is listed twice, got {hands!r}")
    torso_name = data.get("torso")
    if torso_name is None:
        return hands, None
    if torso_name not in segs.body_names:
        raise CharacterError(f"torso: {torso_name!r} is not a segment")
    return hands, segs.body_names.index(torso_name)


def _reference(data: dict) -> tuple[float, float]:
    """The file's `reference` height (m) and mass (kg), those of its numbers."""
    ref = data.get("reference") or {}
    if not isinstance(ref, dict):
        raise CharacterError("reference: must hold the height (m) and mass (kg)")
    h = _positive(ref.get("height"), "reference.height")
    m = _positive(ref.get("mass"), "reference.mass")
    return (rules.within(h, rules.HEIGHT_RANGE, "reference.height", "m"),
            rules.within(m, rules.MASS_RANGE, "reference.mass", "kg"))


def _check_geometry(segs: _Segments, ref_h: float) -> None:
    """Every point of the zero pose above the ground and in the character's box, the feet's
    soles on the ground under their segments."""
    for i, (com, anchor) in enumerate(zip(segs.com, segs.anchor, strict=True)):
        rules.check_place(com, 0.0, ref_h, f"segments[{i}].com")
        if i:
            rules.check_place(anchor, 0.0, ref_h, f"segments[{i}].joint.anchor")
    for k, (p, r) in enumerate(zip(segs.points, segs.point_radius, strict=True)):
        b = segs.point_body[k]
        rules.check_place(p, r, ref_h, f"segments[{b}].points[{segs.point_body[:k].count(b)}]")
    for g in segs.geoms:
        for end in (g.a, g.b):
            rules.check_place(end, g.radius, ref_h, f"segments[{g.body}].geoms "
                              f"({g.name or g.shape})")
    for f, heel, toe in zip(segs.feet, segs.heels, segs.toes, strict=True):
        rules.check_foot(heel, toe, segs.com[f], f"segments[{f}]")


def _scale(ref_h: float, ref_m: float, height: float | None,
           mass: float | None) -> tuple[float, float, float]:
    """(height m, length scale, mass scale) of the character asked for (None: the
    reference's) against the reference."""
    h = ref_h if height is None else float(height)
    m = ref_m if mass is None else float(mass)
    if not 0.3 * ref_h <= h <= 3 * ref_h:
        raise CharacterError(f"height: {h} m is outside [{0.3 * ref_h:g}, {3 * ref_h:g}]")
    if m <= 0:
        raise CharacterError("mass: must be positive")
    return h, h / ref_h, m / ref_m


def parse_character(data: Any, height: float | None = None, mass: float | None = None,
                    name: str = "character") -> Character:
    """Validate a character mapping and scale it; CharacterError names the field and the rule."""
    if not isinstance(data, dict):
        raise CharacterError(f"{name}: a character file must be a mapping")
    rules.check_document(data)
    ref_h, ref_m = _reference(data)
    segs = _parse_segments(data)
    rules.check_masses(segs.mass, segs.inertia, ref_m)
    _check_geometry(segs, ref_h)
    standing = data.get("standing") or {}
    offsets = _standing_offsets(standing, segs)
    hands, torso = _hands_and_torso(data, segs)
    h, ls, ms = _scale(ref_h, ref_m, height, mass)
    arr = np.asarray
    return Character(
        name=name,
        height=h,
        body_names=tuple(segs.body_names),
        hinge_names=tuple(segs.hinge_names),
        parent=arr(segs.parent, dtype=np.int64),
        mass=arr(segs.mass) * ms,
        inertia=arr(segs.inertia) * ms * ls**2,
        com0=arr(segs.com) * ls,
        anchor0=arr(segs.anchor) * ls,
        limits=arr(segs.limits),
        feet=arr(segs.feet, dtype=np.int64),
        heel0=arr(segs.heels) * ls,
        toe0=arr(segs.toes) * ls,
        point_body=arr(segs.point_body, dtype=np.int64),
        point0=arr(segs.points).reshape(-1, 2) * ls,
        point_radius=arr(segs.point_radius) * ls,
        standing_offsets=offsets,
        balance_standing=bool(standing.get("balance", False)),
        tracking_weights=arr(segs.weights, dtype=float),
        torque_limits=arr(segs.torques, dtype=float),
        geoms=tuple(GeomDef(g.name, g.body, g.shape, (g.a[0] * ls, g.a[1] * ls),
                            (g.b[0] * ls, g.b[1] * ls), g.radius * ls) for g in segs.geoms),
        hands=tuple(hands),
        torso=torso,
    )


def shipped_characters() -> list[str]:
    """The names of the characters shipped in `sim/data/`."""
    return sorted(p.stem for p in DATA_DIR.glob("*.yaml"))


def shipped_definition(name: str) -> dict[str, Any]:
    """The definition (the file's mapping) of shipped character `name` (shipped_characters)."""
    if name not in shipped_characters():
        raise CharacterError(f"unknown character {name!r}")
    return _read_definition(DATA_DIR / f"{name}.yaml", name)


def definition_reference(data: Any) -> tuple[float, float] | None:
    """(height m, mass kg) of a definition's `reference`, or None if it has none that reads
    (the parser then reports what is wrong)."""
    try:
        return _reference(data) if isinstance(data, dict) else None
    except CharacterError:
        return None


@lru_cache(maxsize=16)
def character_reference(model: str) -> tuple[float, float] | None:
    """(height m, mass kg) of `sim/data/<model>.yaml`'s `reference`, or None if the file or
    its reference cannot be read (the loader then reports what is wrong)."""
    if not isinstance(model, str) or not model.replace("_", "").isalnum():
        return None
    try:
        ref = _read_definition(DATA_DIR / f"{model}.yaml", model).get("reference")
        return _positive(ref["height"], "height"), _positive(ref["mass"], "mass")
    except (AttributeError, KeyError, TypeError, CharacterError):
        return None


@lru_cache(maxsize=16)
def load_character(model: str = DEFAULT_CHARACTER, height: float | None = None,
                   mass: float | None = None) -> Character:
    """Load `sim/data/<model>.yaml` (or a path), scaled to `height` m and `mass` kg."""
    path = Path(model) if model.endswith((".yaml", ".yml")) else DATA_DIR / f"{model}.yaml"
    return parse_character(_read_definition(path, model), height, mass, name=path.stem)


def _read_definition(path: Path, model: str) -> Any:
    """The document of a character file (`cmrt.specfile.read_document`: bounded, one error)."""
    try:
        return read_document(path, f"character {model!r}")
    except SpecReadError as err:
        raise CharacterError(str(err)) from None


def _number(lo: float | None = None, hi: float | None = None, *, above: float | None = None
            ) -> dict[str, Any]:
    out: dict[str, Any] = {"type": "number"}
    for key, v in (("minimum", lo), ("maximum", hi), ("exclusiveMinimum", above)):
        if v is not None:
            out[key] = v
    return out


def _block(properties: dict[str, Any], required: tuple[str, ...] = ()) -> dict[str, Any]:
    out: dict[str, Any] = {"type": "object", "additionalProperties": False,
                           "properties": properties}
    return {**out, "required": list(required)} if required else out


def definition_schema() -> dict[str, Any]:
    """The JSON Schema of a character definition: the rules of `parse_character` a schema can
    state (the fields of each block, the required ones, names, counts and ranges). The rest
    relates fields to each other (the root is `segments[0]`, parents listed before, segment
    masses summing to the reference mass, feet on the ground, limits around the zero pose, ...)
    and is checked only by `parse_character` (docs/characters.md)."""
    name = {"type": "string", "pattern": f"^{rules.NAME_PATTERN.pattern}$"}
    vec2 = {"type": "array", "items": {"type": "number"}, "minItems": 2, "maxItems": 2}
    joint = _block({"name": name, "anchor": vec2,
                    "limits": {"type": "array", "prefixItems": [
                        _number(-rules.MAX_LIMIT_DEGREES, 0.0),
                        _number(0.0, rules.MAX_LIMIT_DEGREES)], "minItems": 2, "maxItems": 2},
                    "weight": _number(*rules.WEIGHT_RANGE),
                    "torque": _number(*rules.TORQUE_RANGE)}, ("name", "anchor", "limits"))
    point = {"type": "array", "prefixItems": [{"type": "number"}, {"type": "number"},
                                              _number(0.0, rules.MAX_RADIUS)],
             "minItems": 3, "maxItems": 3}
    geom = _block({"name": name, "shape": {"enum": list(GEOM_SHAPES)}, "center": vec2,
                   "from": vec2, "to": vec2, "radius": _number(hi=rules.MAX_RADIUS, above=0.0)},
                  ("shape", "radius"))
    body = {"name": name, "mass": _number(rules.MIN_SEGMENT_MASS),
            "inertia": _number(above=0.0), "com": vec2,
            "foot": _block({"heel": vec2, "toe": vec2}, ("heel", "toe")),
            "points": {"type": "array", "items": point, "maxItems": rules.MAX_POINTS},
            "geoms": {"type": "array", "items": geom, "maxItems": rules.MAX_GEOMS}}
    needs = ("name", "mass", "inertia", "com")
    root = _block(body, needs)  # segments[0]: the root, without a parent or a joint
    segment = _block({**body, "parent": name, "joint": joint}, (*needs, "parent", "joint"))
    return _block({
        "reference": _block({"height": _number(*rules.HEIGHT_RANGE),
                             "mass": _number(*rules.MASS_RANGE)}, ("height", "mass")),
        "root": name,
        "torso": {"anyOf": [name, {"type": "null"}]},
        "torque_limit": _number(*rules.TORQUE_RANGE),
        "hands": {"type": "array", "items": name, "uniqueItems": True,
                  "maxItems": rules.MAX_HANDS},
        "segments": {"type": "array", "prefixItems": [root], "items": segment, "minItems": 2,
                     "maxItems": rules.MAX_SEGMENTS},
        "standing": _block({"pose": {"type": "object", "additionalProperties": {
            "type": "number"}}, "balance": {"type": "boolean"}}),
    }, ("reference", "root", "torque_limit", "segments"))
