"""Point-to-point motion profiles: trapezoid, jerk-limited (ruckig), Hermite keyframes.

Trapezoid and jerk-limited profiles work in any one length unit (mm with mm/s and mm/s^2, or
counts with counts/s and counts/s^2); times are seconds. Hermite keyframes are in counts and
milliseconds and use ``usbmotion.hermite``, the same integer maths as the device's curve
mode, so a host that samples keyframes and a device that plays them produce the same numbers.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt
from ruckig import InputParameter, Result, Ruckig, RuckigError, Trajectory

from usbmotion.errors import ProfileError
from usbmotion.hermite import (
    DURATION_MAX_MS,
    DURATION_MIN_MS,
    POSITION_MAX,
    POSITION_MIN,
    TANGENT_MAX,
    TANGENT_MIN,
    TANGENT_ONE,
    Keyframe,
    tangent_to_fixed,
)

__all__ = [
    "JerkLimitedProfile",
    "TrapezoidProfile",
    "jerk_limited_profile",
    "keyframes_through_points",
    "line_tangent_fixed",
    "polyline_keyframes",
    "straight_line_keyframe",
    "trapezoid_keyframes",
    "trapezoid_profile",
]

FloatArray = npt.NDArray[np.float64]
_SNAP_S = 1e-9


def _number(name: str, value: object) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer)):
        raise ProfileError(f"{name} {value!r} is not a number")
    number = float(value)
    if not math.isfinite(number):
        raise ProfileError(f"{name} {value!r} must be finite")
    return number


def _positive(name: str, value: object) -> float:
    number = _number(name, value)
    if number <= 0.0:
        raise ProfileError(f"{name} {value!r} must be positive")
    return number


def _sample_times(duration_s: float, period_s: float) -> FloatArray:
    period = _positive("period_s", period_s)
    ratio = duration_s / period
    nearest = round(ratio)
    last = int(nearest) if abs(duration_s - nearest * period) <= _SNAP_S else math.ceil(ratio)
    return np.arange(last + 1, dtype=np.float64) * period


# --- trapezoid -----------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class TrapezoidProfile:
    """A trapezoidal (or triangular) velocity profile over a signed distance.

    Fields:
        distance: signed travel (the unit of the caller's choice).
        v_max, a_max: speed and acceleration limits (per second, per second squared).
        v0, v1: speeds at the start and end, >= 0, along the direction of travel.
        v_peak: the highest speed reached.
        t_accel_s, t_cruise_s, t_decel_s: phase durations.
    """

    distance: float
    v_max: float
    a_max: float
    v0: float
    v1: float
    v_peak: float
    t_accel_s: float
    t_cruise_s: float
    t_decel_s: float

    @property
    def duration_s(self) -> float:
        """Total time."""
        return self.t_accel_s + self.t_cruise_s + self.t_decel_s

    def _travel(self, t: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Unsigned distance and speed at times ``t`` (clamped to the profile)."""
        a = self.a_max
        length = abs(self.distance)
        t = np.clip(t, 0.0, self.duration_s)
        t_cruise_end = self.t_accel_s + self.t_cruise_s
        s_accel = self.t_accel_s * (self.v0 + 0.5 * a * self.t_accel_s)
        remaining = np.maximum(self.duration_s - t, 0.0)
        distance = np.where(
            t < self.t_accel_s,
            t * (self.v0 + 0.5 * a * t),
            np.where(
                t < t_cruise_end,
                s_accel + self.v_peak * (t - self.t_accel_s),
                length - remaining * (self.v1 + 0.5 * a * remaining),
            ),
        )
        speed = np.where(
            t < self.t_accel_s,
            self.v0 + a * t,
            np.where(t < t_cruise_end, self.v_peak, self.v1 + a * remaining),
        )
        return distance, speed

    def position_at(self, t_s: npt.ArrayLike) -> FloatArray:
        """Signed position (0 at the start) at time(s) ``t_s``, clamped to the profile."""
        distance, _ = self._travel(np.asarray(t_s, dtype=np.float64))
        return np.copysign(distance, self.distance)

    def velocity_at(self, t_s: npt.ArrayLike) -> FloatArray:
        """Signed velocity at time(s) ``t_s`` (the end speeds outside the profile)."""
        _, speed = self._travel(np.asarray(t_s, dtype=np.float64))
        return speed if self.distance >= 0 else -speed

    def sample(self, period_s: float) -> FloatArray:
        """Positions at ``k * period_s`` for ``k = 0 .. ceil(duration / period)``; the last
        value is ``distance`` exactly.

        Raises:
            ProfileError: ``period_s`` is not positive and finite.
        """
        times = _sample_times(self.duration_s, period_s)
        positions = self.position_at(times)
        positions[-1] = self.distance
        return positions


def trapezoid_profile(
    distance: float, v_max: float, a_max: float, *, v0: float = 0.0, v1: float = 0.0
) -> TrapezoidProfile:
    """The time-optimal trapezoidal profile covering ``distance`` within the limits.

    Parameters:
        distance: signed travel.
        v_max: speed limit (> 0); a_max: acceleration limit (> 0).
        v0, v1: start and end speeds along the direction of travel, 0..v_max.

    Raises:
        ProfileError: a bad number, or end speeds that cannot be joined over the distance
            (``|v1^2 - v0^2| > 2 a_max |distance|``).
    """
    d = _number("distance", distance)
    v_limit = _positive("v_max", v_max)
    a = _positive("a_max", a_max)
    start_v = _number("v0", v0)
    end_v = _number("v1", v1)
    for name, value in (("v0", start_v), ("v1", end_v)):
        if not 0.0 <= value <= v_limit:
            raise ProfileError(f"{name} {value!r} must be within 0..v_max ({v_limit!r})")
    length = abs(d)
    reach = 2.0 * a * length
    if abs(end_v * end_v - start_v * start_v) > reach * (1.0 + 1e-12) + 1e-12:
        raise ProfileError(
            f"cannot go from v0 {start_v!r} to v1 {end_v!r} over distance {d!r} at a_max "
            f"{a!r}: |v1^2 - v0^2| = {abs(end_v**2 - start_v**2)!r} exceeds 2*a*d = {reach!r}"
        )
    peak_sq = min(v_limit * v_limit, 0.5 * (start_v * start_v + end_v * end_v + reach))
    peak = max(math.sqrt(peak_sq), start_v, end_v)
    s_accel = (peak * peak - start_v * start_v) / (2.0 * a)
    s_decel = (peak * peak - end_v * end_v) / (2.0 * a)
    s_cruise = max(0.0, length - s_accel - s_decel)
    return TrapezoidProfile(
        distance=d,
        v_max=v_limit,
        a_max=a,
        v0=start_v,
        v1=end_v,
        v_peak=peak,
        t_accel_s=(peak - start_v) / a,
        t_cruise_s=s_cruise / peak if peak > 0.0 else 0.0,
        t_decel_s=(peak - end_v) / a,
    )


# --- jerk-limited (ruckig) -----------------------------------------------------------------


def _per_dof(name: str, value: float | Sequence[float], dofs: int) -> list[float]:
    if isinstance(value, (int, float, np.floating, np.integer)) and not isinstance(value, bool):
        return [_number(name, value)] * dofs
    if isinstance(value, (str, bytes)) or not isinstance(value, Sequence):
        raise ProfileError(f"{name} {value!r} is not a number or a sequence of numbers")
    if len(value) != dofs:
        raise ProfileError(f"{name} {value!r} has {len(value)} values; {dofs} expected")
    return [_number(f"{name}[{i}]", item) for i, item in enumerate(value)]


@dataclass(frozen=True)
class JerkLimitedProfile:
    """A time-optimal jerk-limited trajectory (ruckig), one or several synchronised axes.

    Fields:
        start, target: positions per axis.
        duration_s: total time.
    """

    start: tuple[float, ...]
    target: tuple[float, ...]
    duration_s: float
    _trajectory: Any = field(repr=False, compare=False)

    @property
    def dofs(self) -> int:
        """Number of axes."""
        return len(self.start)

    def at(self, t_s: float) -> tuple[tuple[float, ...], tuple[float, ...], tuple[float, ...]]:
        """Position, velocity and acceleration of every axis at ``t_s`` (clamped to 0..end)."""
        t = min(max(_number("t_s", t_s), 0.0), self.duration_s)
        position, velocity, acceleration = self._trajectory.at_time(t)[:3]
        return tuple(position), tuple(velocity), tuple(acceleration)

    def sample(self, period_s: float) -> FloatArray:
        """Positions at ``k * period_s`` for ``k = 0 .. ceil(duration / period)``, shape
        ``(n, dofs)``; the last row is the target exactly.

        Raises:
            ProfileError: ``period_s`` is not positive and finite.
        """
        times = _sample_times(self.duration_s, period_s)
        out = np.empty((times.shape[0], self.dofs), dtype=np.float64)
        at_time = self._trajectory.at_time
        for row, t in enumerate(times.tolist()):
            out[row] = at_time(min(t, self.duration_s))[0]
        out[-1] = self.target
        return out

    def sample_counts(self, period_s: float, counts_per_unit: float = 1.0) -> npt.NDArray[np.int64]:
        """``sample`` scaled by ``counts_per_unit`` and rounded to the nearest count.

        Raises:
            ProfileError: a bad period or scale.
        """
        scale = _number("counts_per_unit", counts_per_unit)
        if scale == 0.0:
            raise ProfileError(f"counts_per_unit {counts_per_unit!r} must be non-zero")
        return np.rint(self.sample(period_s) * scale).astype(np.int64)


def jerk_limited_profile(
    start: float | Sequence[float],
    target: float | Sequence[float],
    v_max: float | Sequence[float],
    a_max: float | Sequence[float],
    j_max: float | Sequence[float],
    *,
    v0: float | Sequence[float] = 0.0,
    a0: float | Sequence[float] = 0.0,
    v1: float | Sequence[float] = 0.0,
    a1: float | Sequence[float] = 0.0,
) -> JerkLimitedProfile:
    """The time-optimal jerk-limited move from ``start`` to ``target`` (ruckig, offline).

    Each argument is a number or one number per axis (a sequence fixes the axis count; all
    axes finish together). Limits are per second, per second squared, per second cubed.

    Parameters:
        start, target: positions.
        v_max, a_max, j_max: velocity, acceleration and jerk limits (> 0).
        v0, a0: initial velocity and acceleration; v1, a1: final ones.

    Raises:
        ProfileError: a bad number or length, or ruckig cannot compute the trajectory (the
            message names the inputs and ruckig's result or error).
    """
    arguments = {
        "start": start,
        "target": target,
        "v_max": v_max,
        "a_max": a_max,
        "j_max": j_max,
        "v0": v0,
        "a0": a0,
        "v1": v1,
        "a1": a1,
    }
    dofs = 1
    for name, value in arguments.items():
        if isinstance(value, Sequence) and not isinstance(value, (str, bytes)):
            if dofs != 1 and len(value) != dofs:
                raise ProfileError(f"{name} {value!r} has {len(value)} values; {dofs} expected")
            dofs = max(dofs, len(value))
    if dofs < 1:
        raise ProfileError("start and target need at least one axis")
    values = {name: _per_dof(name, value, dofs) for name, value in arguments.items()}
    for name in ("v_max", "a_max", "j_max"):
        for i, limit in enumerate(values[name]):
            if limit <= 0.0:
                raise ProfileError(f"{name} {arguments[name]!r} must be positive (axis {i})")

    parameters = InputParameter(dofs)
    parameters.current_position = values["start"]
    parameters.current_velocity = values["v0"]
    parameters.current_acceleration = values["a0"]
    parameters.target_position = values["target"]
    parameters.target_velocity = values["v1"]
    parameters.target_acceleration = values["a1"]
    parameters.max_velocity = values["v_max"]
    parameters.max_acceleration = values["a_max"]
    parameters.max_jerk = values["j_max"]
    trajectory = Trajectory(dofs)
    described = ", ".join(f"{name}={value!r}" for name, value in arguments.items())
    try:
        result = Ruckig(dofs).calculate(parameters, trajectory)
    except RuckigError as error:
        raise ProfileError(
            f"ruckig rejected the move ({described}): {str(error).strip()}"
        ) from error
    if result not in (Result.Working, Result.Finished):
        raise ProfileError(f"ruckig could not compute the move ({described}): {result.name}")
    return JerkLimitedProfile(
        start=tuple(values["start"]),
        target=tuple(values["target"]),
        duration_s=float(trajectory.duration),
        _trajectory=trajectory,
    )


# --- Hermite keyframes ---------------------------------------------------------------------


def _counts(name: str, value: object) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise ProfileError(f"{name} {value!r} is not an integer count")
    number = int(value)
    if not POSITION_MIN <= number <= POSITION_MAX:
        raise ProfileError(
            f"{name} {value!r} is out of range; allowed {POSITION_MIN}..{POSITION_MAX}"
        )
    return number


def _duration(name: str, value: object) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise ProfileError(f"{name} {value!r} is not an integer number of ms")
    number = int(value)
    if not DURATION_MIN_MS <= number <= DURATION_MAX_MS:
        raise ProfileError(
            f"{name} {value!r} is out of range; allowed {DURATION_MIN_MS}..{DURATION_MAX_MS} ms"
        )
    return number


def _points_and_durations(
    points_counts: Sequence[int], durations_ms: Sequence[int]
) -> tuple[list[int], list[int]]:
    if len(points_counts) < 2:
        raise ProfileError(
            f"points_counts {points_counts!r} needs the start and at least one more point"
        )
    if len(durations_ms) != len(points_counts) - 1:
        raise ProfileError(
            f"durations_ms has {len(durations_ms)} values; one per segment "
            f"({len(points_counts) - 1}) expected"
        )
    points = [_counts(f"points_counts[{i}]", p) for i, p in enumerate(points_counts)]
    durations = [_duration(f"durations_ms[{i}]", d) for i, d in enumerate(durations_ms)]
    return points, durations


def line_tangent_fixed(from_counts: int, to_counts: int, duration_ms: int) -> int:
    """The slope of a straight line as a 6:10 fixed-point tangent, rounded to nearest.

    Raises:
        ProfileError: a bad input, or a slope beyond the tangent range (about +-31.999
            counts/ms), where the line cannot be drawn straight: lengthen the duration.
    """
    start = _counts("from_counts", from_counts)
    end = _counts("to_counts", to_counts)
    duration = _duration("duration_ms", duration_ms)
    numerator = (end - start) * TANGENT_ONE
    magnitude = (2 * abs(numerator) + duration) // (2 * duration)
    fixed = magnitude if numerator >= 0 else -magnitude
    if not TANGENT_MIN <= fixed <= TANGENT_MAX:
        shortest = math.ceil(abs(end - start) * TANGENT_ONE / TANGENT_MAX)
        raise ProfileError(
            f"a straight line from {start} to {end} counts in {duration} ms has slope "
            f"{(end - start) / duration!r} counts/ms; tangents hold at most "
            f"{TANGENT_MAX / TANGENT_ONE!r} counts/ms, so it needs at least {shortest} ms"
        )
    return fixed


def straight_line_keyframe(
    from_counts: int, to_counts: int, duration_ms: int, *, tangent_out: int | None = None
) -> Keyframe:
    """The keyframe that ends a straight line from ``from_counts`` to ``to_counts``.

    Its ``tangent_in`` is the line's slope; ``tangent_out`` is the slope leaving it (the
    same slope unless given). The segment is straight only if the keyframe before it leaves
    with the same slope (its ``tangent_out`` equal to ``line_tangent_fixed(...)``);
    ``polyline_keyframes`` arranges that. The sampled line is within
    ``0.5 + 0.047 * duration_ms / 1024`` counts of the exact line (the slope is quantised to
    1/1024 count/ms): within one count up to about 10.9 s.

    Raises:
        ProfileError: as ``line_tangent_fixed``, or a bad ``tangent_out``.
    """
    slope = line_tangent_fixed(from_counts, to_counts, duration_ms)
    return Keyframe(
        duration_ms=duration_ms,
        position_counts=to_counts,
        tangent_in=slope,
        tangent_out=slope if tangent_out is None else tangent_out,
    )


def polyline_keyframes(
    points_counts: Sequence[int], durations_ms: Sequence[int], *, lead_ms: int = 1
) -> tuple[Keyframe, ...]:
    """Keyframes that play straight lines through ``points_counts`` (OpenServo style).

    ``points_counts[0]`` is where the device starts; line i runs to ``points_counts[i + 1]``
    in ``durations_ms[i]``. Each keyframe's in- and out-tangents are the slopes of its two
    adjacent lines (different at a corner); a repeated point is a wait (zero tangents, no
    position change). Curve playback always leaves the start with tangent 0, so a lead
    keyframe holds the start for ``lead_ms`` (1..65535) and leaves with the first line's
    slope; ``lead_ms=0`` omits it, and then the first line eases out of rest instead.

    Play with ``sample_keyframes(points_counts[0], keyframes, tick_us=...)``.

    Raises:
        ProfileError: bad points, durations or lead, or a line too steep for the tangents.
    """
    points, durations = _points_and_durations(points_counts, durations_ms)
    if (
        isinstance(lead_ms, bool)
        or not isinstance(lead_ms, int)
        or not (lead_ms == 0 or DURATION_MIN_MS <= lead_ms <= DURATION_MAX_MS)
    ):
        raise ProfileError(f"lead_ms {lead_ms!r} must be 0 or {DURATION_MIN_MS}..{DURATION_MAX_MS}")
    slopes = [
        line_tangent_fixed(points[i], points[i + 1], durations[i]) for i in range(len(durations))
    ]
    keyframes: list[Keyframe] = []
    if lead_ms:
        keyframes.append(Keyframe(lead_ms, points[0], 0, slopes[0]))
    for i, duration in enumerate(durations):
        next_slope = slopes[i + 1] if i + 1 < len(slopes) else 0
        keyframes.append(
            straight_line_keyframe(points[i], points[i + 1], duration, tangent_out=next_slope)
        )
    return tuple(keyframes)


def trapezoid_keyframes(
    start_counts: int,
    peak_counts: int,
    *,
    rise_ms: int,
    hold_ms: int,
    fall_ms: int,
    lead_ms: int = 1,
) -> tuple[Keyframe, ...]:
    """Seed 001's trapezoid: a straight rise to ``peak_counts``, a wait, a straight fall back.

    ``hold_ms = 0`` makes a triangle. See ``polyline_keyframes`` for ``lead_ms``.

    Raises:
        ProfileError: bad positions or durations, or a slope too steep for the tangents.
    """
    if hold_ms == 0:
        return polyline_keyframes(
            [start_counts, peak_counts, start_counts], [rise_ms, fall_ms], lead_ms=lead_ms
        )
    return polyline_keyframes(
        [start_counts, peak_counts, peak_counts, start_counts],
        [rise_ms, hold_ms, fall_ms],
        lead_ms=lead_ms,
    )


def keyframes_through_points(
    points_counts: Sequence[int], durations_ms: Sequence[int]
) -> tuple[Keyframe, ...]:
    """Smooth keyframes through ``points_counts`` (Catmull-Rom tangents, equal in and out).

    ``points_counts[0]`` is where the device starts (curve playback leaves it with tangent
    0); keyframe i reaches ``points_counts[i + 1]`` after ``durations_ms[i]``. An interior
    tangent is the finite difference over the neighbouring points,
    ``(p[i+1] - p[i-1]) / (T[i+1] - T[i-1])`` counts/ms (``T`` the keyframe times), passed
    through ``tangent_to_fixed`` (clipped to about +-31.999 counts/ms; positions stay exact);
    the last keyframe arrives at rest (tangent 0), as the position holds after it.

    Play with ``sample_keyframes(points_counts[0], keyframes, tick_us=...)``.

    Raises:
        ProfileError: bad points or durations.
    """
    points, durations = _points_and_durations(points_counts, durations_ms)
    times = [0]
    for duration in durations:
        times.append(times[-1] + duration)
    keyframes: list[Keyframe] = []
    last = len(points) - 1
    for i in range(1, last + 1):
        tangent = 0
        if i < last:
            slope = (points[i + 1] - points[i - 1]) / (times[i + 1] - times[i - 1])
            tangent = tangent_to_fixed(slope)
        keyframes.append(Keyframe(durations[i - 1], points[i], tangent, tangent))
    return tuple(keyframes)
