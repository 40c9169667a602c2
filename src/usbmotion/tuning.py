"""Measurements of one axis: the step response a person tunes PID gains by, and its reach.

:func:`step_metrics` and :func:`fit_saturated_run` are pure (arrays in, figures out);
:func:`step_response` commands a position step on a connected axis, :func:`measure_reach`
drives it at full voltage there and back; both record the device's own diagnostics every
tick, and both refuse, before anything moves, a test that would take the axis out of its
travel from where it stands (:func:`stands_at_mm`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from usbmotion.errors import ArgumentError, DeviceError, DeviceFaultError
from usbmotion.host.config import AxisReach, PidGains
from usbmotion.host.device import ControlMode, DeviceClient, Diagnostics
from usbmotion.host.machine import Machine
from usbmotion.session.homing import homed_mark

FloatArray = npt.NDArray[np.float64]


FEED_S = 0.2
"""While a test's motion plays out, the host asks the device something at least this often,
so its watchdog (a real machine's: 2 s) never mistakes the wait for a lost host."""


def wait_feeding(machine: Machine, client: DeviceClient, seconds: float) -> None:
    """Wait ``seconds`` on the machine's clock, a queue query to ``client`` every
    :data:`FEED_S` (each call restarts the device's watchdog)."""
    clock = machine.clock
    end = clock.now() + seconds
    while (left := end - clock.now()) > 0:
        clock.sleep(min(left, FEED_S))
        client.queue_status()


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
        ArgumentError: a zero step, or arrays of different lengths or empty.
    """
    if step_counts == 0:
        raise ArgumentError("step_counts 0: a step must move", reason="step_counts")
    if times_s.shape != position.shape or times_s.size == 0:
        raise ArgumentError(
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


def stands_at_mm(machine: Machine, axis: str) -> float | None:
    """Where ``axis`` stands, in machine mm: its device's count on an axis homed for this
    machine file (the device carries the file's homed mark), else, on an axis with a
    simulated motor, its power-up place (``sim.start_mm``) plus the counts it moved since;
    None when neither tells (a real axis not homed).

    Raises:
        DeviceError: the device did not answer.
    """
    target = machine.axis(axis)
    client = target.client
    counts = client.status().actual_counts
    if client.homed_marker() == homed_mark(machine.config, target.config):
        return target.scale.to_mm(counts)
    sim = target.config.sim
    if sim is not None:
        return sim.start_mm + target.scale.to_mm(counts)
    return None


def check_within_travel(machine: Machine, axis: str, distance_mm: float, *,
                        what: str, reason: str) -> None:
    """Refuse to move ``axis`` by ``distance_mm`` from where it stands when that leaves its
    ``travel_mm``; where it stands unknown (:func:`stands_at_mm`), when the distance is
    longer than the whole travel.

    Raises:
        ArgumentError: the move leaves the travel (names the axis, ``what``, where the axis
            stands and the room on either side; ``reason`` is its ``reason``).
    """
    low, high = machine.axis(axis).config.travel_mm
    here = stands_at_mm(machine, axis)
    travel = f"travel_mm [{low:g}, {high:g}]"
    if here is None:
        if abs(distance_mm) > high - low:
            raise ArgumentError(
                f"axis {axis}: {what} of {distance_mm:+g} mm is longer than its whole {travel}"
                " (it is not homed, so where it stands is unknown); nothing moved",
                reason=reason)
        return
    if not low - 1e-9 <= here + distance_mm <= high + 1e-9:
        raise ArgumentError(
            f"axis {axis}: {what} of {distance_mm:+g} mm from {here:.3f} mm would leave its"
            f" {travel}: the room from there is {low - here:+.3f} to {high - here:+.3f} mm;"
            " nothing moved", reason=reason)


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

        ArgumentError: a step of zero or not finite, a non-positive duration, or a step
            that would leave the axis's travel (:func:`check_within_travel`).
    """
    if not (math.isfinite(step_mm) and step_mm != 0):
        raise ArgumentError(f"step_mm {step_mm!r} must be a finite non-zero distance",
                              reason="step_mm")
    if not (math.isfinite(duration_s) and duration_s > 0):
        raise ArgumentError(f"duration_s {duration_s!r} must be > 0", reason="duration_s")
    target = machine.axis(axis)
    client = target.client
    period_s = machine.config.motion_period_s
    tick_s = machine.config.servo_period_s
    step = target.scale.to_counts(step_mm)
    if step == 0:
        raise ArgumentError(f"step_mm {step_mm!r} is under one count", reason="step_mm")
    check_within_travel(machine, axis, step_mm, what="a step", reason="step_mm")
    records: list[Diagnostics] = []
    limit = target.config.following_error_limit_counts
    with client.listening(diagnostics=records.append):
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
        wait_feeding(machine, client, (lead + hold) * period_s + 0.05)
        client.set_diagnostics_interval(0)
        client.sync()
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


# --- reach: what the motor can do at full voltage --------------------------------------------

SATURATING_COUNTS_S = 1_000_000
"""The velocity the reach test asks for: far beyond any motor, so the loop stays at the rail."""
REACH_GAINS = PidGains(kp=0.01, ki=0.0, kd=0.0)
"""Velocity-mode gains of the reach test: proportional only, so the output sits at the supply
from the first tick (any error above ``V / kp``, 1200 counts/s at 12 V, saturates it) and
nothing winds up."""
_FEED_S = 0.25
"""Seconds of saturating setpoints kept queued (topped up when half are used)."""
_POLL_S = 0.005
"""How often the host looks at the run while it accelerates."""
_HOST_LAG_S = 0.02
"""Allowance for how late the host sees the axis and stops it (4 polls: link included)."""
_MIN_TIME_CONSTANTS = 3.0
"""A run must accelerate at least this many time constants for its top speed to count."""


@dataclass(frozen=True, slots=True)
class SaturatedFit:
    """A first-order fit to a run from rest at full voltage: ``x = v (t - tau (1 - e^(-t/tau)))``.

    Fields:
        top_speed_counts_s: ``v``, the speed the run tends to, counts/s.
        time_constant_s: ``tau``, s.
        rms_residual_counts: how far the positions are from the fitted curve, RMS counts.
    """

    top_speed_counts_s: float
    time_constant_s: float
    rms_residual_counts: float

    @property
    def accel_counts_s2(self) -> float:
        """Acceleration from standstill, ``v / tau``, counts/s^2."""
        return self.top_speed_counts_s / self.time_constant_s


def fit_saturated_run(times_s: FloatArray, moved_counts: FloatArray) -> SaturatedFit:
    """Fit a DC motor's run from rest under a constant voltage.

    ``moved_counts[k]`` is the distance from the resting position ``times_s[k]`` after the
    voltage was applied. For a given ``tau`` the best ``v`` is linear least squares; ``tau``
    is found by golden-section search on its logarithm, from a tenth of the first sample's
    time to ten times the record.

    Raises:
        ArgumentError: fewer than 3 samples, arrays of different shapes, times not
            positive and increasing, or a run that did not move forward.
    """
    if times_s.shape != moved_counts.shape or times_s.size < 3:
        raise ArgumentError(
            f"times {times_s.shape} and distances {moved_counts.shape} must match, with at"
            " least 3 samples", reason="arrays",
        )
    if times_s[0] <= 0 or np.any(np.diff(times_s) <= 0):
        raise ArgumentError("times must be positive and increasing", reason="times_s")
    if moved_counts[-1] <= 0:
        raise ArgumentError(f"the run moved {moved_counts[-1]:g} counts: it must move forward",
                              reason="moved_counts")

    def solve(tau: float) -> tuple[float, float]:
        shape = times_s + tau * np.expm1(-times_s / tau)
        speed = float(np.dot(shape, moved_counts) / np.dot(shape, shape))
        residual = moved_counts - speed * shape
        return speed, float(np.dot(residual, residual))

    low, high = math.log(float(times_s[0]) / 10), math.log(float(times_s[-1]) * 10)
    ratio = (math.sqrt(5) - 1) / 2
    a, b = high - ratio * (high - low), low + ratio * (high - low)
    cost_a, cost_b = solve(math.exp(a))[1], solve(math.exp(b))[1]
    while high - low > 1e-6:
        if cost_a < cost_b:
            high, b, cost_b = b, a, cost_a
            a = high - ratio * (high - low)
            cost_a = solve(math.exp(a))[1]
        else:
            low, a, cost_a = a, b, cost_b
            b = low + ratio * (high - low)
            cost_b = solve(math.exp(b))[1]
    tau = math.exp((low + high) / 2)
    speed, cost = solve(tau)
    return SaturatedFit(speed, tau, math.sqrt(cost / times_s.size))


@dataclass(frozen=True, slots=True)
class ReachRun:
    """One run from rest at full voltage in one direction, as the device recorded it.

    Fields:
        direction: ``+1`` toward higher counts, ``-1`` toward lower.
        times_s: time since the voltage was applied, one sample per servo tick.
        moved_counts: distance from the resting position (in the run's direction).
        output_v: the PID output on each tick, volts (the supply, with the run's sign).
        fit: the first-order fit.
        travel_counts: the whole run's extent from where it started, braking included.
    """

    direction: int
    times_s: FloatArray
    moved_counts: FloatArray
    output_v: FloatArray
    fit: SaturatedFit
    travel_counts: int


@dataclass(frozen=True, slots=True)
class ReachMeasurement:
    """What ``usbmotion tune --reach`` measured on one axis.

    Fields:
        axis: the axis letter.
        supply_v: the PID output the runs saturated at (the device's source voltage), V.
        runs: the saturated runs, first in the direction asked for, then back.
        reach: the lesser top speed and acceleration from standstill of the runs, mm/s and
            mm/s^2: what the machine file's ``reach`` table takes.
    """

    axis: str
    supply_v: float
    runs: tuple[ReachRun, ...]
    reach: AxisReach


def measure_reach(
    machine: Machine,
    axis: str,
    *,
    distance_mm: float,
    run_timeout_s: float = 10.0,
) -> ReachMeasurement:
    """Run one axis at full voltage there and back; measure its top speed and acceleration.

    The axis runs in velocity mode toward a setpoint no motor reaches
    (:data:`SATURATING_COUNTS_S`, on :data:`REACH_GAINS`), so the PID output stays at the
    supply; the device's diagnostics of every tick give the positions, to which
    :func:`fit_saturated_run` fits the DC motor's first-order run. Each run stops
    accelerating once it has used half of its room (the host's lag included) and brakes on
    the position loop (changing the mode empties the queue at once), which takes at most as
    long again (braking has the back-EMF on its side). The first run has
    ``abs(distance_mm)`` of room in the direction of its sign from where the axis stands;
    the second comes back over the same stretch, so the axis never leaves
    ``[start, start + distance_mm]`` (:func:`reach_room_counts` says how much room a motor
    needs). The following-error limit is off during the test and restored after; the axis
    is left enabled in position mode, holding.

    Raises:
        ArgumentError: a distance of zero or under 100 counts, one that would leave the
            axis's travel (:func:`check_within_travel`), or a run that was still
            accelerating when it had used its room (give more distance).
        DeviceError: the axis did not move, the output did not saturate, or it did not come
            to rest in time.
        DeviceFaultError: the device faulted during the test.
    """
    if not (math.isfinite(distance_mm) and distance_mm != 0):
        raise ArgumentError(f"distance_mm {distance_mm!r} must be a finite non-zero distance",
                              reason="distance_mm")
    target = machine.axis(axis)
    client = target.client
    room = abs(target.scale.to_counts(distance_mm))
    if room < 100:
        raise ArgumentError(
            f"distance_mm {distance_mm!r} is {room} counts; a reach test needs at least 100",
            reason="distance_mm",
        )
    check_within_travel(machine, axis, distance_mm, what="a reach test",
                        reason="distance_mm")
    records: list[Diagnostics] = []
    limit = target.config.following_error_limit_counts
    try:
        with client.listening(diagnostics=records.append):
            try:
                client.set_following_error_limit(0)
                machine.set_mode(ControlMode.POSITION, axes=[axis])
                client.set_servo_enable(True)
                client.set_diagnostics_interval(1)
                start = client.status().actual_counts
                direction = 1 if distance_mm > 0 else -1
                first = _saturated_run(machine, axis, records, direction, room, run_timeout_s)
                back_room = abs(client.status().actual_counts - start)
                second = _saturated_run(machine, axis, records, -direction, back_room,
                                        run_timeout_s)
            finally:
                client.set_diagnostics_interval(0)
                client.sync()
    finally:
        client.set_following_error_limit(limit)
    runs = (first, second)
    supply_v = max(float(np.max(np.abs(run.output_v))) for run in runs)
    scale = target.config.counts_per_mm
    reach = AxisReach(
        velocity_mm_s=min(run.fit.top_speed_counts_s for run in runs) / scale,
        accel_mm_s2=min(run.fit.accel_counts_s2 for run in runs) / scale,
    )
    return ReachMeasurement(axis, supply_v, runs, reach)


def _saturated_run(machine: Machine, axis: str, records: list[Diagnostics], direction: int,
                   room: int, timeout_s: float) -> ReachRun:
    """One run from rest at full voltage with ``room`` counts ahead, braked, at rest again."""
    client = machine.axis(axis).client
    clock = machine.clock
    period_s = machine.config.motion_period_s
    tick_s = machine.config.servo_period_s
    _settle(machine, axis, records, timeout_s)
    begin = len(records)
    resting = records[-1]
    feed = max(2, math.ceil(_FEED_S / period_s))
    value = direction * SATURATING_COUNTS_S
    client.set_gains(kp=REACH_GAINS.kp, ki=REACH_GAINS.ki, kd=REACH_GAINS.kd)
    client.set_control_mode(ControlMode.VELOCITY)
    client.add_setpoints([value] * feed)
    deadline = clock.now() + timeout_s
    while True:
        clock.sleep(_POLL_S)
        queued, _ = client.queue_status()
        last = records[-1]
        moved = direction * (last.actual_counts - resting.actual_counts)
        lag_counts = abs(last.velocity_counts_s) * _HOST_LAG_S
        if 2 * (moved + lag_counts) >= room:
            break
        if clock.now() > deadline:
            machine.set_mode(ControlMode.POSITION, axes=[axis])
            scale = machine.axis(axis).config.counts_per_mm
            raise DeviceError(
                f"axis {axis}: moved {moved / scale:.3g} mm of the {room / 2 / scale:.3g} mm"
                f" it may accelerate over in {timeout_s:g} s at full voltage: is the motor"
                " connected, powered and free to turn?", device=client.name,
            )
        if queued < feed // 2:
            client.add_setpoints([value] * (feed - queued))
    machine.set_mode(ControlMode.POSITION, axes=[axis])
    _settle(machine, axis, records, timeout_s)
    taken = [i for i in range(begin, len(records)) if records[i].desired == value]
    if not taken or taken[0] == 0 or taken[-1] - taken[0] + 1 != len(taken):
        raise DeviceError(
            f"axis {axis}: the run at full voltage was not one unbroken stretch of ticks (the"
            " queue ran dry: the host fell behind)", device=client.name,
        )
    rest = records[taken[0] - 1]
    run = records[taken[0]:taken[-1] + 1]
    ticks = np.array([r.clock - rest.clock for r in run], dtype=np.float64)
    moved_counts = np.array([direction * (r.actual_counts - rest.actual_counts) for r in run],
                            dtype=np.float64)
    output_v = np.array([r.output_mv / 1000 for r in run], dtype=np.float64)
    if np.any(direction * output_v < np.max(np.abs(output_v))):
        raise DeviceError(
            f"axis {axis}: the output did not stay at the supply during the run"
            f" ({np.min(direction * output_v):g} V at the least, {np.max(np.abs(output_v)):g} V"
            " at the most)", device=client.name,
        )
    times = ticks * tick_s
    fit = fit_saturated_run(times, moved_counts)
    if times[-1] < _MIN_TIME_CONSTANTS * fit.time_constant_s:
        scale = machine.axis(axis).config.counts_per_mm
        raise ArgumentError(
            f"axis {axis}: still accelerating after {moved_counts[-1] / scale:.3g} mm"
            f" ({times[-1] * 1000:.0f} ms, {times[-1] / fit.time_constant_s:.1f} time constants"
            f" of {fit.time_constant_s * 1000:.1f} ms; at least {_MIN_TIME_CONSTANTS:g}"
            f" needed): give the test at least {reach_room_counts(fit) / scale:.2g} mm",
            reason="distance_mm",
        )
    extent = max(direction * (r.actual_counts - rest.actual_counts) for r in records[begin:])
    return ReachRun(direction, times, moved_counts, output_v, fit, extent)


def reach_room_counts(fit: SaturatedFit) -> float:
    """The room :func:`measure_reach` needs for a motor like ``fit``, counts, with a fifth
    to spare: each run stops accelerating at half its room (less the host's lag), and the
    run back has the room the first left it, so ``4 x`` the distance of
    :data:`_MIN_TIME_CONSTANTS` time constants from rest ``+ 6 x`` the lag's."""
    speed, tau = fit.top_speed_counts_s, fit.time_constant_s
    span = _MIN_TIME_CONSTANTS
    accelerating = speed * tau * (span + math.expm1(-span))
    return 1.2 * (4 * accelerating + 6 * speed * _HOST_LAG_S)


def _settle(machine: Machine, axis: str, records: list[Diagnostics], timeout_s: float) -> None:
    """Wait until the axis has been at rest (speed 0) for 20 ticks.

    Raises:
        DeviceFaultError: the device faulted.
        DeviceError: not at rest within ``timeout_s``.
    """
    client = machine.axis(axis).client
    deadline = machine.clock.now() + timeout_s
    while True:
        machine.clock.sleep(0.02)
        status = client.status()
        if status.fault:
            raise DeviceFaultError(f"axis {axis}: {status.fault_name} during the reach test",
                                   device=client.name)
        tail = records[-20:]
        if len(tail) == 20 and all(r.velocity_counts_s == 0 for r in tail):
            return
        if machine.clock.now() > deadline:
            raise DeviceError(f"axis {axis}: not at rest {timeout_s:g} s after the run",
                              device=client.name)
