"""Identification of one axis on a connected machine: excite it within a stated travel,
record every tick, fit :class:`~usbmotion.autotune.model.AxisModel`.

The device has no open-loop voltage mode, and needs none: each diagnostics line carries the
output the drive held over that tick, so any excitation serves. Two are used:

1. a probe, before any position loop closes: velocity mode on a small proportional gain
   (a loop too weak to run away even with the encoder reversed) asking for a speed that
   puts about a quarter of the supply on the motor for :data:`PROBE_S` (half, when that
   did not move it); the axis must move a few counts, and the way the voltage pushes. It
   stops here, servo disabled, when it does not move (a stall: blocked, unpowered, encoder
   unplugged) or moves the other way (the encoder or the motor wired reversed).
2. moves in position mode on the axis's own proportional and derivative gains, its integral
   gain off (so that each rest is a rest: an integrator would keep pushing the stuck shaft
   past its Coulomb torque, a count at a time): trapezoids of varied length, speed and
   acceleration (up to the machine file's ``max_velocity_mm_s`` and ``max_accel_mm_s2``),
   both ways, each followed by a rest, all within ``[here, here + travel]`` less a margin;
   the host watches every tick as it comes and stops the axis if it leaves that stretch,
   stalls at the ceiling, or runs against its voltage.
"""

from __future__ import annotations

import contextlib
import math
from dataclasses import dataclass

import numpy as np

from usbmotion.autotune.model import FloatArray, ModelFit, fit_model
from usbmotion.errors import ArgumentError, DeviceError, DeviceFaultError
from usbmotion.host.device import ControlMode, Diagnostics
from usbmotion.host.machine import Machine
from usbmotion.protocol import CallNumber
from usbmotion.tuning import check_within_travel, stands_at_mm

MAX_DURATION_S = 10.0
"""The longest an identification may move the axis, probe included."""
PROBE_S = 0.04
"""How long the probe pushes."""
PROBE_SHARE = 0.25
"""The share of the supply the probe asks for (twice that when the axis did not move)."""
PROBE_GAIN_V_PER_COUNT_S = 1e-4
"""The probe's velocity-mode gain: a loop gain of about 0.1 on a motor like the default
(900 counts/s per V), stable whichever way the encoder counts."""
PROBE_MIN_COUNTS = 3
"""The probe must move at least this far, the way its voltage pushes."""
REST_S = 0.15
"""The rest after each move: the shaft stops, and the fit starts its stretches there."""
MARGIN_SHARE = 0.05
"""The share of the travel left free at each end for the following error."""
STALL_TICKS = 100
"""Ticks at the ceiling without a count of motion that make a stall."""
MIN_ROOM_COUNTS = 200
"""The least travel an identification accepts, counts."""

_MOVES = (
    # (share of the room, share of max velocity, share of max acceleration)
    (1.00, 0.50, 0.50),
    (0.50, 1.00, 1.00),
    (0.75, 0.30, 0.70),
    (0.40, 0.70, 0.40),
    (0.90, 1.00, 0.60),
    (0.30, 0.45, 1.00),
    (0.60, 0.85, 0.85),
    (0.20, 0.20, 0.30),
)
"""The excitation: moves cycled through, alternating direction, each from the last end."""


@dataclass(frozen=True, slots=True)
class Identification:
    """What ``tune --auto`` learned about one axis.

    Fields:
        axis: the axis letter.
        fit: the fitted model with its standard errors.
        tick_s: the servo period.
        times_s: time of each recorded tick from the excitation's start.
        voltages_v: the drive's output on each tick.
        positions: the count at the end of each tick.
        desired: the position asked for on each tick.
        origin_counts: where the axis stood before the test.
        origin_mm: the same in machine mm, when known (:func:`usbmotion.tuning.stands_at_mm`).
        low_counts, high_counts: the stretch the test was allowed, counts.
        reached_low_counts, reached_high_counts: the least and most position recorded.
        probe_v, probe_counts: the probe's mean voltage and how far it moved (toward the
            travel's direction, positive when the way the voltage pushed).
    """

    axis: str
    fit: ModelFit
    tick_s: float
    times_s: FloatArray
    voltages_v: FloatArray
    positions: FloatArray
    desired: FloatArray
    origin_counts: int
    origin_mm: float | None
    low_counts: int
    high_counts: int
    reached_low_counts: int
    reached_high_counts: int
    probe_v: float
    probe_counts: int


