"""The typed moves a G-code program turns into: plain frozen data, lengths in mm.

These are the interface between the interpreter (``motion.gcode``) and the planner
(``motion.planner``). Coordinates are absolute machine positions ``(x, y, z)`` in mm.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum

Vec3 = tuple[float, float, float]


class Plane(Enum):
    """The arc plane, with the axis indices LinuxCNC uses for (first, second, normal)."""

    XY = "XY"  # G17: first X, second Y, normal Z
    XZ = "XZ"  # G18: first Z, second X, normal Y (LinuxCNC puts Z first)
    YZ = "YZ"  # G19: first Y, second Z, normal X

    @property
    def axes(self) -> tuple[int, int, int]:
        """Indices into ``(x, y, z)`` of the first, second and normal axis."""
        return _PLANE_AXES[self]


_PLANE_AXES = {Plane.XY: (0, 1, 2), Plane.XZ: (2, 0, 1), Plane.YZ: (1, 2, 0)}


@dataclass(frozen=True, slots=True)
class Rapid:
    """G0: straight move at the axes' own limits."""

    line: int
    start: Vec3
    end: Vec3


@dataclass(frozen=True, slots=True)
class Linear:
    """G1: straight move at the programmed feed."""

    line: int
    start: Vec3
    end: Vec3
    feed_mm_min: float


@dataclass(frozen=True, slots=True)
class Arc:
    """G2/G3: circular or helical move.

    ``centre`` is the absolute centre; its coordinate along the plane normal is the
    start's (it carries no meaning). ``rotation`` is LinuxCNC's turn count: -P for G2
    (clockwise), +P for G3, so -1 / +1 is one ordinary pass and a full circle has
    ``end == start`` in the plane. The end may differ from the start along the normal
    (a helix).
    """

    line: int
    start: Vec3
    end: Vec3
    centre: Vec3
    plane: Plane
    rotation: int
    feed_mm_min: float

    @property
    def clockwise(self) -> bool:
        """True for G2."""
        return self.rotation < 0


@dataclass(frozen=True, slots=True)
class Dwell:
    """G4: stay at ``position`` for ``seconds``."""

    line: int
    position: Vec3
    seconds: float


Move = Rapid | Linear | Arc | Dwell
