"""Step response of one axis: the figures a person tunes PID gains by.

:func:`step_metrics` is pure (arrays in, figures out); :func:`step_response` commands a
position step on a connected axis and records the device's own diagnostics every tick.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from usbmotion.errors import DeviceFaultError, OutOfRangeError
from usbmotion.host.device import ControlMode, Diagnostics
from usbmotion.host.machine import Machine

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True, slots=True)
class StepMetrics:
    """How a position step was followed.

    Fields:
        step_counts: the commanded step.
        rise_time_s: from 10 % to 90 % of the step (NaN if never reached).
        overshoot_pct: the largest excursion past the target, percent of the step.
        settling_time_s: from the step until the response stays within the band for good
            (NaN if it never settles).
        settling_band_counts: the band: 2 % of the step, at least 2 counts.
        steady_state_error_counts: mean error over the last tenth of the record.
    """

    step_counts: int
    rise_time_s: float
    overshoot_pct: float
    settling_time_s: float
    settling_band_counts: float
    steady_state_error_counts: float


def step_metrics(times_s: FloatArray, position: FloatArray, *, start: float,
                 step_counts: int) -> StepMetrics:
    """Figures of a step from ``start`` by ``step_counts`` applied at time 0.

    Raises:
        OutOfRangeError: a zero step, or arrays of different lengths or empty.
    """
    if step_counts == 0:
        raise OutOfRangeError("step_counts 0: a step must move", reason="step_counts")
    if times_s.shape != position.shape or times_s.size == 0:
        raise OutOfRangeError(
            f"times {times_s.shape} and positions {position.shape} must match and not be empty",
            reason="arrays",
        )
    after = times_s >= 0
    t = times_s[after]
    progress = (position[after] - start) / step_counts
    rise_low = np.nonzero(progress >= 0.1)[0]
    rise_high = np.nonzero(progress >= 0.9)[0]
    rise = (float(t[rise_high[0]] - t[rise_low[0]])
            if rise_low.size and rise_high.size else math.nan)
    overshoot = max(0.0, float(np.max(progress)) - 1.0) * 100.0 if progress.size else 0.0
    band = max(2.0, 0.02 * abs(step_counts))
    error = (start + step_counts) - position[after]
    outside = np.nonzero(np.abs(error) > band)[0]
    if not outside.size:
        settling = 0.0
    elif outside[-1] == error.size - 1:
        settling = math.nan
    else:
        settling = float(t[outside[-1] + 1])
    tail = error[int(error.size * 0.9):]
    steady = float(np.mean(tail)) if tail.size else math.nan
    return StepMetrics(step_counts, rise, overshoot, settling, band, steady)


@dataclass(frozen=True, slots=True)
class StepResponse:
    """A recorded step: time since the step (s), desired and actual counts, and figures."""

    axis: str
    times_s: FloatArray
    desired: FloatArray
    actual: FloatArray
    metrics: StepMetrics


def step_response(
    machine: Machine,
    axis: str,
    *,
    step_mm: float,
    duration_s: float = 0.5,
    lead_s: float = 0.05,
) -> StepResponse:
    """Command a position step on one axis and record it, tick by tick.

    The machine must be configured; the axis holds its present position for ``lead_s``,
    then steps by ``step_mm`` and holds for ``duration_s``. The following-error limit is
    widened to twice the step for the test, then restored. The axis is left enabled at
    the new position.

    Raises:
        DeviceFaultError: the device faulted during the test.

        OutOfRangeError: a step of zero or not finite, or a non-positive duration.
    """
    if not (math.isfinite(step_mm) and step_mm != 0):
        raise OutOfRangeError(f"step_mm {step_mm!r} must be a finite non-zero distance",
                              reason="step_mm")
    if not (math.isfinite(duration_s) and duration_s > 0):
        raise OutOfRangeError(f"duration_s {duration_s!r} must be > 0", reason="duration_s")
    target = machine.axis(axis)
    client = target.client
    period_s = machine.config.motion_period_s
    tick_s = machine.config.servo_period_s
    step = target.scale.to_counts(step_mm)
    if step == 0:
        raise OutOfRangeError(f"step_mm {step_mm!r} is under one count", reason="step_mm")
    records: list[Diagnostics] = []
    client.on_diagnostics = records.append
    limit = target.config.following_error_limit_counts
    if limit:
        client.set_following_error_limit(max(limit, 2 * abs(step)))
    client.set_control_mode(ControlMode.POSITION)
    client.set_servo_enable(True)
    start = client.status().actual_counts
    lead = max(1, round(lead_s / period_s))
    hold = max(1, round(duration_s / period_s))
    client.set_diagnostics_interval(1)
    client.start_at(client.clock() + 2)
    values = [start] * lead + [start + step] * hold
    for first in range(0, len(values), 500):
        while client.queue_status()[1] < 500:
            machine.clock.sleep(0.2)
        client.add_setpoints(values[first:first + 500])
    machine.clock.sleep((lead + hold) * period_s + 0.05)
    client.set_diagnostics_interval(0)
    client.sync()
    client.on_diagnostics = None
    client.set_following_error_limit(limit)
    status = client.status()
    if status.fault:
        raise DeviceFaultError(
            f"axis {axis}: {status.fault_name} during the step test", device=client.name
        )
    clock = np.array([r.clock for r in records], dtype=np.float64)
    desired = np.array([r.desired for r in records], dtype=np.float64)
    actual = np.array([r.actual_counts for r in records], dtype=np.float64)
    stepped = np.nonzero(desired != start)[0]
    t0 = clock[stepped[0]] if stepped.size else clock[0]
    times = (clock - t0) * tick_s
    metrics = step_metrics(times, actual, start=float(start), step_counts=step)
    return StepResponse(axis, times, desired, actual, metrics)
