"""Re-planning the rest of a program from a point of its path: after a feed hold (from rest)
and when an override changes the speed (from the speed the machine has there).

A point of a program is a :class:`PathPoint`: a segment of the program's :class:`Plan` and
how far along it the machine is (and, in a dwell, how long it has dwelt). The rest of the
program from there is the segment's remainder and every segment after it, planned again
by the look-ahead planner with the same vertices, kinds and lines, so the path is the same
one; only the speeds differ: feed moves at ``feed_scale`` times their feed, rapids at
``rapid_scale`` times the fastest the axes allow along them, and every axis within its
velocity and acceleration limits as in any plan. The new plan starts at the speed the
machine has at the point (0 after a hold), so the velocity is continuous at the seam; when
the new speed of that segment is lower, its first piece is a deceleration at the
segment's acceleration from the old speed to the new one.

Pure functions and frozen dataclasses, no device and no clock.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import numpy.typing as npt

from usbmotion.errors import PlanningError
from usbmotion.motion.limits import AxisLimits, PlannerConfig
from usbmotion.motion.planner import Plan, SegmentKind, _plan_columns

__all__ = ["Leg", "PathPoint", "locate", "plan_rest", "whole_program"]

IntArray = npt.NDArray[np.int64]
FloatArray = npt.NDArray[np.float64]
SPEED_MATCH = 1e-6
"""Relative tolerance of the new plan's entry speed against the speed asked for."""


@dataclass(frozen=True, slots=True)
class PathPoint:
    """A point of a program's path.

    Fields:
        segment: the program plan's segment the point is on (``len(plan)`` at the end).
        distance_mm: how far along that segment, mm.
        dwelt_s: in a dwell, how long of it has passed, s.
        position_mm: the point, mm (one coordinate per axis of the plan).
        speed_mm_s: the path speed there, mm/s.
        program_time_s: when the uninterrupted program passes the point, s.
    """

    segment: int
    distance_mm: float
    dwelt_s: float
    position_mm: tuple[float, ...]
    speed_mm_s: float
    program_time_s: float

    @property
    def at_end(self) -> bool:
        """True when nothing of the program is left."""
        return self.segment < 0


@dataclass(frozen=True, slots=True)
class Leg:
    """A stretch of a program planned from a point: the plan, and for each of its segments
    the program's segment it lies on and how far along that segment it starts.

    Fields:
        plan: the plan of the stretch (its time 0 is the point it starts from).
        source: (n,) the program plan's segment of each segment.
        offset_mm: (n,) where each segment starts along its program segment, mm.
        offset_s: (n,) in a dwell, how much of the program's dwell was done before it, s.
    """

    plan: Plan
    source: IntArray
    offset_mm: FloatArray
    offset_s: FloatArray


def whole_program(plan: Plan) -> Leg:
    """The whole program as one leg (its own plan)."""
    count = len(plan)
    return Leg(plan, np.arange(count, dtype=np.int64), np.zeros(count), np.zeros(count))


class _Trapezoid(NamedTuple):
    """One segment's speed profile: duration (s), acceleration (mm/s^2), entry, cruise and
    exit speeds (mm/s), acceleration and cruise times (s), length (mm)."""

    segment_s: float
    a: float
    v_entry: float
    v_cruise: float
    v_exit: float
    t_accel: float
    t_cruise: float
    length: float


def _trapezoid(plan: Plan, index: int) -> _Trapezoid:
    """Segment ``index``'s profile as Python floats."""
    return _Trapezoid(
        float(plan.segment_duration_s[index]), float(plan.accel_mm_s2[index]),
        float(plan.v_entry_mm_s[index]), float(plan.v_cruise_mm_s[index]),
        float(plan.v_exit_mm_s[index]), float(plan.t_accel_s[index]),
        float(plan.t_cruise_s[index]), float(plan.length_mm[index]))


def _segment_state(plan: Plan, index: int, elapsed_s: float) -> tuple[float, float]:
    """Distance along segment ``index`` and path speed, ``elapsed_s`` after its start."""
    if plan.kind[index] == SegmentKind.DWELL:
        return 0.0, 0.0
    segment_s, a, v_entry, v_cruise, v_exit, t_accel, t_cruise, length = _trapezoid(plan, index)
    t = min(max(elapsed_s, 0.0), segment_s)
    if t < t_accel:
        return v_entry * t + 0.5 * a * t * t, v_entry + a * t
    if t < t_accel + t_cruise:
        s_accel = v_entry * t_accel + 0.5 * a * t_accel * t_accel
        return s_accel + v_cruise * (t - t_accel), v_cruise
    left = max(0.0, segment_s - t)
    return max(0.0, length - (v_exit * left + 0.5 * a * left * left)), v_exit + a * left


