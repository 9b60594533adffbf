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

from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np
import yaml

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
    torso: int = 0  # body a push acts on by default

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
    arr = np.asarray(value, dtype=float) if isinstance(value, list | tuple) else None
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
    if name is not None and not isinstance(name, str):
        raise CharacterError(f"{where}.name: must be a string")
    radius = _positive(g.get("radius"), f"{where}.radius")
    if g["shape"] == "sphere":
        a = b = _vec2(g.get("center"), f"{where}.center")
    else:
        a = _vec2(g.get("from"), f"{where}.from")
        b = _vec2(g.get("to"), f"{where}.to")
        if np.allclose(a, b):
            raise CharacterError(f"{where}: a capsule needs two distinct end points")
    return GeomDef(name, body, g["shape"], (float(a[0]), float(a[1])),
                   (float(b[0]), float(b[1])), radius)


def parse_character(data: Any, height: float | None = None, mass: float | None = None,
                    name: str = "character") -> Character:
    """Validate a character mapping and scale it; CharacterError names the field and the rule."""
    if not isinstance(data, dict):
        raise CharacterError(f"{name}: a character file must be a mapping")
    ref = data.get("reference") or {}
    ref_h = _positive(ref.get("height"), "reference.height")
    ref_m = _positive(ref.get("mass"), "reference.mass")
    segs = data.get("segments")
    if not isinstance(segs, list) or len(segs) < 2:
        raise CharacterError("segments: must be a list of at least two segments")
    root = data.get("root")
    if not segs[0] or segs[0].get("name") != root:
        raise CharacterError(f"segments[0]: must be the root segment {root!r}")

    body_names: list[str] = []
    hinge_names: list[str] = []
    parent, mass_l, inertia_l, com_l, anchor_l, limits_l = [], [], [], [], [], []
    feet, heels, toes, pbody, pts, prad = [], [], [], [], [], []
    weights_l, torques_l, geoms_l = [], [], []
    torque_limit = _positive(data.get("torque_limit"), "torque_limit")
    for i, seg in enumerate(segs):
        where = f"segments[{i}]"
        if not isinstance(seg, dict) or not isinstance(seg.get("name"), str):
            raise CharacterError(f"{where}.name: every segment needs a name")
        sname = seg["name"]
        if sname in body_names:
            raise CharacterError(f"{where}.name: duplicate segment {sname!r}")
        mass_l.append(_positive(seg.get("mass"), f"{where}.mass"))
        inertia_l.append(_positive(seg.get("inertia"), f"{where}.inertia"))
        com = _vec2(seg.get("com"), f"{where}.com")
        com_l.append(com)
        if i == 0:
            parent.append(-1)
            anchor_l.append(com)
        else:
            pname = seg.get("parent")
            if pname not in body_names:
                raise CharacterError(
                    f"{where}.parent: {pname!r} must name a segment listed before {sname!r}")
            joint = seg.get("joint")
            if not isinstance(joint, dict) or not isinstance(joint.get("name"), str):
                raise CharacterError(f"{where}.joint: needs a name, an anchor and limits")
            if joint["name"] in hinge_names:
                raise CharacterError(f"{where}.joint.name: duplicate joint {joint['name']!r}")
            lim = joint.get("limits")
            if (not isinstance(lim, list) or len(lim) != 2 or not all(
                    isinstance(v, int | float) for v in lim) or not lim[0] < lim[1]):
                raise CharacterError(f"{where}.joint.limits: must be [lo, hi] degrees, lo < hi")
            if not lim[0] <= 0.0 <= lim[1]:
                raise CharacterError(f"{where}.joint.limits: must include the zero pose (0)")
            weights_l.append(_nonnegative(joint.get("weight", DEFAULT_TRACKING_WEIGHT),
                                          f"{where}.joint.weight"))
            torques_l.append(_positive(joint.get("torque", torque_limit), f"{where}.joint.torque"))
            parent.append(body_names.index(pname))
            anchor_l.append(_vec2(joint.get("anchor"), f"{where}.joint.anchor"))
            hinge_names.append(joint["name"])
            limits_l.append(np.radians(lim))
        body_names.append(sname)
        if "foot" in seg:
            foot = seg["foot"]
            if not isinstance(foot, dict):
                raise CharacterError(f"{where}.foot: must hold heel and toe points")
            heel = _vec2(foot.get("heel"), f"{where}.foot.heel")
            toe = _vec2(foot.get("toe"), f"{where}.foot.toe")
            if not toe[0] > heel[0]:
                raise CharacterError(f"{where}.foot: the toe must be ahead (+x) of the heel")
            feet.append(i)
            heels.append(heel)
            toes.append(toe)
        for k, p in enumerate(seg.get("points", []) or []):
            if not isinstance(p, list) or len(p) != 3:
                raise CharacterError(f"{where}.points[{k}]: must be [x, y, radius]")
            pbody.append(i)
            pts.append(_vec2(p[:2], f"{where}.points[{k}]"))
            prad.append(float(p[2]))
        for k, g in enumerate(seg.get("geoms", []) or []):
            geoms_l.append(_geom(g, i, f"{where}.geoms[{k}]"))
    if not feet:
        raise CharacterError("segments: at least one segment needs a foot (heel and toe)")

    standing = data.get("standing") or {}
    offsets = np.zeros(len(hinge_names))
    for jname, deg in (standing.get("pose") or {}).items():
        if jname not in hinge_names:
            raise CharacterError(f"standing.pose: unknown joint {jname!r}")
        offsets[hinge_names.index(jname)] = np.radians(float(deg))

    geom_names = [g.name for g in geoms_l if g.name is not None]
    if len(set(geom_names)) != len(geom_names):
        raise CharacterError("geoms: geom names must be unique")
    hands = data.get("hands") or []
    if not isinstance(hands, list) or any(hd not in geom_names for hd in hands):
        raise CharacterError(f"hands: must list geom names, got {hands!r}")
    torso_name = data.get("torso", root)
    if torso_name not in body_names:
        raise CharacterError(f"torso: {torso_name!r} is not a segment")

    h = ref_h if height is None else float(height)
    m = ref_m if mass is None else float(mass)
    if not 0.3 * ref_h <= h <= 3 * ref_h:
        raise CharacterError(f"height: {h} m is outside [{0.3 * ref_h:g}, {3 * ref_h:g}]")
    if m <= 0:
        raise CharacterError("mass: must be positive")
    ls, ms = h / ref_h, m / ref_m
    arr = np.asarray
    return Character(
        name=name,
        height=h,
        body_names=tuple(body_names),
        hinge_names=tuple(hinge_names),
        parent=arr(parent, dtype=np.int64),
        mass=arr(mass_l) * ms,
        inertia=arr(inertia_l) * ms * ls**2,
        com0=arr(com_l) * ls,
        anchor0=arr(anchor_l) * ls,
        limits=arr(limits_l),
        feet=arr(feet, dtype=np.int64),
        heel0=arr(heels) * ls,
        toe0=arr(toes) * ls,
        point_body=arr(pbody, dtype=np.int64),
        point0=arr(pts).reshape(-1, 2) * ls,
        point_radius=arr(prad) * ls,
        standing_offsets=offsets,
        balance_standing=bool(standing.get("balance", False)),
        tracking_weights=arr(weights_l, dtype=float),
        torque_limits=arr(torques_l, dtype=float),
        geoms=tuple(GeomDef(g.name, g.body, g.shape, (g.a[0] * ls, g.a[1] * ls),
                            (g.b[0] * ls, g.b[1] * ls), g.radius * ls) for g in geoms_l),
        hands=tuple(hands),
        torso=body_names.index(torso_name),
    )


@lru_cache(maxsize=16)
def reference_size(model: str = DEFAULT_CHARACTER) -> tuple[float, float]:
    """(height m, mass kg) of `sim/data/<model>.yaml`'s `reference`: the size a spec that names
    the model without a height or mass gets (the file unscaled)."""
    ch = load_character(model)  # validates the file, `reference` included
    ref = yaml.safe_load((DATA_DIR / f"{model}.yaml").read_text())["reference"]
    return ch.height, float(ref["mass"])


@lru_cache(maxsize=16)
def load_character(model: str = DEFAULT_CHARACTER, height: float | None = None,
                   mass: float | None = None) -> Character:
    """Load `sim/data/<model>.yaml` (or a path), scaled to `height` m and `mass` kg."""
    path = Path(model) if model.endswith((".yaml", ".yml")) else DATA_DIR / f"{model}.yaml"
    try:
        data = yaml.safe_load(path.read_text())
    except OSError as err:
        raise CharacterError(f"character {model!r}: cannot read {path} ({err.strerror})") from None
    except yaml.YAMLError as err:
        raise CharacterError(f"character {model!r}: not valid YAML: {err}") from None
    return parse_character(data, height, mass, name=path.stem)