def trapezoid(distance: float, velocity: float, accel: float, period_s: float) -> FloatArray:
    """Positions every ``period_s`` of a rest-to-rest move of ``distance`` (any unit) at
    most ``velocity`` and ``accel``; the last is the end."""
    length = abs(distance)
    if length == 0:
        return np.zeros(1)
    top = min(velocity, math.sqrt(length * accel))
    ramp_t = top / accel
    ramp_d = 0.5 * accel * ramp_t * ramp_t
    cruise_t = (length - 2 * ramp_d) / top
    total = 2 * ramp_t + cruise_t
    t = np.arange(1, math.ceil(total / period_s) + 1) * period_s
    t = np.minimum(t, total)
    up = 0.5 * accel * np.minimum(t, ramp_t) ** 2
    cruise = top * np.clip(t - ramp_t, 0, cruise_t)
    down_t = np.clip(t - ramp_t - cruise_t, 0, ramp_t)
    down = top * down_t - 0.5 * accel * down_t ** 2
    return np.asarray(math.copysign(1.0, distance) * (up + cruise + down), dtype=np.float64)


def excitation(room_counts: float, *, max_velocity_counts_s: float,
               max_accel_counts_s2: float, period_s: float, duration_s: float) -> FloatArray:
    """The excitation's setpoints, counts from the start of the room toward its end, one
    every ``period_s``: from 0 to the margin, then :data:`_MOVES` cycled, each followed by
    :data:`REST_S` of rest, while they fit in ``duration_s``; all within
    ``[margin, room - margin]`` (``margin`` :data:`MARGIN_SHARE` of the room)."""
    margin = MARGIN_SHARE * room_counts
    usable = room_counts - 2 * margin
    rest = np.full(max(1, round(REST_S / period_s)), 0.0)
    pieces = [trapezoid(margin, 0.3 * max_velocity_counts_s, 0.5 * max_accel_counts_s2,
                        period_s)]
    pieces.append(rest + pieces[-1][-1])
    here = margin
    direction = 1.0
    count = sum(p.size for p in pieces)
    index = 0
    while True:
        share, speed, accel = _MOVES[index % len(_MOVES)]
        index += 1
        target = margin + usable * share if direction > 0 else margin + usable * (1 - share)
        if (direction > 0 and target <= here + 1) or (direction < 0 and target >= here - 1):
            target = margin + usable if direction > 0 else margin
        move = here + trapezoid(target - here, speed * max_velocity_counts_s,
                                accel * max_accel_counts_s2, period_s)
        if (count + move.size + rest.size) * period_s > duration_s:
            break
        pieces.extend([move, rest + move[-1]])
        count += move.size + rest.size
        here = float(move[-1])
        direction = -direction
    return np.concatenate(pieces)