def locate(program: Plan, leg: Leg, time_s: float) -> PathPoint:
    """The point of ``program`` where ``leg`` is ``time_s`` after its start.

    Raises:
        PlanningError: a time that is not finite.
    """
    if not math.isfinite(time_s):
        raise PlanningError(f"time_s {time_s!r} is not finite")
    plan = leg.plan
    if len(plan) == 0 or time_s >= plan.duration_s:
        end = program.vertices_mm[-1]
        return PathPoint(-1, 0.0, 0.0, tuple(float(c) for c in end), 0.0, program.duration_s)
    index = max(0, int(np.searchsorted(plan.start_time_s, time_s, side="right")) - 1)
    elapsed = time_s - float(plan.start_time_s[index])
    distance, speed = _segment_state(plan, index, elapsed)
    position = plan.vertices_mm[index] + plan.unit[index] * distance
    source = int(leg.source[index])
    along = float(leg.offset_mm[index]) + distance
    dwelt = float(leg.offset_s[index]) + (elapsed if plan.kind[index] == SegmentKind.DWELL
                                          else 0.0)
    program_time = float(program.start_time_s[source]) + _time_along(program, source, along,
                                                                     dwelt)
    return PathPoint(source, along, dwelt, tuple(float(c) for c in position), speed,
                     program_time)


def _time_along(plan: Plan, index: int, distance_mm: float, dwelt_s: float) -> float:
    """When the program's own plan is ``distance_mm`` along segment ``index``: the
    trapezoid's distance inverted phase by phase (accelerate, cruise, decelerate)."""
    if plan.kind[index] == SegmentKind.DWELL:
        return dwelt_s
    segment_s, a, v_entry, v_cruise, v_exit, t_accel, t_cruise, length = _trapezoid(plan, index)
    s = min(max(distance_mm, 0.0), length)
    s_accel = v_entry * t_accel + 0.5 * a * t_accel * t_accel
    if s <= s_accel and t_accel > 0.0:
        return min(t_accel, _time_to_cover(s, v_entry, a))
    s_cruised = s_accel + v_cruise * t_cruise
    if s <= s_cruised and t_cruise > 0.0:
        return t_accel + (s - s_accel) / v_cruise if v_cruise > 0.0 else t_accel
    left = _time_to_cover(length - s, v_exit, a)
    return min(segment_s, max(t_accel + t_cruise, segment_s - left))


def _time_to_cover(distance_mm: float, v_mm_s: float, a_mm_s2: float) -> float:
    """The time to cover ``distance_mm`` from speed ``v_mm_s`` gaining ``a_mm_s2``."""
    if distance_mm <= 0.0:
        return 0.0
    if a_mm_s2 <= 0.0:
        return distance_mm / v_mm_s if v_mm_s > 0.0 else 0.0
    root = math.sqrt(v_mm_s * v_mm_s + 2.0 * a_mm_s2 * distance_mm)
    # (root - v) / a without the cancellation of two near-equal numbers
    return 2.0 * distance_mm / (root + v_mm_s)


