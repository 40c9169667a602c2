"""Rapids into the stock: a program's rapid that goes below work Z0 where the stock is, found
before the program runs (a report, not a refusal: the program still runs).

A rapid (G0, or a canned cycle's rapid) below work Z0 inside the stock plunges the tool into
the material at the axes' full speed. The controller does not know the stock; it takes the
stock's XY extent from the program itself: the XY bounding box, in machine coordinates, of
the program's cutting moves (G1, G2, G3 and the feed moves of canned cycles) where they are
at or below work Z0. Work Z is the tool tip's Z in the program's own coordinates, machine Z
less the G5x, G92 and tool length offsets the move was made in
(:attr:`usbmotion.motion.gcode.GCodeProgram.frames`), so work Z0 is the stock's top.

A rapid counts when any part of it below work Z0 lies in that extent (its edges included),
except a rapid straight along Z that goes up (a retract out of a cut), or that goes down at
an XY where an earlier cutting move already went at least as deep (a peck drilling cycle's
return into its hole). The check runs over the planned path, so every chord of an arc and
every move of a canned cycle is seen.

Pure functions and frozen data: no device, no clock.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from usbmotion.motion.gcode import GCodeProgram
from usbmotion.motion.planner import Plan, SegmentKind

WARNINGS_SHOWN = 5
"""How many rapids :func:`plunge_warnings` words in full; the others are counted, by line."""
PLUNGE_TOLERANCE_MM = 1e-6
"""How far below work Z0 a rapid must go, or how far inside the extent, to count (float
noise): a rapid to exactly Z0 is not below it."""
LINES_NAMED = 20
"""How many more such rapids the last warning names by line."""

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True, slots=True)
class RapidPlunge:
    """A rapid that goes below work Z0 inside the stock's XY extent.

    Fields:
        line: the G-code line of the rapid.
        z_mm: the lowest work Z it reaches inside the extent (the tool tip in program
            coordinates), mm.
        x_mm, y_mm: the machine X and Y where it reaches it, mm.
        extent_mm: the stock's XY extent, machine coordinates: ``((x_low, x_high),
            (y_low, y_high))``, mm.
    """

    line: int
    z_mm: float
    x_mm: float
    y_mm: float
    extent_mm: tuple[tuple[float, float], tuple[float, float]]

    @property
    def message(self) -> str:
        """The warning in words: the line, the Z it reaches, where, and why it matters."""
        (x_low, x_high), (y_low, y_high) = self.extent_mm
        return (f"line {self.line}: a rapid reaches work Z {self.z_mm:.3f} mm, below work Z0,"
                f" at machine X {self.x_mm:.3f} Y {self.y_mm:.3f} mm, inside the stock's XY"
                f" extent X {x_low:.3f}..{x_high:.3f} Y {y_low:.3f}..{y_high:.3f} mm (where the"
                " program cuts at or below work Z0): it would plunge into the stock at rapid"
                " speed")


def rapid_plunges(program: GCodeProgram, plan: Plan) -> tuple[RapidPlunge, ...]:
    """The rapids of a planned program that go below work Z0 inside the stock's XY extent
    (the module docstring says how both are found), one per line, in program order.

    ``plan`` is ``program``'s plan (:func:`usbmotion.motion.planner.plan_moves` of its
    moves). A machine without X, Y and Z, or a program that never cuts at or below work Z0,
    has none.
    """
    axes = plan.axes
    if not all(letter in axes for letter in "XYZ") or len(plan) == 0:
        return ()
    ix, iy, iz = (axes.index(letter) for letter in "XYZ")
    vertices = np.asarray(plan.vertices_mm, dtype=np.float64)
    start, end = vertices[:-1], vertices[1:]
    offset_z = _offsets_z(program, np.asarray(plan.line), program.axes.index("Z"))
    z0, z1 = start[:, iz] - offset_z, end[:, iz] - offset_z
    kind = np.asarray(plan.kind)
    tolerance = PLUNGE_TOLERANCE_MM

    cutting = ((kind == SegmentKind.LINEAR) | (kind == SegmentKind.ARC)) & (
        np.minimum(z0, z1) <= tolerance)
    if not cutting.any():
        return ()
    low_a, low_b = _part_below(z0[cutting], z1[cutting], tolerance)
    xy = np.stack((start[cutting][:, [ix, iy]], end[cutting][:, [ix, iy]]))
    near = xy[0] + low_a[:, None] * (xy[1] - xy[0])
    far = xy[0] + low_b[:, None] * (xy[1] - xy[0])
    ends = np.vstack((near, far))
    extent = ((float(ends[:, 0].min()), float(ends[:, 0].max())),
              (float(ends[:, 1].min()), float(ends[:, 1].max())))

    rapid = (kind == SegmentKind.RAPID) & (np.minimum(z0, z1) < -tolerance)
    found: list[RapidPlunge] = []
    lines_seen: set[int] = set()
    for index in map(int, np.flatnonzero(rapid)):
        line = int(plan.line[index])
        if line in lines_seen:
            continue
        a, b = start[index], end[index]
        below = _part_below(np.array([z0[index]]), np.array([z1[index]]), -tolerance)
        lowest = _lowest_inside(a, b, float(z0[index]), float(z1[index]),
                                (float(below[0][0]), float(below[1][0])), (ix, iy), extent)
        if lowest is None:
            continue
        if abs(b[ix] - a[ix]) <= tolerance and abs(b[iy] - a[iy]) <= tolerance and (
                z1[index] >= z0[index]
                or _cut_as_deep(index, a[ix], a[iy], float(z1[index]), start, end, z0, z1,
                                cutting, (ix, iy))):
            continue
        z_mm, x_mm, y_mm = lowest
        lines_seen.add(line)
        found.append(RapidPlunge(line, z_mm, x_mm, y_mm, extent))
    return tuple(found)


def plunge_warnings(plunges: tuple[RapidPlunge, ...]) -> tuple[str, ...]:
    """The warnings a run shows for these rapids: the first :data:`WARNINGS_SHOWN` in full,
    then one line counting the others and naming their lines (a program whose work Z0 is
    wrong has a rapid into the stock in every figure)."""
    shown = tuple(plunge.message for plunge in plunges[:WARNINGS_SHOWN])
    rest = plunges[WARNINGS_SHOWN:]
    if not rest:
        return shown
    lines = ", ".join(str(plunge.line) for plunge in rest[:LINES_NAMED])
    more = f" and {len(rest) - LINES_NAMED} more" if len(rest) > LINES_NAMED else ""
    return (*shown, f"{len(rest)} more rapids reach below work Z0 inside the stock's XY"
                    f" extent: lines {lines}{more}")


def _offsets_z(program: GCodeProgram, lines: npt.NDArray[np.int64], z: int) -> FloatArray:
    """The Z offset (G5x + G92 + tool) each segment of these lines was made in: a program's
    offsets change only between lines, so a frame from a move on holds for its line on."""
    frames = program.frames or ((0, (0.0,) * len(program.axes)),)
    moves = program.moves
    never = np.iinfo(np.int64).max
    frame_lines = np.array([moves[index].line if index < len(moves) else never
                            for index, _ in frames], dtype=np.int64)
    values = np.array([offset[z] for _, offset in frames], dtype=np.float64)
    which = np.searchsorted(frame_lines, lines, side="right") - 1
    return values[np.maximum(which, 0)]


def _part_below(z0: FloatArray, z1: FloatArray, level: float) -> tuple[FloatArray, FloatArray]:
    """For segments from ``z0`` to ``z1``, the fractions ``(a, b)`` of their length between
    which they are at or below ``level`` (``a > b`` where none is)."""
    rise = z1 - z0
    with np.errstate(divide="ignore", invalid="ignore"):
        cross = np.clip(np.where(rise != 0.0, (level - z0) / rise, 0.0), 0.0, 1.0)
    below0, below1 = z0 <= level, z1 <= level
    a = np.where(below0, 0.0, np.where(below1, cross, 1.0))
    b = np.where(below1, 1.0, np.where(below0, cross, 0.0))
    return a, b


def _lowest_inside(a: FloatArray, b: FloatArray, z0: float, z1: float,
                   below: tuple[float, float], xy: tuple[int, int],
                   extent: tuple[tuple[float, float], tuple[float, float]],
                   ) -> tuple[float, float, float] | None:
    """The lowest point (work Z, machine X, machine Y) of the part ``below`` (fractions of
    the segment from ``a`` to ``b``) that lies in the XY ``extent``, or None."""
    enter, leave = below
    tolerance = PLUNGE_TOLERANCE_MM
    for axis, (low, high) in zip(xy, extent, strict=True):
        origin, step = float(a[axis]), float(b[axis] - a[axis])
        if abs(step) <= 1e-15:
            if not low - tolerance <= origin <= high + tolerance:
                return None
            continue
        first = (low - tolerance - origin) / step
        second = (high + tolerance - origin) / step
        enter = max(enter, min(first, second))
        leave = min(leave, max(first, second))
    if enter > leave:
        return None
    at = enter if z0 + enter * (z1 - z0) <= z0 + leave * (z1 - z0) else leave
    point = a + at * (b - a)
    return z0 + at * (z1 - z0), float(point[xy[0]]), float(point[xy[1]])


def _cut_as_deep(index: int, x_mm: float, y_mm: float, z_mm: float, start: FloatArray,
                 end: FloatArray, z0: FloatArray, z1: FloatArray,
                 cutting: npt.NDArray[np.bool_], xy: tuple[int, int]) -> bool:
    """True when a cutting segment before ``index`` reached work Z ``z_mm`` or deeper at the
    machine XY ``(x_mm, y_mm)`` (at one of its ends)."""
    tolerance = PLUNGE_TOLERANCE_MM
    earlier = cutting[:index]
    ix, iy = xy
    for points, depth in ((start[:index], z0[:index]), (end[:index], z1[:index])):
        there = (earlier & (np.abs(points[:, ix] - x_mm) <= tolerance)
                 & (np.abs(points[:, iy] - y_mm) <= tolerance)
                 & (depth <= z_mm + tolerance))
        if there.any():
            return True
    return False
