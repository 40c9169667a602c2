"""Machine limits and planner settings: frozen, validated data for ``motion.planner``."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from usbmotion.errors import PlanningError, SoftLimitError

AXIS_NAMES = ("X", "Y", "Z")


def _check_positive(name: str, value: float) -> None:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise PlanningError(
            f"{name} {value!r} is not a number; a positive finite number is required"
        )
    if not (math.isfinite(value) and value > 0):
        raise PlanningError(f"{name} {value!r} is invalid; a positive finite number is required")


@dataclass(frozen=True, slots=True)
class AxisLimits:
    """The limits of one axis.

    Fields:
        velocity_mm_s: the fastest the axis may move, mm/s (positive, finite).
        accel_mm_s2: the largest acceleration of the axis, mm/s^2 (positive, finite).

    Raises:
        PlanningError: a limit is zero, negative, NaN or infinite.
    """

    velocity_mm_s: float
    accel_mm_s2: float

    def __post_init__(self) -> None:
        _check_positive("velocity_mm_s", self.velocity_mm_s)
        _check_positive("accel_mm_s2", self.accel_mm_s2)


@dataclass(frozen=True, slots=True)
class PlannerConfig:
    """How the planner cuts arcs and takes corners.

    Fields:
        junction_deviation_mm: the grbl/Klipper cornering tolerance; a junction is taken at
            the speed of a circular turn of this deviation from the corner, at the junction's
            acceleration. 0.01 mm is grbl's default.
        arc_tolerance_mm: the largest distance between an arc and the chords that replace
            it (the chord sagitta), mm. 0.002 mm is grbl's default.
        min_segment_mm: moves shorter than this are dropped (their tiny displacement is
            carried into the next move), and arcs are never cut into chords shorter than it.
        continuity_tolerance_mm: the largest gap allowed between a move's start and the end
            of the previous move (or the plan's start) before the program is rejected.

    Rapids (G0) have no setting here: they run at the fastest speed the axis limits allow
    along their direction.

    Raises:
        PlanningError: a value is not a positive finite number.
    """

    junction_deviation_mm: float = 0.01
    arc_tolerance_mm: float = 0.002
    min_segment_mm: float = 1e-6
    continuity_tolerance_mm: float = 1e-6

    def __post_init__(self) -> None:
        _check_positive("junction_deviation_mm", self.junction_deviation_mm)
        _check_positive("arc_tolerance_mm", self.arc_tolerance_mm)
        _check_positive("min_segment_mm", self.min_segment_mm)
        _check_positive("continuity_tolerance_mm", self.continuity_tolerance_mm)


SOFT_LIMIT_SLACK_MM = 1e-9
"""How far past a travel end a coordinate may be and still count as on it (float noise)."""

SETTLED_BAND_COUNTS = 4
"""How far outside a travel end, in encoder counts, a machine may stand and still count as at
that end: twice the band a run settles within before it ends (``SETTLE_COUNTS``, 2 counts,
in ``usbmotion.session.report``), so a servo that settled at a travel end and was then
disabled at rest (the end of ``usbmotion run``, whose next run starts where the encoder
stands) is at that end, not outside it."""


def settled_band_mm(counts_per_mm: Sequence[float]) -> tuple[float, ...]:
    """:data:`SETTLED_BAND_COUNTS` in mm on each axis of ``counts_per_mm`` (counts per mm)."""
    return tuple(SETTLED_BAND_COUNTS / scale for scale in counts_per_mm)


def check_travel(vertices_mm: npt.ArrayLike, lines: npt.ArrayLike,
                 travel_mm: Sequence[tuple[float, float]],
                 *, axes: Sequence[str] = AXIS_NAMES,
                 band_mm: Sequence[float] | None = None) -> None:
    """Soft limits: refuse a path that leaves any axis's travel, before anything moves.

    A start outside the travel is where the machine stands, and a path may always come
    back from it: outside its travel an axis may stay where it stands (while others move)
    or move back toward its travel, never farther out than it has already come back to
    (each vertex outside a travel end no farther out than every vertex before it). A start
    within ``band_mm`` of a travel end counts as at that end (a servo settled there);
    from a start farther out (after a limit fault, an axis pushed by hand, a travel made
    shorter) the first segment must bring an axis that stands outside back toward its
    travel.

    Parameters:
        vertices_mm: (n + 1, k) machine positions of a plan's vertices: the start, then the
            end of every segment (every chord of every arc, so the whole path is checked:
            a straight segment between two points inside the travel stays inside).
        lines: (n,) the G-code line of each segment.
        travel_mm: (lowest, highest) machine position of each of the k axes.
        axes: the axes' letters, for the message.
        band_mm: how far outside a travel end each axis may stand and count as at that end
            (:func:`settled_band_mm`); none: 0 on every axis.

    Raises:
        SoftLimitError: the first vertex outside the travel (farther out than the start),
            naming the line, the axis, the coordinate and the limit; or a start beyond the
            band whose first segment brings no axis standing outside back (named as the
            first segment's line).
        PlanningError: the arrays, travels, axes and bands do not match.
    """
    points = np.asarray(vertices_mm, dtype=np.float64)
    segment_lines = np.asarray(lines, dtype=np.int64)
    if points.ndim != 2 or points.shape[1] != len(travel_mm) or len(axes) != len(travel_mm):
        raise PlanningError(f"vertices {points.shape} do not match {len(travel_mm)} travels"
                            f" and axes {tuple(axes)}")
    band = np.zeros(len(travel_mm)) if band_mm is None else np.asarray(band_mm, np.float64)
    if band.shape != (len(travel_mm),) or not np.all(np.isfinite(band) & (band >= 0)):
        raise PlanningError(f"band_mm {band_mm!r}: one distance >= 0 per axis of"
                            f" {tuple(axes)} is required")
    low = np.array([t[0] for t in travel_mm])
    high = np.array([t[1] for t in travel_mm])
    above = np.maximum(points - high, 0.0)
    below = np.maximum(low - points, 0.0)
    if points.shape[0] < 2:
        return
    beyond = (above[0] > band + SOFT_LIMIT_SLACK_MM) | (below[0] > band + SOFT_LIMIT_SLACK_MM)
    back = ((above[1] < above[0] - SOFT_LIMIT_SLACK_MM)
            | (below[1] < below[0] - SOFT_LIMIT_SLACK_MM))
    if beyond.any() and not (beyond & back).any():
        column = int(np.flatnonzero(beyond)[0])
        standing = [_standing(axes[i], float(points[0, i]), travel_mm[i], float(band[i]))
                    for i in map(int, np.flatnonzero(beyond))]
        line = int(segment_lines[0])
        lowest, highest = travel_mm[column]
        limit = lowest if below[0, column] > 0 else highest
        raise SoftLimitError(
            f"line {line}: the machine stands outside its travel ({'; '.join(standing)}):"
            " from there a program's first move must bring an axis that stands outside back"
            " toward its travel (jog it back, or home the machine); nothing was moved",
            line=line, axis=axes[column], coordinate_mm=float(points[0, column]),
            limit_mm=limit)
    allowed_above = np.minimum.accumulate(above[:-1], axis=0)
    allowed_below = np.minimum.accumulate(below[:-1], axis=0)
    outside = ((above[1:] > allowed_above + SOFT_LIMIT_SLACK_MM)
               | (below[1:] > allowed_below + SOFT_LIMIT_SLACK_MM))
    rows = np.flatnonzero(outside.any(axis=1))
    if rows.size == 0:
        return
    row = int(rows[0])
    column = int(np.flatnonzero(outside[row])[0])
    axis = axes[column]
    coordinate = float(points[row + 1, column])
    lowest, highest = travel_mm[column]
    below_end = coordinate < lowest
    limit = lowest if below_end else highest
    line = int(segment_lines[row])
    end = "lower" if below_end else "upper"
    start = float(points[0, column])
    came_from = ""
    unit, key = _unit(axis)
    if (below[0, column] if below_end else above[0, column]) > 0:
        came_from = (f", farther out than the {start:.3f} {unit} it started from: outside its"
                     " travel an axis may only come back")
    raise SoftLimitError(
        f"line {line}: {axis} would reach {coordinate:.3f} {unit}, beyond the {end} end"
        f" {limit:g} {unit} of axis {axis}'s {key} [{lowest:g}, {highest:g}]{came_from};"
        " nothing was moved",
        line=line, axis=axis, coordinate_mm=coordinate, limit_mm=limit)


def _standing(axis: str, coordinate_mm: float, travel_mm: tuple[float, float],
              band_mm: float) -> str:
    """``Z 0.500 mm, 0.500 mm above the upper end 0 mm of axis Z's travel_mm [-100, 0]``."""
    lowest, highest = travel_mm
    below = coordinate_mm < lowest
    side, limit = ("below the lower", lowest) if below else ("above the upper", highest)
    unit, key = _unit(axis)
    return (f"{axis} {coordinate_mm:.3f} {unit}, {abs(coordinate_mm - limit):.3f} {unit} {side}"
            f" end {limit:g} {unit} of axis {axis}'s {key} [{lowest:g}, {highest:g}], more than"
            f" the {band_mm:.4f} {unit} a settled servo may stand beyond it")


def _unit(axis: str) -> tuple[str, str]:
    """The unit of an axis and its travel's key: degrees for A B C."""
    return ("deg", "travel_deg") if axis in "ABC" else ("mm", "travel_mm")
