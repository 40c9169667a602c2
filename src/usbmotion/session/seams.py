"""Changing what a run streams from a seam, a device tick just ahead of the devices: a stop
or a hold along the program's path, an override's new speed, more moves joined to a
program still being written. The queued future is replaced there (call 38), so there is no
seam in the motion whatever the link's latency.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np
import numpy.typing as npt

from usbmotion.errors import DeviceError, PlanningError
from usbmotion.host.machine import Machine
from usbmotion.host.stream import SetpointStream, run_streams
from usbmotion.motion.replanning import PathPoint, locate
from usbmotion.motion.stopping import stop_setpoints
from usbmotion.session.legs import Legs
from usbmotion.session.rest import wait_for_rest
from usbmotion.session.streaming import REPLACE_BATCH, RunStreams

REJOIN_COUNTS = 1
"""How far off its path point (counts, any axis) a resumed axis may stand without a move
there first: the rounding of the two."""

RESEAM_ROWS = 20
"""When the rest cannot be planned from the seam at the speed the axes have there (too
little of the segment left to slow to the new speed), the seam moves on by this many rows."""


def replan_from_seam(legs: Legs, streams: RunStreams, *, start: int = 0, only: bool = False,
                     growing: bool = False, release_limit: Callable[[], int]) -> int | None:
    """The queued future planned again (the program's rest at the overrides) from a row a
    device tick just ahead (or row ``start``, when later), at the speed the axes have
    there, and replaced from that tick (call 38): the tick, or None when no row is left to
    replace (or, with ``only``, when that row cannot be planned from). ``growing``: the
    program is still being written (the rows may end before its plan does)."""
    index = max(streams.seam()[0], start)
    sent = streams.sent
    while index < min(sent, legs.count - 1) or (index < sent and growing):
        point = legs.point_at(index)
        try:
            rest = legs.plan_rest(point)
        except PlanningError:
            if only:
                return None
            index += RESEAM_ROWS
            continue
        if rest is None:
            return None
        tick = streams.tick_of(index)
        rows = legs.splice(index, rest)
        replace_rows(legs, streams, tick, index, rows, release_limit=release_limit)
        return tick
    return None


def replace_rows(legs: Legs, streams: RunStreams, tick: int, index: int,
                 rows: npt.NDArray[np.integer], *, release_limit: Callable[[], int],
                 whole: bool = False) -> None:
    """Every axis's queued future from ``tick`` (row ``index``) replaced by ``rows`` (the
    legs' rows from there on already): the streams get the first :data:`REPLACE_BATCH` at
    once and, of the rest, what the run releases (``whole``: all of them)."""
    streams.released = index
    limit = (index + rows.shape[0] if whole else
             max(index + min(REPLACE_BATCH, rows.shape[0]), release_limit()))
    streams.replace(tick, index, legs.rows[index:], limit)


def join_rows(legs: Legs, streams: RunStreams, *, stop_time_s: float,
              release_limit: Callable[[], int]) -> bool:
    """Join the program's grown plan (``legs.plan`` already the new one) to what streams:
    the rest is planned again from the latest row that cannot have felt the old plan's end
    at rest (``stop_time_s`` before it), or from the first row the devices can still have
    replaced when that one has passed; rows not sent yet are revised in the streams, rows
    sent are replaced from a device tick just ahead (call 38). False when no row could be
    planned from (the machine must come to rest first)."""
    safe = legs.final_row(stop_time_s)
    seam, _ = streams.seam()
    row = max(min(streams.released, safe), seam)
    sent = streams.sent
    # A join inside a short segment (an arc's chord) may be unable to keep the speed there
    # (the piece left is short, so is its corner's limit): try the rows before it (down to
    # the seam), then those after it (up to the safe row).
    candidates = [*range(row, seam - 1, -RESEAM_ROWS), *range(row + RESEAM_ROWS, safe,
                                                               RESEAM_ROWS)]
    for row in candidates:
        if row < sent:
            if replan_from_seam(legs, streams, start=row, only=True, growing=True,
                                release_limit=release_limit) is not None:
                return True
            continue
        try:
            rest = legs.plan_rest(legs.point_at(row))
        except PlanningError:
            continue
        if rest is None:
            return True
        legs.splice(row, rest)
        given = max(row, min(streams.released, legs.count))
        streams.revise(row, legs.rows[row:], given)
        return True
    return False


@dataclass(frozen=True, slots=True)
class Decelerated:
    """A stop's figures: the tick its deceleration began on, the planned ``v^2/2a`` from the
    speed there and the distance the axes took (mm, their encoders), where on the program
    they came to rest, and the row (of the rows since the last start, fractional) the
    stop ended at."""

    tick: int
    planned_mm: float
    distance_mm: float
    point: PathPoint
    stopped_row: float
    note: str = ""
    late_s: float = 0.0
    """How long after its planned tick the stop reached the latest device (0: on time): the
    axes ran on along the path that long first, and ``distance_mm`` includes it."""


def decelerate(legs: Legs, streams: RunStreams, machine: Machine, *,
               accel_mm_s2: Sequence[float], stop_now: Callable[[], bool]) -> Decelerated:
    """Every axis still enabled to rest along the path at its planned deceleration: the
    queued future replaced from a device tick just ahead (call 50: a stop that reaches a
    device late decelerates in full from where the axis had got to)."""
    index, tick = streams.seam()
    scales = np.array(legs.counts_per_mm)
    accel = [a * s for a, s in zip(accel_mm_s2, legs.counts_per_mm, strict=True)]
    planned_mm = 0.0
    if index == 0 or index >= legs.count:
        stop_rows: npt.NDArray[np.integer] = np.zeros((0, len(scales)), dtype=np.int64)
        end = float(min(index, legs.count) - 1)
    else:
        stop = stop_setpoints(legs.rows, index, period_s=legs.period_s, accel_counts_s2=accel)
        stop_rows, end = stop.setpoints, stop.end_index
        speed_mm_s = float(np.linalg.norm(np.array(stop.velocity_counts_s) / scales))
        decel_mm_s2 = stop.step * speed_mm_s / legs.period_s
        if decel_mm_s2 > 0:
            planned_mm = speed_mm_s**2 / (2 * decel_mm_s2)
    began = legs.rows[index - 1].astype(np.float64) if index > 0 else None
    legs.cut(index, stop_rows)
    streams.released = index
    late = streams.stop(tick, index, legs.rows[index:])
    note = ""
    if late:  # run on along the path that long, then the whole stop: it ends that far on
        note = (f"the stop reached a device {late * legs.period_s * 1000:.0f} ms after the"
                " tick it was planned from (the host or the link was held up): the axes"
                " decelerated in full from where they had got to, that much further along")
        end += late
    first, leg = legs.leg_at(end)
    point = replace(locate(legs.plan, leg, (end - first) * legs.period_s), speed_mm_s=0.0)
    try:
        wait_for_rest(machine, streams.axes, stop_now=stop_now)
    except DeviceError as error:
        note = f"stop: {error}"
        machine.stop()
    distance_mm = 0.0
    if began is not None:
        statuses = machine.status()
        rest = np.array([statuses[n].actual_counts for n in streams.axes], dtype=np.float64)
        distance_mm = float(np.linalg.norm((rest - began) / scales))
    return Decelerated(tick + late * streams.scalar, planned_mm, distance_mm, point, end,
                       note, late * legs.period_s)


def rejoin(machine: Machine, axes: Sequence[str], point: PathPoint, *,
           counts_per_mm: Sequence[float], accel_mm_s2: Sequence[float], period_s: float,
           stop_now: Callable[[], bool]) -> bool:
    """Axes at rest off the path point ``point`` (a stop that came late ended where the axes
    had got to, beside the path where it curves) brought onto it before the program takes
    up from there: one straight move from rest to rest, each axis's values a half cosine of
    one length, within every axis's acceleration. True when they had to move.

    Raises:
        DeviceError: as :func:`wait_for_rest`.
    """
    statuses = machine.status()
    start = np.array([statuses[name].desired_counts for name in axes], dtype=np.int64)
    scales = np.asarray(counts_per_mm, dtype=np.float64)
    delta = np.rint(np.asarray(point.position_mm) * scales).astype(np.int64) - start
    if not np.any(np.abs(delta) > REJOIN_COUNTS):
        return False
    accel = np.asarray(accel_mm_s2, dtype=np.float64) * scales
    duration_s = float(np.max(math.pi * np.sqrt(np.abs(delta) / (2 * accel))))
    steps = max(2, math.ceil(duration_s / period_s))
    shape = (1 - np.cos(math.pi * np.arange(1, steps + 1) / steps)) / 2
    run_streams([SetpointStream(machine.axis(name).client,
                                np.rint(start[column] + delta[column] * shape).astype(np.int64),
                                period_s=period_s)
                 for column, name in enumerate(axes)], should_stop=stop_now)
    wait_for_rest(machine, list(axes), stop_now=stop_now)
    return True


def stop_time_s(limits: Sequence[tuple[float, float]]) -> float:
    """Longer than any stop from full speed takes, for axes of (velocity, acceleration):
    a plan is final up to this long before its end (the look-ahead's end at rest cannot
    reach further back)."""
    worst = max(v / a for v, a in limits)
    return worst * (math.sqrt(len(limits)) if len(limits) > 1 else 1.0)
