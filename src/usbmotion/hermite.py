"""OpenServo-style Hermite keyframes: the maths shared by the device's curve mode and the host.

A keyframe is ``(duration_ms, position_counts, tangent_in, tangent_out)``. Tangents are
slopes in counts per millisecond stored as signed 6:10 fixed point (``TANGENT_ONE = 1024``
is one count/ms; the stored range is -32768..32767, about +-31.999 counts/ms).

Segments
    Playing ``keyframes`` from a device at ``start_position``: segment 0 runs from
    ``start_position`` (out-tangent 0) to ``keyframes[0]`` over ``keyframes[0].duration_ms``;
    segment i (i >= 1) runs from ``keyframes[i-1]`` (its ``tangent_out``) to ``keyframes[i]``
    (its ``tangent_in``) over ``keyframes[i].duration_ms``. After the last keyframe the
    position holds at the last keyframe's position.

The curve of one segment
    The cubic Hermite from ``p0`` to ``p1`` over ``D = duration_ms * 1000`` microseconds,
    at ``s = elapsed_us / D``::

        p(s) = h00(s) p0 + h10(s) m0' + h01(s) p1 + h11(s) m1'
        m'   = m_fixed * duration_ms / 1024      (tangent scaled by the segment duration, counts)

    evaluated EXACTLY with integers (the numerator over the common denominator
    ``1024 * D**3``) and rounded to the nearest count, ties away from zero. This is
    symmetric: negating every position and tangent negates every result (OpenServo rounds
    toward zero, which biases negative positions; not copied). At ``elapsed_us == 0`` the
    value is ``p0`` and at ``elapsed_us == D`` it is ``p1``, exactly, so the end of one
    segment equals the start of the next (OpenServo's velocity spike at exactly the segment
    ends is not copied either). The exact value may lie outside int32 when tangents overshoot
    near the ends of the int32 range; the device's counter wraps as the hardware does.

Ticks (the contract the device's curve mode reproduces tick by tick)
    Tick k is at time ``t = k * tick_us`` from the start of the first segment. At tick k the
    device evaluates the segment containing t with ``hermite_position``; a tick exactly on a
    boundary belongs to the END of the earlier segment (``elapsed_us == D``, giving that
    keyframe's position ``p_i``); tick 0 is segment 0 at ``elapsed_us == 0`` (the start
    position); ticks after the last boundary give the last position. ``sample_keyframes``
    returns exactly these values.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from usbmotion.errors import ProfileError

TANGENT_ONE = 1024
"""One count per millisecond in 6:10 fixed point."""
TANGENT_MIN = -32768
TANGENT_MAX = 32767
DURATION_MIN_MS = 1
DURATION_MAX_MS = 65535
POSITION_MIN = -(2**31)
POSITION_MAX = 2**31 - 1

# The float fast path of ``sample_keyframes`` is within about 1e-5 counts of the exact value
# (|p| < 2**33, |m'| < 2**21); values this close to a rounding tie are recomputed exactly.
_TIE_MARGIN = 1e-3


def _check_int(name: str, value: object, low: int, high: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise ProfileError(f"{name} {value!r} is not an integer; allowed {low}..{high}")
    number = int(value)
    if not low <= number <= high:
        raise ProfileError(f"{name} {value!r} is out of range; allowed {low}..{high}")
    return number


@dataclass(frozen=True, slots=True)
class Keyframe:
    """One Hermite keyframe, as the device's curve buffer holds it.

    Fields:
        duration_ms: time from the previous keyframe (or from the start), 1..65535 ms.
        position_counts: position reached at the end of the segment, int32 counts.
        tangent_in: slope arriving at this keyframe, counts/ms in 6:10 fixed point
            (-32768..32767; 1024 is one count/ms).
        tangent_out: slope leaving this keyframe, same units.

    Raises:
        ProfileError: (a ``ValueError``) naming the field, the value and the range.
    """

    duration_ms: int
    position_counts: int
    tangent_in: int
    tangent_out: int

    def __post_init__(self) -> None:
        _check_int("duration_ms", self.duration_ms, DURATION_MIN_MS, DURATION_MAX_MS)
        _check_int("position_counts", self.position_counts, POSITION_MIN, POSITION_MAX)
        _check_int("tangent_in", self.tangent_in, TANGENT_MIN, TANGENT_MAX)
        _check_int("tangent_out", self.tangent_out, TANGENT_MIN, TANGENT_MAX)


def _round_half_away(numerator: int, denominator: int) -> int:
    """``numerator / denominator`` (denominator > 0) rounded to nearest, ties away from zero."""
    magnitude = (2 * abs(numerator) + denominator) // (2 * denominator)
    return magnitude if numerator >= 0 else -magnitude


def tangent_to_fixed(counts_per_ms: float) -> int:
    """A slope in counts/ms as 6:10 fixed point: rounded to nearest (ties away from zero),
    clipped to -32768..32767.

    Raises:
        ProfileError: the slope is NaN or infinite.
    """
    if not math.isfinite(counts_per_ms):
        raise ProfileError(f"tangent {counts_per_ms!r} counts/ms is not a finite number")
    scaled = counts_per_ms * TANGENT_ONE
    fixed = math.floor(scaled + 0.5) if scaled >= 0 else -math.floor(-scaled + 0.5)
    return min(TANGENT_MAX, max(TANGENT_MIN, fixed))


def fixed_to_tangent(fixed: int) -> float:
    """A 6:10 fixed-point tangent as counts/ms.

    Raises:
        ProfileError: ``fixed`` is not an integer in -32768..32767.
    """
    return _check_int("tangent", fixed, TANGENT_MIN, TANGENT_MAX) / TANGENT_ONE


def _check_segment(
    p0: int, p1: int, m0_fixed: int, m1_fixed: int, duration_ms: int, elapsed_us: int
) -> tuple[int, int, int, int, int, int]:
    duration = _check_int("duration_ms", duration_ms, DURATION_MIN_MS, DURATION_MAX_MS)
    return (
        _check_int("p0", p0, POSITION_MIN, POSITION_MAX),
        _check_int("p1", p1, POSITION_MIN, POSITION_MAX),
        _check_int("m0_fixed", m0_fixed, TANGENT_MIN, TANGENT_MAX),
        _check_int("m1_fixed", m1_fixed, TANGENT_MIN, TANGENT_MAX),
        duration,
        _check_int("elapsed_us", elapsed_us, 0, duration * 1000),
    )


def hermite_position(
    p0: int, p1: int, m0_fixed: int, m1_fixed: int, duration_ms: int, elapsed_us: int
) -> int:
    """Position of one Hermite segment, exact then rounded to nearest (ties away from zero).

    Parameters:
        p0, p1: start and end positions, int32 counts.
        m0_fixed: out-tangent at the start, 6:10 fixed point counts/ms.
        m1_fixed: in-tangent at the end, 6:10 fixed point counts/ms.
        duration_ms: segment duration, 1..65535 ms.
        elapsed_us: time since the segment start, 0..duration_ms*1000 us.

    Returns ``p0`` at ``elapsed_us == 0`` and ``p1`` at the end, exactly.

    Raises:
        ProfileError: any input is not an integer or is out of its range.
    """
    p0, p1, m0, m1, duration, e = _check_segment(
        p0, p1, m0_fixed, m1_fixed, duration_ms, elapsed_us
    )
    d = duration * 1000
    rest = d - e
    # 1024 * D**3 * p(s), with s = e / D; each basis function multiplied through by D**3.
    numerator = TANGENT_ONE * (
        d * d * d * p0 + (p1 - p0) * e * e * (3 * d - 2 * e)
    ) + duration * e * rest * (m0 * rest - m1 * e)
    return _round_half_away(numerator, TANGENT_ONE * d * d * d)


def hermite_velocity(
    p0: int, p1: int, m0_fixed: int, m1_fixed: int, duration_ms: int, elapsed_us: int
) -> float:
    """Velocity of one Hermite segment in counts/s (float; for diagnostics).

    Same parameters and errors as ``hermite_position``. At the ends it equals the tangents:
    ``m0_fixed * 1000 / 1024`` and ``m1_fixed * 1000 / 1024`` counts/s.
    """
    p0, p1, m0, m1, duration, e = _check_segment(
        p0, p1, m0_fixed, m1_fixed, duration_ms, elapsed_us
    )
    s = e / (duration * 1000)
    scale = duration / TANGENT_ONE
    dp_ds = (
        (p1 - p0) * 6.0 * s * (1.0 - s)
        + m0 * scale * (1.0 - s) * (1.0 - 3.0 * s)
        + m1 * scale * s * (3.0 * s - 2.0)
    )
    return dp_ds / (duration * 1e-3)


def keyframe_tick_count(keyframes: Sequence[Keyframe], *, tick_us: int) -> int:
    """Number of ticks ``sample_keyframes`` returns: ``ceil(total_us / tick_us) + 1``.

    Raises:
        ProfileError: ``tick_us`` is not a positive integer.
    """
    tick = _check_int("tick_us", tick_us, 1, 2**62)
    total_us = sum(k.duration_ms for k in keyframes) * 1000
    return -(-total_us // tick) + 1


def sample_keyframes(
    start_position: int, keyframes: Sequence[Keyframe], *, tick_us: int
) -> npt.NDArray[np.int64]:
    """The position at every tick while playing ``keyframes`` from ``start_position``.

    Tick k is at ``k * tick_us`` microseconds; ticks run from 0 until the first tick at or
    after the end of the last segment (``keyframe_tick_count`` values), with the semantics
    of the module docstring. Each value equals ``hermite_position`` for its tick (a float
    evaluation, with an exact recomputation of every value near a rounding tie).

    Parameters:
        start_position: position before the first keyframe, int32 counts.
        keyframes: the keyframes in play order.
        tick_us: tick period in microseconds (positive integer).

    Raises:
        ProfileError: a bad start position or tick, or an item that is not a ``Keyframe``.
    """
    start = _check_int("start_position", start_position, POSITION_MIN, POSITION_MAX)
    for index, keyframe in enumerate(keyframes):
        if not isinstance(keyframe, Keyframe):
            raise ProfileError(f"keyframes[{index}] {keyframe!r} is not a Keyframe")
    count = keyframe_tick_count(keyframes, tick_us=tick_us)
    if not keyframes:
        return np.full(1, start, dtype=np.int64)

    durations = np.array([k.duration_ms for k in keyframes], dtype=np.int64)
    p1 = np.array([k.position_counts for k in keyframes], dtype=np.int64)
    p0 = np.concatenate(([start], p1[:-1]))
    m1 = np.array([k.tangent_in for k in keyframes], dtype=np.int64)
    m0 = np.array([0] + [k.tangent_out for k in keyframes[:-1]], dtype=np.int64)
    ends_us = np.cumsum(durations * 1000)
    starts_us = ends_us - durations * 1000

    times_us = np.arange(count, dtype=np.int64) * np.int64(tick_us)
    segment = np.searchsorted(ends_us, times_us, side="left")
    inside = segment < len(keyframes)
    result = np.full(count, p1[-1], dtype=np.int64)
    seg = segment[inside]
    elapsed = times_us[inside] - starts_us[seg]

    seg_d = (durations[seg] * 1000).astype(np.float64)
    s = elapsed / seg_d
    scale = durations[seg] / TANGENT_ONE
    start_f = p0[seg].astype(np.float64)
    delta = (p1[seg] - p0[seg]).astype(np.float64)
    one_minus = 1.0 - s
    value = (
        start_f
        + delta * (s * s * (3.0 - 2.0 * s))
        + scale * s * one_minus * (m0[seg] * one_minus - m1[seg] * s)
    )
    magnitude = np.abs(value)
    rounded = np.floor(magnitude + 0.5)
    near_tie = np.abs(magnitude - np.floor(magnitude) - 0.5) < _TIE_MARGIN
    values = (np.sign(value) * rounded).astype(np.int64)
    for i in np.flatnonzero(near_tie):
        j = int(seg[i])
        values[i] = hermite_position(
            int(p0[j]),
            int(p1[j]),
            int(m0[j]),
            int(m1[j]),
            int(durations[j]),
            int(elapsed[i]),
        )
    result[inside] = values
    return result