def identify_axis(machine: Machine, axis: str, *, travel_mm: float,
                  duration_s: float = 6.0) -> Identification:
    """Excite ``axis`` within ``travel_mm`` of where it stands and fit its model.

    ``travel_mm``: the room from where the axis stands, toward higher positions (negative:
    lower); the axis never leaves it (nor its ``travel_mm`` soft limits, checked first).
    ``duration_s`` (at most :data:`MAX_DURATION_S`) bounds the time the axis moves. The
    axis is left enabled in position mode on its file's gains, holding, or disabled when
    the test stopped it.

    Raises:
        ArgumentError: a travel not finite, under :data:`MIN_ROOM_COUNTS` counts or leaving
            the soft limits; a duration out of range; a record with nothing to fit.
        DeviceError: the probe did not move the axis (a stall) or moved it against its
            voltage (encoder or motor reversed); the axis stalled, ran against its voltage
            or left its stretch during the moves; diagnostics lines were lost. The servo
            is disabled first.
        DeviceFaultError: the device faulted.
    """
    if not (math.isfinite(travel_mm) and travel_mm != 0):
        raise ArgumentError(f"travel_mm {travel_mm!r} must be a finite non-zero distance",
                            reason="travel_mm")
    if not (math.isfinite(duration_s) and 0.5 <= duration_s <= MAX_DURATION_S):
        raise ArgumentError(f"duration_s {duration_s!r} is out of range; allowed: 0.5 to"
                            f" {MAX_DURATION_S:g} s", reason="duration_s")
    target = machine.axis(axis)
    client = target.client
    settings = target.config
    room = abs(target.scale.to_counts(travel_mm))
    if room < MIN_ROOM_COUNTS:
        raise ArgumentError(
            f"travel_mm {travel_mm!r} is {room} counts; an identification needs at least"
            f" {MIN_ROOM_COUNTS} ({MIN_ROOM_COUNTS / settings.counts_per_mm:.3g} mm)",
            reason="travel_mm")
    check_within_travel(machine, axis, travel_mm, what="the identification's travel",
                        reason="travel_mm")
    direction = 1 if travel_mm > 0 else -1
    origin_mm = stands_at_mm(machine, axis)
    tick_s = machine.config.servo_period_s
    period_s = machine.config.motion_period_s
    records: list[Diagnostics] = []
    with client.listening(diagnostics=records.append):
        try:
            machine.set_mode(ControlMode.POSITION, axes=[axis])
            client.set_servo_enable(True)
            origin = client.status().actual_counts
            low, high = (origin, origin + room) if direction > 0 else (origin - room, origin)
            client.set_diagnostics_interval(1)
            supply = client.sim_value(CallNumber.SET_SIM_SOURCE_VOLTAGE)
            probe_v, probe_counts = _probe(machine, axis, records, direction, supply)
            gains = settings.gains
            client.set_gains(kp=gains.kp, ki=0.0, kd=gains.kd)
            client.set_control_mode(ControlMode.POSITION)
            client.sync()
            begin = len(records)
            plan = excitation(room, max_velocity_counts_s=settings.max_velocity_mm_s
                              * settings.counts_per_mm,
                              max_accel_counts_s2=settings.max_accel_mm_s2
                              * settings.counts_per_mm,
                              period_s=period_s, duration_s=duration_s - 2 * PROBE_S)
            here = client.status().actual_counts
            setpoints = [origin + direction * round(p) for p in plan]
            # join from where the probe left the axis: straight to the plan's first point
            setpoints = [here + round((s - here) * min(1.0, (i + 1) / 50))
                         for i, s in enumerate(setpoints[:50])] + setpoints[50:]
            _stream(machine, axis, records, setpoints, low=low, high=high, supply_v=supply,
                    watch_from=begin)
        except (DeviceError, ArgumentError):
            _disable(machine, axis)
            raise
        finally:
            client.set_diagnostics_interval(0)
            client.sync()
    if client.servo_enabled():
        machine.set_mode(ControlMode.POSITION, axes=[axis])
    run = records[begin:]
    clocks = np.array([r.clock for r in run], dtype=np.int64)
    if np.any(np.diff(clocks) != 1):
        raise DeviceError(f"axis {axis}: diagnostics lines were lost during the test"
                          " (the link dropped some): run it again", device=client.name)
    volts = np.array([r.output_mv / 1000 for r in run], dtype=np.float64)
    positions = np.array([r.actual_counts for r in run], dtype=np.float64)
    desired = np.array([r.desired for r in run], dtype=np.float64)
    fit = fit_model(volts, positions, tick_s=tick_s, supply_v=supply)
    return Identification(
        axis=axis, fit=fit, tick_s=tick_s,
        times_s=(clocks - clocks[0]).astype(np.float64) * tick_s,
        voltages_v=volts, positions=positions, desired=desired, origin_counts=origin,
        origin_mm=origin_mm,
        low_counts=low, high_counts=high,
        reached_low_counts=int(min(positions.min(), *(r.actual_counts for r in records))),
        reached_high_counts=int(max(positions.max(), *(r.actual_counts for r in records))),
        probe_v=probe_v, probe_counts=probe_counts,
    )


def _disable(machine: Machine, axis: str) -> None:
    """Stop the axis: empty its queue and disable its servo (errors here are secondary)."""
    client = machine.axis(axis).client
    for action in (client.clear_queue, lambda: client.set_servo_enable(False)):
        with contextlib.suppress(DeviceError, OSError):
            action()


