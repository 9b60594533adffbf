"""Props as data: the dynamic objects a task puts in the world (a ball, a bag, a block).

A `PropDef` is pure data (no ODE): tasks build them from their spec and `sim.physics.Physics`
turns them into ODE bodies kept in the character's plane (z = 0, rotation about z only).

Shapes (metres): `box` (size = (width along x, height along y)), `sphere` (size = (radius,)),
`capsule` (size = (radius, length of the cylinder part); its axis is the body's local y),
`disc` (size = (outer radius, inner radius)): a wheel or tire turning in the plane, an annulus
of uniform density (inertia m (R^2 + r^2) / 2); it collides as a circle of the outer radius
(ODE's sphere geom, whose section by the plane is that circle and whose contacts lie on it).
Inertia about z follows the shape with uniform density (ODE's `Mass.set*Total`).
A prop may hang from a fixed point of the world (`Hanging`): a rigid massless rod when
`links` is 0 (a hinge about z at the anchor), else a chain of `links` small bodies joined by
z-axis hinges, the first one hinged to the anchor, the prop hinged to the last.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

PROP_SHAPES = ("box", "sphere", "capsule", "disc")
#: Out-of-plane thickness (m) of box props: it sets only the shape's z extent (which does not
#: enter the planar dynamics: the inertia about z of a box is m (w^2 + h^2) / 12).
PROP_DEPTH = 0.2
#: Friction coefficient of prop contacts (ground, other props, the character's hands).
PROP_FRICTION_MU = 0.8


@dataclass(frozen=True)
class Hanging:
    """The prop hangs from `anchor` (world x, y in m) by a rod (links = 0) or a chain."""

    anchor: tuple[float, float]
    links: int = 0
    link_mass: float = 0.1  # kg per link of a chain


@dataclass(frozen=True)
class PropDef:
    """One prop: shape, mass (kg), initial pose and velocity (m, rad, m/s, rad/s)."""

    name: str
    shape: str
    size: tuple[float, ...]
    mass: float
    position: tuple[float, float]
    angle: float = 0.0
    velocity: tuple[float, float] = (0.0, 0.0)
    angular_velocity: float = 0.0
    friction: float = PROP_FRICTION_MU
    hanging: Hanging | None = None
    #: Coefficient of restitution of the prop's contacts (ground, props, the character's
    #: geoms): the normal velocity after an impact is -restitution times the one before
    #: (ODE's contact bounce; 0, the default, is a plastic contact).
    restitution: float = 0.0

    def __post_init__(self) -> None:
        if self.shape not in PROP_SHAPES:
            raise ValueError(f"prop {self.name!r}: shape must be one of {', '.join(PROP_SHAPES)}")
        need = {"box": 2, "sphere": 1, "capsule": 2, "disc": 2}[self.shape]
        if len(self.size) != need or not all(s > 0 and math.isfinite(s) for s in self.size):
            raise ValueError(f"prop {self.name!r}: a {self.shape} needs {need} positive sizes")
        if self.shape == "disc" and not self.size[1] < self.size[0]:
            raise ValueError(f"prop {self.name!r}: a disc's inner radius must be below its outer")
        if not 0.0 <= self.restitution <= 1.0:
            raise ValueError(f"prop {self.name!r}: restitution must be in [0, 1]")
        if not (self.mass > 0 and math.isfinite(self.mass)):
            raise ValueError(f"prop {self.name!r}: mass must be positive")

    @property
    def inertia(self) -> float:
        """Moment of inertia about the z axis through the CoM (kg m^2), uniform density."""
        m = self.mass
        if self.shape == "box":
            w, h = self.size
            return m * (w * w + h * h) / 12.0
        if self.shape == "sphere":
            return 0.4 * m * self.size[0] ** 2
        if self.shape == "disc":
            return 0.5 * m * (self.size[0] ** 2 + self.size[1] ** 2)
        r, length = self.size
        # ODE's capsule: a cylinder of length `length` plus two hemispheres, uniform density.
        vc, vs = math.pi * r * r * length, 4.0 / 3.0 * math.pi * r**3
        mc, ms = m * vc / (vc + vs), m * vs / (vc + vs)
        cyl = mc * (0.25 * r * r + length * length / 12.0)
        caps = ms * (0.4 * r * r + 0.25 * length * length + 3.0 / 8.0 * r * length)
        return cyl + caps

