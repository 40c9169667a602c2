"""Timed segments to setpoints: the position of every axis at every motion-update period.

Sample ``k`` is at ``t_k = k * period_s``, computed from the integer index (never by
accumulating the period), for ``k = 0 .. K`` with ``K = ceil(duration / period)``; so there
are ``K + 1`` samples, the first at the start and the last at or after the end. When the
duration is within 1 ns of a whole number of periods, ``K`` is that number (float noise in
the duration never adds a sample). The last sample is the program's end, exactly, to the
count. Segment start times are the planner's exact cumulative sums (``planner.exact_cumsum``),
so a ten-hour program does not drift.

Within segment ``i`` (found for all samples at once by ``searchsorted`` over the start
times) the distance along the segment is the piecewise quadratic of its trapezoid; the
accelerate and cruise phases are measured from the segment's start and the decelerate phase
from its end, so a segment's last instant is its end vertex exactly. Counts are
``rint(mm * counts_per_mm)`` (nearest, ties to even, which is symmetric in sign).

Samples are computed in chunks, so memory stays bounded on long programs;
``iter_sample_chunks`` hands the chunks out one by one for streaming.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from usbmotion.errors import PlanningError
from usbmotion.motion.planner import Plan

__all__ = [
    "iter_sample_chunks",
    "positions_at_mm",
    "sample_axis",
    "sample_count",
    "sample_plan",
    "sample_positions_mm",
    "sample_times",
]

FloatArray = npt.NDArray[np.float64]
DEFAULT_CHUNK_SAMPLES = 32768
_SNAP_S = 1e-9
_INT32_MAX = 2**31 - 1

# Columns of the per-segment table gathered for every sample.
_START, _T_ACCEL, _T_DECEL_AT, _T_END, _V_ENTRY, _V_CRUISE, _V_EXIT, _ACCEL, _S_ACCEL = range(9)
_COLUMNS = 9


@dataclass(frozen=True)
class _Table:
    """The plan as columns, each gathered by segment for every sample (a column gathered
    whole is read once and lands contiguous: a row per segment made every later step
    stride through nine values)."""

    scalars: FloatArray  # (_COLUMNS, n)
    starts: FloatArray  # (n,) segment start times
    origin: FloatArray  # (k, n) start vertices, an axis a row
    finish: FloatArray  # (k, n) end vertices
    unit: FloatArray  # (k, n)
    end: FloatArray  # (k,) the program's end


def _table(plan: Plan) -> _Table:
    if not isinstance(plan, Plan):
        raise PlanningError(f"plan {plan!r} is not a Plan")
    t_accel = plan.t_accel_s
    v_entry = plan.v_entry_mm_s
    scalars = np.empty((_COLUMNS, len(plan)), dtype=np.float64)
    scalars[_START] = plan.start_time_s
    scalars[_T_ACCEL] = t_accel
    scalars[_T_DECEL_AT] = t_accel + plan.t_cruise_s
    scalars[_T_END] = plan.segment_duration_s
    scalars[_V_ENTRY] = v_entry
    scalars[_V_CRUISE] = plan.v_cruise_mm_s
    scalars[_V_EXIT] = plan.v_exit_mm_s
    scalars[_ACCEL] = plan.accel_mm_s2
    scalars[_S_ACCEL] = v_entry * t_accel + 0.5 * plan.accel_mm_s2 * t_accel * t_accel
    return _Table(
        scalars=scalars,
        starts=np.ascontiguousarray(plan.start_time_s),
        origin=np.ascontiguousarray(plan.vertices_mm[:-1].T),
        finish=np.ascontiguousarray(plan.vertices_mm[1:].T),
        unit=np.ascontiguousarray(plan.unit.T),
        end=np.array(plan.vertices_mm[-1], dtype=np.float64),
    )


def _check_period(period_s: float) -> float:
    if isinstance(period_s, bool) or not isinstance(period_s, (int, float)):
        raise PlanningError(f"period_s {period_s!r} is not a number; a positive time in s")
    if not (math.isfinite(period_s) and period_s > 0.0):
        raise PlanningError(f"period_s {period_s!r} must be positive and finite")
    return float(period_s)


def _check_counts_per_mm(counts_per_mm: Sequence[float], axes: str) -> FloatArray:
    if isinstance(counts_per_mm, (str, bytes)) or len(counts_per_mm) != len(axes):
        raise PlanningError(f"counts_per_mm {counts_per_mm!r} must be {len(axes)} numbers"
                            f" ({', '.join(axes)})")
    for value in counts_per_mm:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise PlanningError(f"counts_per_mm {counts_per_mm!r} holds {value!r}: not a number")
        if not (math.isfinite(value) and value != 0.0):
            raise PlanningError(
                f"counts_per_mm {counts_per_mm!r} holds {value!r}; each must be finite, non-zero"
            )
    return np.array(counts_per_mm, dtype=np.float64)


def _check_range(plan: Plan, scale: FloatArray, axes: tuple[int, ...]) -> None:
    extent = np.abs(plan.vertices_mm[:, list(axes)]).max(axis=0) * np.abs(scale)
    worst = int(np.argmax(extent))
    if extent[worst] + 0.5 > _INT32_MAX:
        raise PlanningError(
            f"axis {plan.axes[axes[worst]]} reaches {float(extent[worst])!r} counts at "
            f"{float(scale[worst])!r} counts/mm; setpoints must fit int32 (+-{_INT32_MAX})"
        )


def sample_count(plan: Plan, period_s: float) -> int:
    """How many samples ``sample_plan`` returns: ``ceil(duration / period) + 1``.

    Raises:
        PlanningError: ``period_s`` is not positive and finite.
    """
    period = _check_period(period_s)
    if not isinstance(plan, Plan):
        raise PlanningError(f"plan {plan!r} is not a Plan")
    ratio = plan.duration_s / period
    nearest = round(ratio)
    if abs(plan.duration_s - nearest * period) <= _SNAP_S:
        return int(nearest) + 1
    return math.ceil(ratio) + 1


def sample_times(plan: Plan, period_s: float) -> FloatArray:
    """Sample times ``k * period_s`` in seconds (for plotting against the samples).

    Raises:
        PlanningError: ``period_s`` is not positive and finite.
    """
    count = sample_count(plan, period_s)
    return np.arange(count, dtype=np.float64) * float(period_s)


def _segments(starts: FloatArray, times: FloatArray, *, ascending: bool) -> npt.NDArray[np.intp]:
    """The segment of each time: the last whose start is at or before it (0 before the
    first). ``ascending`` times (a chunk of samples) are placed by searching the few
    segment starts among them, not each time among the starts: the same indices."""
    if not ascending or not times.size:
        segment = np.searchsorted(starts, times, side="right") - 1
    else:
        before = int(np.searchsorted(starts, times[0], side="right"))
        within = int(np.searchsorted(starts, times[-1], side="right"))
        reached = np.searchsorted(times, starts[before:within], side="left")
        segment = np.cumsum(np.bincount(reached, minlength=times.size)[: times.size])
        segment += before - 1
    np.clip(segment, 0, starts.shape[0] - 1, out=segment)
    return segment


def _distance(
    table: _Table, times: FloatArray, *, ascending: bool = False
) -> tuple[npt.NDArray[np.intp], FloatArray, FloatArray, npt.NDArray[np.bool_]]:
    """Segment index, distance from the start, distance to the end, decelerating flag."""
    segment = _segments(table.starts, times, ascending=ascending)
    columns = table.scalars
    tau = times - columns[_START].take(segment)
    np.maximum(tau, 0.0, out=tau)
    t_accel = columns[_T_ACCEL].take(segment)
    half_a = 0.5 * columns[_ACCEL].take(segment)
    in_accel = tau < t_accel
    decelerating = tau >= columns[_T_DECEL_AT].take(segment)
    from_start = np.where(
        in_accel,
        tau * (columns[_V_ENTRY].take(segment) + half_a * tau),
        columns[_S_ACCEL].take(segment) + columns[_V_CRUISE].take(segment) * (tau - t_accel),
    )
    remaining = columns[_T_END].take(segment) - tau
    np.maximum(remaining, 0.0, out=remaining)
    to_end = remaining * (columns[_V_EXIT].take(segment) + half_a * remaining)
    return segment, from_start, to_end, decelerating


def _positions(table: _Table, times: FloatArray, axes: tuple[int, ...], *,
               ascending: bool = False) -> FloatArray:
    out = np.empty((times.shape[0], len(axes)), dtype=np.float64)
    if table.starts.shape[0] == 0:
        out[:] = table.end[list(axes)]
        return out
    segment, from_start, to_end, decelerating = _distance(table, times, ascending=ascending)
    for column, axis in enumerate(axes):
        direction = table.unit[axis].take(segment)
        out[:, column] = np.where(
            decelerating,
            table.finish[axis].take(segment) - direction * to_end,
            table.origin[axis].take(segment) + direction * from_start,
        )
    return out


def positions_at_mm(plan: Plan, times_s: npt.ArrayLike) -> FloatArray:
    """Positions (mm, shape ``(n, k)``, a column per axis of the plan) at arbitrary times in
    seconds from the plan's start.

    Times before 0 give the start, times after the end give the end.

    Raises:
        PlanningError: a time is NaN.
    """
    table = _table(plan)
    times = np.atleast_1d(np.asarray(times_s, dtype=np.float64))
    if np.isnan(times).any():
        raise PlanningError(f"times_s {times_s!r} holds NaN")
    return _positions(table, times.ravel(), _all(plan))


def _chunks(
    plan: Plan, period_s: float, axes: tuple[int, ...], chunk_samples: int
) -> Iterator[FloatArray]:
    table = _table(plan)
    count = sample_count(plan, period_s)
    period = float(period_s)
    for first in range(0, count, chunk_samples):
        stop = min(count, first + chunk_samples)
        times = np.arange(first, stop, dtype=np.float64) * period
        positions = _positions(table, times, axes, ascending=True)
        if stop == count:
            positions[-1] = table.end[list(axes)]
        yield positions


def _all(plan: Plan) -> tuple[int, ...]:
    """The column of every axis of the plan."""
    return tuple(range(len(plan.axes)))


def _check_chunk(chunk_samples: int) -> int:
    if isinstance(chunk_samples, bool) or not isinstance(chunk_samples, int) or chunk_samples < 1:
        raise PlanningError(f"chunk_samples {chunk_samples!r} must be a positive integer")
    return chunk_samples


def sample_positions_mm(
    plan: Plan, *, period_s: float, chunk_samples: int = DEFAULT_CHUNK_SAMPLES
) -> FloatArray:
    """Positions in mm, shape ``(sample_count, k)``, at every ``period_s`` (unrounded).

    Raises:
        PlanningError: a bad period or chunk size.
    """
    chunk = _check_chunk(chunk_samples)
    out = np.empty((sample_count(plan, period_s), len(plan.axes)), dtype=np.float64)
    first = 0
    for block in _chunks(plan, period_s, _all(plan), chunk):
        out[first : first + block.shape[0]] = block
        first += block.shape[0]
    return out


def iter_sample_chunks(
    plan: Plan,
    *,
    period_s: float,
    counts_per_mm: Sequence[float],
    chunk_samples: int = DEFAULT_CHUNK_SAMPLES,
) -> Iterator[npt.NDArray[np.int32]]:
    """The setpoints of ``sample_plan`` in consecutive int32 blocks of ``chunk_samples`` rows.

    Raises:
        PlanningError: as ``sample_plan`` (checked before the first block).
    """
    if not isinstance(plan, Plan):
        raise PlanningError(f"plan {plan!r} is not a Plan")
    scale = _check_counts_per_mm(counts_per_mm, plan.axes)
    _check_period(period_s)
    chunk = _check_chunk(chunk_samples)
    _check_range(plan, scale, _all(plan))
    return (
        np.rint(block * scale).astype(np.int32)
        for block in _chunks(plan, period_s, _all(plan), chunk)
    )


def sample_plan(
    plan: Plan,
    *,
    period_s: float,
    counts_per_mm: Sequence[float],
    chunk_samples: int = DEFAULT_CHUNK_SAMPLES,
) -> npt.NDArray[np.int32]:
    """Integer setpoints of every axis at every ``period_s``: int32, shape ``(n, k)``, a
    column per axis of ``plan.axes``.

    Parameters:
        plan: the planned program.
        period_s: the motion-update period, s.
        counts_per_mm: encoder counts per mm of each axis of ``plan.axes`` (non-zero).
        chunk_samples: samples computed per numpy pass (memory bound, not semantics).

    Returns ``sample_count(plan, period_s)`` rows; row k is the position at ``k * period_s``
    rounded to the nearest count, and the last row is the program's end.

    Raises:
        PlanningError: bad period, counts per mm or chunk size, or setpoints beyond int32.
    """
    if not isinstance(plan, Plan):
        raise PlanningError(f"plan {plan!r} is not a Plan")
    scale = _check_counts_per_mm(counts_per_mm, plan.axes)
    chunk = _check_chunk(chunk_samples)
    _check_range(plan, scale, _all(plan))
    out = np.empty((sample_count(plan, period_s), len(plan.axes)), dtype=np.int32)
    first = 0
    for block in _chunks(plan, period_s, _all(plan), chunk):
        rows = block.shape[0]
        np.rint(block * scale, out=block)
        out[first : first + rows] = block
        first += rows
    return out


def sample_axis(
    plan: Plan,
    axis: int,
    *,
    period_s: float,
    counts_per_mm: float,
    chunk_samples: int = DEFAULT_CHUNK_SAMPLES,
) -> npt.NDArray[np.int32]:
    """Integer setpoints of one axis (its column in ``plan.axes``: 0 = X ...): int32, shape
    ``(n,)``.

    Same samples as the matching column of ``sample_plan``.

    Raises:
        PlanningError: a bad axis, period, counts per mm or chunk size, or int32 overflow.
    """
    if not isinstance(plan, Plan):
        raise PlanningError(f"plan {plan!r} is not a Plan")
    columns = ", ".join(f"{i} ({letter})" for i, letter in enumerate(plan.axes))
    if isinstance(axis, bool) or axis not in range(len(plan.axes)):
        raise PlanningError(f"axis {axis!r} must be one of {columns}")
    scale = _check_counts_per_mm((counts_per_mm,), plan.axes[axis])
    chunk = _check_chunk(chunk_samples)
    _check_range(plan, scale, (axis,))
    out = np.empty(sample_count(plan, period_s), dtype=np.int32)
    first = 0
    for block in _chunks(plan, period_s, (axis,), chunk):
        rows = block.shape[0]
        out[first : first + rows] = np.rint(block[:, 0] * scale[0])
        first += rows
    return out
