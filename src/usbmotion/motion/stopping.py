"""Stopping along a planned path: the setpoints that bring a moving machine to rest on its
own path at its acceleration limits, from any point of a program.

A program's setpoints ``S[i]`` (one row per motion period, one column per axis) are a path
travelled at the planned speed. Stopping keeps the path and slows the clock along it: the
path parameter advances by ``r`` samples per period, ``r`` falling from 1 by the same step
``delta`` each period until it reaches 0. Near the stop point the path velocity is ``v``
(counts per second per axis, measured over the last few periods), so each axis
decelerates at ``|v_k| delta / dt``; ``delta``
is the largest that keeps every axis within its acceleration limit, the planner's own
deceleration along that direction. On a straight path at constant speed the axes stop
after ``v^2 / (2 a)``, exactly what a trapezoid's ramp takes; where the path curves or
the plan itself accelerates, the step is reduced until every axis's second difference is
within its limit.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from usbmotion.errors import PlanningError

IntArray = npt.NDArray[np.int64]
QUANTUM_COUNTS = 2.0
"""Second differences of integer setpoints carry up to this much rounding (counts)."""
_TRIES = 12
VELOCITY_SPAN = 8
"""Periods the path's velocity at the stop is measured over: integer setpoints make a single
difference up to a count off (20 % at 5 counts a period)."""


@dataclass(frozen=True, slots=True)
class Stop:
    """A stop along the path.

    Fields:
        setpoints: (m, k) rows that replace the program from its ``start`` row; they end at
            rest (the last two rows equal); empty when the path is at rest there.
        end_index: where on the program's path the stop ends (a fractional row).
        step: the fall of the path rate per period (1 / step periods to rest).
        velocity_counts_s: the path's velocity where the stop began, per axis.
    """

    setpoints: IntArray
    end_index: float
    step: float
    velocity_counts_s: tuple[float, ...] = ()


def stop_setpoints(
    setpoints: npt.ArrayLike,
    start: int,
    *,
    period_s: float,
    accel_counts_s2: Sequence[float],
) -> Stop:
    """The setpoints that replace ``setpoints[start:]`` to stop on the path.

    Parameters:
        setpoints: (n, k) integer setpoints, one row per motion period.
        start: the first row to replace (the machine has used rows ``< start``); 0 means
            the machine stands at row 0.
        period_s: the motion period.
        accel_counts_s2: each axis's acceleration limit, counts/s^2.

    Returns:
        The :class:`Stop`.

    Raises:
        PlanningError: bad shapes or limits.
    """
    path = np.asarray(setpoints, dtype=np.float64)
    if path.ndim == 1:
        path = path[:, None]
    limits = np.asarray(accel_counts_s2, dtype=np.float64)
    if path.ndim != 2 or path.shape[1] != limits.shape[0] or not np.all(limits > 0):
        raise PlanningError(f"setpoints {path.shape} and accelerations {limits.tolist()} do not"
                            " match, or an acceleration is not positive")
    count = path.shape[0]
    if count == 0 or not 0 <= start <= count or period_s <= 0:
        raise PlanningError(f"start {start} is outside the {count} setpoints")
    empty = np.zeros((0, path.shape[1]), dtype=np.int64)
    if start == 0 or start >= count:
        return Stop(empty, float(max(0, min(start, count) - 1)), 1.0)
    span = min(start, VELOCITY_SPAN)
    velocity = (path[start - 1] - path[start - 1 - span]) / (span * period_s) if span else (
        path[start] - path[start - 1]) / period_s
    if not np.any(path[start] - path[start - 1]) and not np.any(velocity):
        return Stop(empty, float(start - 1), 1.0)
    if not np.any(velocity):
        velocity = (path[start] - path[start - 1]) / period_s
    step = float(np.min(limits[velocity != 0] * period_s / np.abs(velocity[velocity != 0])))
    step = min(step, 1.0)
    bound = limits * period_s * period_s + QUANTUM_COUNTS
    for _ in range(_TRIES):
        values, end = _warp(path, start - 1, step)
        trail = np.vstack((path[max(0, start - 2) : start], values))
        if trail.shape[0] < 3 or np.all(
            np.abs(np.diff(trail, n=2, axis=0)) <= bound
        ):
            return Stop(values, end, step, tuple(velocity.tolist()))
        step *= 0.7
    values, end = _warp(path, start - 1, step)
    return Stop(values, end, step, tuple(velocity.tolist()))


def _warp(path: npt.NDArray[np.float64], origin: int,
          step: float) -> tuple[IntArray, float]:
    """Rows along ``path`` from ``origin`` with the parameter's rate falling by ``step``,
    and the fractional row they end on."""
    rates = 1.0 - step * np.arange(1, int(np.ceil(1.0 / step)) + 1)
    rates = rates[rates > 0]
    taus = origin + np.cumsum(rates)
    taus = np.minimum(taus, path.shape[0] - 1)
    low = np.floor(taus).astype(np.int64)
    high = np.minimum(low + 1, path.shape[0] - 1)
    fraction = (taus - low)[:, None]
    rows = path[low] * (1.0 - fraction) + path[high] * fraction
    values = np.rint(rows).astype(np.int64)
    if values.shape[0]:
        values = np.vstack((values, values[-1:]))
    return values, float(taus[-1]) if taus.size else float(origin)