def _probe(machine: Machine, axis: str, records: list[Diagnostics], direction: int,
           supply_v: float) -> tuple[float, int]:
    """Push the axis gently in ``direction`` and check it moves that way: with
    :data:`PROBE_SHARE` of the supply, then, if it did not move, twice that.

    Returns the probe's mean voltage and the counts it moved in ``direction``.
    """
    client = machine.axis(axis).client
    clock = machine.clock
    period_s = machine.config.motion_period_s
    client.set_gains(kp=PROBE_GAIN_V_PER_COUNT_S, ki=0.0, kd=0.0)
    for attempt, share in enumerate((PROBE_SHARE, 2 * PROBE_SHARE)):
        begin = len(records)
        speed = round(share * supply_v / PROBE_GAIN_V_PER_COUNT_S)
        client.set_control_mode(ControlMode.VELOCITY)
        client.add_setpoints([direction * speed] * max(1, round(PROBE_S / period_s)))
        clock.sleep(PROBE_S + 0.01)
        client.sync()
        pushed = [r for r in records[begin:] if r.desired == direction * speed]
        status = client.status()
        if status.fault:
            raise DeviceFaultError(f"axis {axis}: {status.fault_name} during the probe",
                                   device=client.name)
        if not pushed:
            raise DeviceError(f"axis {axis}: the probe recorded nothing (no diagnostics"
                              " came)", device=client.name)
        first = records[begin - 1].actual_counts if begin else pushed[0].actual_counts
        moved = direction * (pushed[-1].actual_counts - first)
        volts = float(np.mean([r.output_mv for r in pushed])) / 1000
        ms = len(pushed) * machine.config.servo_period_s * 1000
        if moved <= -PROBE_MIN_COUNTS:
            client.set_servo_enable(False)
            raise DeviceError(
                f"axis {axis}: {volts:+.2f} V for {ms:.0f} ms moved it {direction * moved:+d}"
                " counts, against the voltage: the encoder counts backwards or the motor is"
                " wired reversed (swap the encoder's A and B channels, or the motor's"
                " leads); the servo is disabled", device=client.name)
        if moved >= PROBE_MIN_COUNTS:
            return volts, moved
        if attempt == 1:
            client.set_servo_enable(False)
            raise DeviceError(
                f"axis {axis}: stalled: {volts:+.2f} V for {ms:.0f} ms moved it {moved}"
                f" counts (at least {PROBE_MIN_COUNTS} expected): is it blocked, is the motor"
                " powered and connected, is the encoder plugged in? The servo is disabled",
                device=client.name)
    raise AssertionError("unreachable")


def _stream(machine: Machine, axis: str, records: list[Diagnostics], setpoints: list[int],
            *, low: int, high: int, supply_v: float, watch_from: int) -> None:
    """Feed ``setpoints`` and watch every tick until the queue has run dry for a few polls.

    Raises:
        DeviceError: the axis left ``[low, high]``, stalled at the ceiling (:data:`STALL_TICKS`
            at 95 % of it without a count of motion) or sped up against a voltage of at
            least half the supply for 20 ticks (braking slows it down).
        DeviceFaultError: the device faulted.
    """
    client = machine.axis(axis).client
    clock = machine.clock
    scale = machine.axis(axis).config.counts_per_mm
    sent = 0
    checked = watch_from
    ceiling_run = 0
    against_run = 0
    against_from = 0
    last_speed = 0
    idle_polls = 0
    while True:
        queued, free = client.queue_status()
        if sent < len(setpoints) and free >= 200:
            batch = setpoints[sent:sent + min(free - 100, 500)]
            client.add_setpoints(batch)
            sent += len(batch)
        for record in records[checked:]:
            position = record.actual_counts
            if not low <= position <= high:
                beyond = position - (low if position < low else high)
                raise DeviceError(
                    f"axis {axis}: at {position} counts it left the test's stretch"
                    f" [{low}, {high}] ({beyond / scale:+.3f}"
                    " mm beyond it): its gains cannot follow the test; the servo is disabled",
                    device=client.name)
            volts = record.output_mv / 1000
            if abs(volts) >= 0.95 * supply_v and abs(record.velocity_counts_s) == 0:
                ceiling_run += 1
            else:
                ceiling_run = 0
            speed = abs(record.velocity_counts_s)
            if (abs(volts) >= 0.5 * supply_v and record.velocity_counts_s * volts < 0
                    and speed >= last_speed):
                if against_run == 0:
                    against_from = last_speed
                against_run += 1
            else:
                against_run = 0
            last_speed = speed
            if ceiling_run >= STALL_TICKS:
                raise DeviceError(
                    f"axis {axis}: stalled at {position} counts: {volts:+.2f} V for"
                    f" {STALL_TICKS} ticks and it did not move: is it blocked? The servo is"
                    " disabled", device=client.name)
            if against_run >= 20 and speed > against_from:
                raise DeviceError(
                    f"axis {axis}: it sped up against its voltage ({volts:+.2f} V,"
                    f" {record.velocity_counts_s:+d} counts/s) for 20 ticks: the encoder or the"
                    " motor is wired reversed; the servo is disabled", device=client.name)
        checked = len(records)
        if sent >= len(setpoints) and queued == 0:
            idle_polls += 1
            if idle_polls > 3:
                break
        clock.sleep(0.02)
        if len(records) == checked:
            status = client.status()
            if status.fault:
                raise DeviceFaultError(f"axis {axis}: {status.fault_name} during the test",
                                       device=client.name)
    status = client.status()
    if status.fault:
        raise DeviceFaultError(f"axis {axis}: {status.fault_name} during the test",
                               device=client.name)


__all__ = ["MAX_DURATION_S", "Identification", "excitation", "identify_axis", "trapezoid"]
