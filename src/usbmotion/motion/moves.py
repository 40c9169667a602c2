"""The typed moves a G-code program turns into: plain frozen data, lengths in mm.

These are the interface between the interpreter (``motion.gcode``) and the planner
(``motion.planner``). Coordinates are absolute machine positions in mm (degrees for the
rotary axes A B C), one per axis of the program's axis set (:data:`AXIS_ORDER`'s letters the
machine has, in that order; ``"XYZ"`` by default, so a point is ``(x, y, z)``).

A feed move's ``feed_mm_min`` is the speed along its path as the planner measures it, every
axis's coordinate alike (mm and degrees): the programmed feed on a machine of linear axes X Y
Z; where rotary (or U V W) axes move too, the feed that gives the move the time LinuxCNC
gives it (``motion.gcode``: F along the X Y Z length, or 1/F minutes in G93).
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum

Point = tuple[float, ...]
"""A machine position in mm, one coordinate per axis of the program's axis set."""

AXIS_ORDER = "XYZABCUVW"
"""The axes G-code can move, in LinuxCNC's order; an axis set is a subsequence."""
ROTARY_AXES = "ABC"
"""The rotary axes: their coordinates are degrees (whatever G20/G21 say)."""
DEFAULT_AXES = "XYZ"


class Plane(Enum):
    """The arc plane, with the axis indices LinuxCNC uses for (first, second, normal)."""

    XY = "XY"  # G17: first X, second Y, normal Z
    XZ = "XZ"  # G18: first Z, second X, normal Y (LinuxCNC puts Z first)
    YZ = "YZ"  # G19: first Y, second Z, normal X

    @property
    def axes(self) -> tuple[int, int, int]:
        """Indices into ``(x, y, z)`` of the first, second and normal axis."""
        return _PLANE_AXES[self]

    @property
    def letters(self) -> tuple[str, str, str]:
        """The letters of the first, second and normal axis: ``("Z", "X", "Y")`` for XZ."""
        return _PLANE_LETTERS[self]

    def indices(self, axes: str) -> tuple[int, int, int]:
        """Indices into a point of the axis set ``axes`` of the first, second and normal
        axis; the normal is -1 when the set lacks it (no helix is possible then).

        Raises:
            ValueError: the set lacks one of the plane's two axes (the message names it).
        """
        first, second, normal = _PLANE_LETTERS[self]
        for letter in (first, second):
            if letter not in axes:
                raise ValueError(
                    f"the {self.value} plane needs axis {letter}, which axes {axes!r} lack"
                )
        return axes.index(first), axes.index(second), axes.find(normal)


_PLANE_AXES = {Plane.XY: (0, 1, 2), Plane.XZ: (2, 0, 1), Plane.YZ: (1, 2, 0)}
_PLANE_LETTERS = {Plane.XY: ("X", "Y", "Z"), Plane.XZ: ("Z", "X", "Y"), Plane.YZ: ("Y", "Z", "X")}


@dataclass(frozen=True, slots=True)
class Rapid:
    """G0: straight move at the axes' own limits."""

    line: int
    start: Point
    end: Point


@dataclass(frozen=True, slots=True)
class Linear:
    """G1: straight move at the programmed feed."""

    line: int
    start: Point
    end: Point
    feed_mm_min: float


@dataclass(frozen=True, slots=True)
class Arc:
    """G2/G3: circular or helical move.

    ``centre`` is the absolute centre; its coordinate along the plane normal (when the
    axis set has the normal axis) is the start's (it carries no meaning). ``rotation`` is
    LinuxCNC's turn count: -P for G2 (clockwise), +P for G3, so -1 / +1 is one ordinary
    pass and a full circle has ``end == start`` in the plane. The end may differ from the
    start along the normal (a helix).
    """

    line: int
    start: Point
    end: Point
    centre: Point
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
    position: Point
    seconds: float


Move = Rapid | Linear | Arc | Dwell


def start_of(move: Move) -> Point:
    """Where ``move`` starts (a dwell: where it stays)."""
    return move.position if isinstance(move, Dwell) else move.start
