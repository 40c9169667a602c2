"""The setpoints a run streams, as legs of its program: no device, no clock.

A run streams rows of setpoints (one per motion period, one column per program axis) since
its last start from rest. They are a sequence of *legs*, each the rest of the program
planned from a point of its path (:mod:`usbmotion.motion.replanning`): the first from the
start, then one for every override, every join of more moves and every resume. Row ``r``
of the setpoints is due ``r`` motion periods after the start; :class:`Legs` says where on
the program each row is, which line it executes and when the uninterrupted program passes
there.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from usbmotion.motion.gcode import Pause
from usbmotion.motion.limits import AxisLimits, PlannerConfig
from usbmotion.motion.moves import Dwell, Move
from usbmotion.motion.planner import Plan, SegmentKind
from usbmotion.motion.replanning import Leg, PathPoint, locate, plan_rest, whole_program
from usbmotion.motion.sampler import sample_plan

Rows = npt.NDArray[np.int32]


def pause_segments(plan: Plan, moves: Sequence[Move], pauses: Sequence[Pause]) -> list[int]:
    """The plan's segment of each pause: its zero-second dwell (dwells are never merged
    or dropped, so the k-th dwell move is the k-th dwell segment)."""
    if not pauses:
        return []
    dwell_segments = np.flatnonzero(plan.kind == SegmentKind.DWELL)
    ordinal: dict[int, int] = {}
    for index, move in enumerate(moves):
        if isinstance(move, Dwell):
            ordinal[index] = len(ordinal)
    return [int(dwell_segments[ordinal[pause.move]]) for pause in pauses
            if ordinal.get(pause.move, len(dwell_segments)) < len(dwell_segments)]


@dataclass(frozen=True, slots=True)
class RowPlace:
    """Where a row of the setpoints is on the program: the line it executes, when the
    uninterrupted program passes there (s) and the path speed there (mm/s)."""

    line: int
    program_time_s: float
    speed_mm_s: float
    segment: int


class Legs:
    """The rows a run streams and the legs of the program they come from.

    Parameters:
        plan: the program's plan (from its start, at 100 %).
        period_s: the motion period, s.
        counts_per_mm: each program axis's scale.
        limits, planner: the planner's inputs for the program's axes.
        overrides: the feed and rapid overrides, percent.
    """

    def __init__(self, plan: Plan, *, period_s: float, counts_per_mm: Sequence[float],
                 limits: Sequence[AxisLimits], planner: PlannerConfig,
                 overrides: tuple[int, int] = (100, 100)) -> None:
        self.plan = plan
        self.period_s = period_s
        self.counts_per_mm = list(counts_per_mm)
        self.limits = limits
        self.planner = planner
        self.overrides = overrides
        first = whole_program(plan)
        if overrides != (100, 100):
            first = self.plan_rest(locate(plan, first, 0.0)) or first
        self.legs: list[tuple[int, Leg]] = [(0, first)]
        """The legs streamed since the last start, each with the row it starts on."""
        self.rows: Rows = self.sample(first)
        """The setpoints since the last start or resume."""
        self.rows_before = 0
        """Rows executed before the last start (earlier legs from rest)."""

    @property
    def count(self) -> int:
        """Rows since the last start."""
        return int(self.rows.shape[0])

    def sample(self, leg: Leg) -> Rows:
        """The setpoints of ``leg``."""
        return sample_plan(leg.plan, period_s=self.period_s, counts_per_mm=self.counts_per_mm)

    def plan_rest(self, point: PathPoint) -> Leg | None:
        """The rest of the program from ``point`` at the overrides (None: nothing left).

        Raises:
            PlanningError: the rest cannot start at the point's speed (try a later point).
        """
        feed, rapid = self.overrides
        return plan_rest(self.plan, point, self.limits, self.planner,
                         feed_scale=feed / 100.0, rapid_scale=rapid / 100.0)

    def leg_at(self, row: float) -> tuple[int, Leg]:
        """The leg row ``row`` belongs to, and the row it starts on."""
        found = self.legs[0]
        for first, leg in self.legs:
            if first <= row:
                found = (first, leg)
        return found

    def point_at(self, row: int) -> PathPoint:
        """The point of the program where row ``row`` is (after the end of its leg: that
        end, at rest, on the segment after the leg's last)."""
        first, leg = self.leg_at(row)
        elapsed = (row - first) * self.period_s
        if len(leg.plan) and elapsed < leg.plan.duration_s:
            return locate(self.plan, leg, elapsed)
        end = leg.plan.vertices_mm[-1]
        segment = int(leg.source[-1]) + 1 if len(leg.plan) else 0
        when = (float(self.plan.start_time_s[segment]) if segment < len(self.plan)
                else self.plan.duration_s)
        # past the program's last segment so far: the segment the next move will make
        # (the rest from here is none until the program grows)
        return PathPoint(segment, 0.0, 0.0, tuple(float(c) for c in end), 0.0, when)

    def whole(self) -> bool:
        """Whether the rows are the program's own plan from its start (no seam yet)."""
        return (self.rows_before == 0 and len(self.legs) == 1
                and self.legs[0][1].plan is self.plan)

    def program_time_s(self, row: float) -> float:
        """When the uninterrupted program passes where row ``row`` is."""
        if self.whole():
            return row * self.period_s
        first, leg = self.leg_at(row)
        return locate(self.plan, leg, (row - first) * self.period_s).program_time_s

    def place(self, row: float) -> RowPlace:
        """Where row ``row`` is on the program (clamped to the rows there are)."""
        row = min(max(row, 0.0), max(self.count - 1, 0))
        plan = self.plan
        if not len(plan):
            return RowPlace(0, 0.0, 0.0, 0)
        first, leg = self.leg_at(row)
        point = locate(plan, leg, (row - first) * self.period_s)
        segment = point.segment if point.segment >= 0 else len(plan) - 1
        return RowPlace(int(plan.line[segment]), point.program_time_s, point.speed_mm_s,
                        point.segment)

    def segments(self, rows: npt.NDArray[np.float64]) -> npt.NDArray[np.int64]:
        """:meth:`place`'s ``segment`` of each of ``rows`` at once (-1 past the end of a
        row's leg)."""
        out = np.full(rows.shape, -1, dtype=np.int64)
        if not len(self.plan):
            return np.zeros(rows.shape, dtype=np.int64)
        rows = np.clip(rows, 0.0, max(self.count - 1, 0))
        firsts = np.array([first for first, _ in self.legs], dtype=np.float64)
        which = np.maximum(np.searchsorted(firsts, rows, side="right") - 1, 0)
        for index, (first, leg) in enumerate(self.legs):
            plan = leg.plan
            elapsed = (rows - first) * self.period_s
            mine = (which == index) & (elapsed < plan.duration_s)
            if not len(plan) or not mine.any():
                continue
            at = np.searchsorted(plan.start_time_s, elapsed[mine], side="right") - 1
            out[mine] = leg.source[np.maximum(at, 0)]
        return out

    def left_s(self, row: float) -> float:
        """Planned time from row ``row`` to the end of the rows, s."""
        return max(0.0, (self.count - row) * self.period_s)

    def start(self, leg: Leg) -> None:
        """Start again from rest with ``leg``: the rows so far count as executed."""
        self.rows_before += self.count
        self.legs = [(0, leg)]
        self.rows = self.sample(leg)

    def splice(self, row: int, leg: Leg) -> Rows:
        """From row ``row`` on, the rows of ``leg``; returns them."""
        rows = self.sample(leg)
        self.legs = [(at, old) for at, old in self.legs if at < row] + [(row, leg)]
        self.rows = np.vstack((self.rows[:row], rows)).astype(np.int32)
        return rows

    def cut(self, row: int, rows: npt.NDArray[np.integer]) -> None:
        """From row ``row`` on, ``rows`` (a stop's deceleration: the legs stay)."""
        self.rows = np.vstack((self.rows[:row], rows)).astype(np.int32)

    def pause_row(self, segment: int) -> int | None:
        """The row of the pause at program segment ``segment`` on the last leg (None: not
        on it)."""
        first, leg = self.legs[-1]
        hits = np.flatnonzero((leg.source == segment) & (leg.plan.kind == SegmentKind.DWELL))
        if not hits.size:
            return None
        return first + int(float(leg.plan.start_time_s[hits[0]]) / self.period_s)

    def final_row(self, stop_time_s: float) -> int:
        """The last row that more moves cannot change: ``stop_time_s`` (longer than any
        stop from full speed) before the end of the last leg."""
        first, leg = self.legs[-1]
        return first + int(max(0.0, leg.plan.duration_s - stop_time_s) / self.period_s)

    def segment_point(self, segment: int) -> PathPoint:
        """The start of program segment ``segment``, at rest."""
        plan = self.plan
        return PathPoint(segment, 0.0, 0.0, tuple(float(c) for c in plan.vertices_mm[segment]),
                         0.0, float(plan.start_time_s[segment]))
