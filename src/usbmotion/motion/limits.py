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


def check_travel(vertices_mm: npt.ArrayLike, lines: npt.ArrayLike,
                 travel_mm: Sequence[tuple[float, float]],
                 *, axes: Sequence[str] = AXIS_NAMES) -> None:
    """Soft limits: refuse a path that leaves any axis's travel, before anything moves.

    Parameters:
        vertices_mm: (n + 1, k) machine positions of a plan's vertices: the start, then the
            end of every segment (every chord of every arc, so the whole path is checked:
            a straight segment between two points inside the travel stays inside).
        lines: (n,) the G-code line of each segment.
        travel_mm: (lowest, highest) machine position of each of the k axes.
        axes: the axes' letters, for the message.

    Raises:
        SoftLimitError: the first vertex outside the travel, naming the line, the axis, the
            coordinate and the limit (the start itself outside is named as line 0, where
            the machine stands).
    """
    points = np.asarray(vertices_mm, dtype=np.float64)
    segment_lines = np.asarray(lines, dtype=np.int64)
    if points.ndim != 2 or points.shape[1] != len(travel_mm) or len(axes) != len(travel_mm):
        raise PlanningError(f"vertices {points.shape} do not match {len(travel_mm)} travels"
                            f" and axes {tuple(axes)}")
    low = np.array([t[0] for t in travel_mm]) - SOFT_LIMIT_SLACK_MM
    high = np.array([t[1] for t in travel_mm]) + SOFT_LIMIT_SLACK_MM
    outside = (points < low) | (points > high)
    rows = np.flatnonzero(outside.any(axis=1))
    if rows.size == 0:
        return
    row = int(rows[0])
    column = int(np.flatnonzero(outside[row])[0])
    axis = axes[column]
    coordinate = float(points[row, column])
    lowest, highest = travel_mm[column]
    below = coordinate < lowest
    limit = lowest if below else highest
    travel = f"travel_mm [{lowest:g}, {highest:g}]"
    if row == 0:
        raise SoftLimitError(
            f"the machine stands at {axis} {coordinate:.3f} mm, outside axis {axis}'s"
            f" {travel}: a program cannot start there (home the machine, or jog it back"
            " inside its travel)", line=0, axis=axis, coordinate_mm=coordinate,
            limit_mm=limit)
    line = int(segment_lines[row - 1])
    end = "lower" if below else "upper"
    raise SoftLimitError(
        f"line {line}: {axis} would reach {coordinate:.3f} mm, beyond the {end} end"
        f" {limit:g} mm of axis {axis}'s {travel}; nothing was moved",
        line=line, axis=axis, coordinate_mm=coordinate, limit_mm=limit)