def plan_rest(
    program: Plan,
    point: PathPoint,
    limits: Sequence[AxisLimits],
    config: PlannerConfig,
    *,
    feed_scale: float = 1.0,
    rapid_scale: float = 1.0,
) -> Leg | None:
    """The rest of ``program`` from ``point``, planned from the speed the machine has
    there (``point.speed_mm_s``): ``None`` when nothing is left.

    Parameters:
        program: the program's plan (the one run from its start, at 100 %).
        point: where the rest starts (:func:`locate`).
        limits: each program axis's limits; config: the planner's settings (as the
            program's).
        feed_scale: feed moves at this times their feed (0.1 .. 2).
        rapid_scale: rapids at this times the fastest the axes allow (0 < scale <= 1).

    Raises:
        PlanningError: a scale out of its range, or a new plan that cannot start at the
            point's speed (the rest of the segment is too short to slow down to what the
            new speeds allow at its end: re-plan from a later point).
    """
    if not (math.isfinite(feed_scale) and 0.0 < feed_scale <= 2.0):
        raise PlanningError(f"feed_scale {feed_scale!r} must be within (0, 2]")
    if not (math.isfinite(rapid_scale) and 0.0 < rapid_scale <= 1.0):
        raise PlanningError(f"rapid_scale {rapid_scale!r} must be within (0, 1]")
    if point.at_end or point.segment >= len(program):  # nothing left (yet)
        return None
    first = point.segment
    count = len(program)
    minimum = config.min_segment_mm
    length = program.length_mm
    remaining = float(length[first]) - point.distance_mm
    kinds: list[int] = []
    feeds: list[float] = []
    dwells: list[float] = []
    ends: list[npt.NDArray[np.float64]] = []
    source: list[int] = []
    offsets: list[float] = []
    offsets_s: list[float] = []
    inv_v = np.array([1.0 / a.velocity_mm_s for a in limits])

    def speed_of(index: int) -> float:
        kind = int(program.kind[index])
        if kind == SegmentKind.RAPID:
            fastest = 1.0 / float(np.max(np.abs(program.unit[index]) * inv_v))
            return rapid_scale * fastest
        if kind == SegmentKind.DWELL:
            return 0.0
        return feed_scale * float(program.feed_mm_s[index])

    def add(index: int, end: npt.NDArray[np.float64], speed: float, offset: float,
            *, dwell_s: float = 0.0, offset_s: float = 0.0) -> None:
        kinds.append(int(program.kind[index]))
        feeds.append(speed * 60.0)
        dwells.append(dwell_s)
        ends.append(end)
        source.append(index)
        offsets.append(offset)
        offsets_s.append(offset_s)

    start = np.array(point.position_mm, dtype=np.float64)
    entry = point.speed_mm_s
    if program.kind[first] == SegmentKind.DWELL:
        left_s = float(program.t_cruise_s[first]) - point.dwelt_s
        if left_s > 0.0:
            add(first, start, 0.0, 0.0, dwell_s=left_s, offset_s=point.dwelt_s)
        entry = 0.0
    elif remaining > minimum:
        unit = program.unit[first]
        new_speed = speed_of(first)
        axis_speed = 1.0 / float(np.max(np.abs(unit) * inv_v))
        new_speed = min(new_speed, axis_speed)
        ramp = (entry * entry - new_speed * new_speed) / (2.0 * float(program.accel_mm_s2[first]))
        ramp *= 1.0 + 1e-6
        if entry > new_speed and minimum < ramp and ramp + minimum < remaining:
            add(first, start + unit * ramp, entry, point.distance_mm)
            add(first, program.vertices_mm[first + 1].copy(), new_speed,
                point.distance_mm + ramp)
        else:
            add(first, program.vertices_mm[first + 1].copy(), max(new_speed, entry),
                point.distance_mm)
    for index in range(first + 1, count):
        if program.kind[index] == SegmentKind.DWELL:
            add(index, program.vertices_mm[index].copy(), 0.0, 0.0,
                dwell_s=float(program.t_cruise_s[index]))
        else:
            add(index, program.vertices_mm[index + 1].copy(), speed_of(index), 0.0)
    if not kinds:
        return None
    total = len(kinds)
    lines = program.line[np.array(source, dtype=np.int64)]
    plan = _plan_columns(
        origin=tuple(float(c) for c in start),
        limits=tuple(limits),
        config=config,
        move_count=total,
        total=total,
        item_kind=kinds,
        item_line=[int(line) for line in lines],
        item_feed=feeds,
        item_dwell=dwells,
        item_count=[1] * total,
        ends=[tuple(float(c) for c in end) for end in ends],
        arc_rows=[],
        arc_planes=[],
        axes=program.axes,
        entry_speed_mm_s=entry,
    )
    reached = float(plan.v_entry_mm_s[0]) if len(plan) else 0.0
    if reached < entry * (1.0 - SPEED_MATCH) - 1e-9:
        raise PlanningError(
            f"the rest of the program from {point.position_mm} cannot start at"
            f" {entry!r} mm/s at these speeds (at most {reached!r}): re-plan from later")
    return Leg(plan, np.array(source, dtype=np.int64), np.array(offsets, dtype=np.float64),
               np.array(offsets_s, dtype=np.float64))
