"""Machine limits and planner settings: frozen, validated data for ``motion.planner``."""

from __future__ import annotations

import math
from dataclasses import dataclass

from usbmotion.errors import PlanningError

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
