"""The spindle: a USB Motion Device in velocity mode, kept spinning by the host.

In velocity mode a device takes one velocity (counts/s) from its queue every motion period
and brakes to a stop when the queue runs dry (PROTOCOL.md, the servo tick): a spindle turns
only as long as its host keeps the queue fed, so a host that goes away stops it. The
spindle's queue holds a value every :data:`FEED_PERIOD_S`; :meth:`Spindle.service` keeps
:data:`LEAD_S` of them queued (a refill when less than :data:`REFILL_S` is left), and a new
speed replaces the queued future from a tick just ahead (call 38): the speed ramps from
the one the device runs now to the new one at ``accel_rpm_s``, and holds it.

The speed a front shows is the encoder's (call 20's measured velocity), never the one
asked: :meth:`Spindle.read` reads it; :meth:`Spindle.at_speed` says whether the ramp is
over and the measured speed within ``at_speed_tolerance`` of it (LinuxCNC's
spindle-at-speed); :meth:`Spindle.stalled` whether, once at speed, it fell further than
``stall_tolerance`` from it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from usbmotion.errors import OutOfRangeError
from usbmotion.host.config import SIM_MOTOR_CALLS, SpindleConfig
from usbmotion.host.device import DeviceClient
from usbmotion.protocol import QUEUE_CAPACITY, ControlMode
from usbmotion.protocol.table import INT32_MAX, INT32_MIN

FEED_PERIOD_S = 0.01
"""Seconds between the spindle's queue values (its motion scalar is this over the servo
period)."""
LEAD_S = 3.0
"""How far ahead the spindle's queue is kept fed, seconds."""
REFILL_S = 1.5
"""A refill comes once less than this is left in the queue, seconds: the host may be
silent this long before the spindle would brake (a watchdog still stops it sooner)."""
AHEAD_S = 0.01
"""A new speed starts this far after the tick the device last reported (link latency)."""


@dataclass(frozen=True, slots=True)
class SpindleNow:
    """The spindle as last read.

    Fields:
        commanded_rpm: the speed asked (signed: + clockwise, M3; - counter-clockwise, M4).
        ramp_rpm: the speed the device is told this tick (on the ramp to ``commanded_rpm``).
        measured_rpm: the encoder's speed, signed.
        at_speed: the ramp is over and the measured speed within the tolerance.
        tick: the device clock of the reading.
    """

    commanded_rpm: float = 0.0
    ramp_rpm: float = 0.0
    measured_rpm: float = 0.0
    at_speed: bool = True
    tick: int = 0


class Spindle:
    """A spindle device (see the module docstring).

    Parameters:
        client: the spindle device's link.
        config: its ``[spindle]`` table.
        servo_interval_dms: the machine's servo period (every device runs at it).
        watchdog_ms: the machine's watchdog.
    """

    def __init__(self, client: DeviceClient, config: SpindleConfig, *,
                 servo_interval_dms: int, watchdog_ms: int) -> None:
        self.client = client
        self.config = config
        self.servo_interval_dms = servo_interval_dms
        self.watchdog_ms = watchdog_ms
        self.tick_s = servo_interval_dms * 1e-4
        self.scalar = max(1, min(65535, round(FEED_PERIOD_S / self.tick_s)))
        self.period_s = self.scalar * self.tick_s
        self.commanded_rpm = 0.0
        self.override = 100
        """The spindle speed override, percent (grbl's 0x99-0x9D): the device turns at the
        commanded speed times this."""
        self._override_asked = 100
        self.now = SpindleNow()
        self._last_value = 0  # the last queued velocity, counts/s
        self._queued_to_tick = 0  # the tick after the last queued value's period
        self._ramp_end_tick = 0
        self._refill_at_s = math.inf
        self._read_tick = 0
        self._read_s = 0.0
        self.was_at_speed = False
        """Reached its commanded speed since the last change (stall detection arms)."""

    # --- setting up ----------------------------------------------------------------------------

    def configure(self) -> None:
        """Servo off, the period, velocity mode with its gains, no following-error limit,
        the machine's watchdog, and a simulated motor's values (no switches)."""
        client, config = self.client, self.config
        client.set_servo_enable(False)
        client.set_servo_interval_dms(self.servo_interval_dms)
        client.set_motion_scalar(self.scalar)
        gains = config.velocity_gains
        client.set_gains(kp=gains.kp, ki=gains.ki, kd=gains.kd)
        client.set_control_mode(ControlMode.VELOCITY)
        client.set_following_error_limit(0)
        client.set_watchdog_ms(self.watchdog_ms)
        sim = config.sim
        if sim is not None:
            client.set_sim_interval_dms(sim.update_interval_dms)
            for key, call in SIM_MOTOR_CALLS:
                client.set_sim_value(call, getattr(sim, key), label=key)
            client.set_sim_counts_per_revolution(sim.counts_per_revolution)
            client.set_sim_travel(INT32_MIN, INT32_MAX)
        self.commanded_rpm = 0.0
        self._last_value = 0
        self._refill_at_s = math.inf
        self.now = SpindleNow()

    # --- commanding ----------------------------------------------------------------------------

    def check_rpm(self, rpm: float) -> None:
        """Refuse a speed beyond ``max_rpm``.

        Raises:
            OutOfRangeError: names the speed and the machine's maximum.
        """
        if not math.isfinite(rpm) or abs(rpm) > self.config.max_rpm:
            raise OutOfRangeError(
                f"spindle speed S{abs(rpm):g} is beyond the spindle's max_rpm"
                f" {self.config.max_rpm:g}; allowed: 0..{self.config.max_rpm:g} rpm",
                reason="S")

    def command(self, rpm: float) -> None:
        """Turn at ``rpm`` (signed; 0 stops along the ramp): the queued future replaced
        from a tick just ahead by the ramp from the speed the device runs there.

        Raises:
            OutOfRangeError: beyond ``max_rpm``.
        """
        self.check_rpm(rpm)
        self.commanded_rpm = rpm
        self.was_at_speed = False
        self._restart()

    def ask_override(self, percent: int) -> None:
        """The spindle override (10..200 %), asked from any thread: :meth:`service` (on the
        thread that drives the device) applies it."""
        self._override_asked = max(10, min(200, percent))

    def set_override(self, percent: int) -> None:
        """The spindle override (10..200 %): the running speed follows at once."""
        self.override = self._override_asked = max(10, min(200, percent))
        if self.commanded_rpm:
            self._restart()

    @property
    def target_rpm(self) -> float:
        """The speed the device is ramping to: the commanded one at the override."""
        return self.commanded_rpm * self.override / 100.0

    def _restart(self) -> None:
        """The ramp from the velocity the device is told now (0 when its servo is off) to
        the target, then the target held for :data:`LEAD_S`, from a tick just ahead."""
        client = self.client
        status = client.status()
        self._remember(status.clock)
        if not status.enabled and self.target_rpm == 0:
            return
        start_value = status.desired_counts if status.enabled else 0
        ramp = self._ramp_values(start_value)
        values = self._ramp(start_value, self._lead_values())
        if status.enabled:
            start = status.clock + max(1, math.ceil(AHEAD_S / self.tick_s))
            # call 50: a line that comes late delays the ramp rather than cutting it short
            # (a jump in speed; every value past, the queue left empty: the spindle braking)
            start += client.stop_from(start, values).late * self.scalar
        else:  # the queue starts on the first tick after enabling
            client.clear_queue()
            client.add_setpoints(values.tolist())
            client.set_servo_enable(True)
            start = status.clock + 1
        self._queued_to_tick = start + len(values) * self.scalar
        self._ramp_end_tick = start + ramp * self.scalar
        self._plan_refill()

    def _target_value(self) -> int:
        return self.config.counts_per_s(self.target_rpm)

    def _ramp_values(self, start_value: int) -> int:
        step = self.config.accel_rpm_s * self.config.counts_per_revolution / 60.0 * self.period_s
        return math.ceil(abs(self._target_value() - start_value) / step) if step > 0 else 0

    def _ramp(self, start_value: int, count: int) -> np.ndarray:
        """``count`` values from ``start_value`` on, at the acceleration, up to the target
        (then held); the last one is remembered."""
        target = self._target_value()
        step = self.config.accel_rpm_s * self.config.counts_per_revolution / 60.0 * self.period_s
        k = np.arange(1, count + 1, dtype=np.float64)
        if target >= start_value:
            values = np.minimum(start_value + k * step, target)
        else:
            values = np.maximum(start_value - k * step, target)
        out = np.rint(values).astype(np.int64)
        if count:
            self._last_value = int(out[-1])
        return out

    def _lead_values(self) -> int:
        return min(QUEUE_CAPACITY - 10, round(LEAD_S / self.period_s))

    def _remember(self, tick: int) -> None:
        self._read_tick = tick
        self._read_s = self.client.transport.clock.now()

    def _tick_now(self) -> int:
        return self._read_tick + round((self.client.transport.clock.now() - self._read_s)
                                       / self.tick_s)

    def _plan_refill(self) -> None:
        left_s = (self._queued_to_tick - self._tick_now()) * self.tick_s
        self._refill_at_s = self.client.transport.clock.now() + max(0.0, left_s - REFILL_S)

    # --- keeping it fed ------------------------------------------------------------------------

    @property
    def running(self) -> bool:
        """The device is told to turn (or still ramping down)."""
        return self.commanded_rpm != 0 or self._last_value != 0

    def service(self) -> None:
        """Keep the queue fed while the spindle turns (a refill when due, else nothing);
        once a stop's ramp reached 0, the servo off (the motor free, as a spindle off)."""
        if self._override_asked != self.override:
            self.set_override(self._override_asked)
        if not self.running and self._refill_at_s == math.inf:
            return
        if self.client.transport.clock.now() < self._refill_at_s:
            return
        status = self.client.status()
        self._remember(status.clock)
        if not self.running:
            if status.clock >= self._ramp_end_tick:
                self.client.set_servo_enable(False)
                self._refill_at_s = math.inf
            else:
                self._plan_refill()
            return
        count = self._lead_values() - status.queued
        if count > 0:
            self.client.add_setpoints(self._ramp(self._last_value, count).tolist())
            self._queued_to_tick = max(self._queued_to_tick, status.clock) + count * self.scalar
        self._plan_refill()

    def next_service_s(self) -> float:
        """When :meth:`service` next writes to the device (host clock, s; inf: never)."""
        return self._refill_at_s

    # --- reading -------------------------------------------------------------------------------

    def read(self) -> SpindleNow:
        """The spindle now: call 20's measured velocity, the ramp's and the commanded."""
        status = self.client.status()
        self._remember(status.clock)
        config = self.config
        measured = config.rpm(status.velocity_counts_s)
        ramp = config.rpm(status.desired_counts) if status.enabled else 0.0
        target = self.target_rpm
        ramp_done = status.clock >= self._ramp_end_tick
        if target:
            at_speed = ramp_done and abs(measured - target) <= config.at_speed_tolerance * abs(
                target)
        else:
            at_speed = abs(measured) <= config.at_speed_tolerance * config.max_rpm
        if at_speed and target:
            self.was_at_speed = True
        self.now = SpindleNow(commanded_rpm=self.commanded_rpm, ramp_rpm=ramp,
                              measured_rpm=measured, at_speed=at_speed, tick=status.clock)
        return self.now

    def ramp_s(self, rpm: float) -> float:
        """How long the ramp from the commanded speed to ``rpm`` takes, s."""
        return abs(rpm - self.commanded_rpm) / self.config.accel_rpm_s

    def stalled(self) -> str | None:
        """After :meth:`read`: why the spindle counts as stalled (it was at speed and fell
        beyond ``stall_tolerance``), or None."""
        now, target = self.now, self.target_rpm
        if not (self.was_at_speed and target) or now.tick < self._ramp_end_tick:
            return None
        if abs(now.measured_rpm - target) <= self.config.stall_tolerance * abs(target):
            return None
        return (f"spindle stalled: {now.measured_rpm:.0f} rpm measured against"
                f" {target:.0f} rpm commanded (beyond {self.config.stall_tolerance:.0%})")

    def halt(self) -> None:
        """At once: queue emptied, servo off (the spindle coasts: a fault or a lost link)."""
        self.client.clear_queue()
        self.client.set_servo_enable(False)
        self.commanded_rpm = 0.0
        self._last_value = 0
        self._refill_at_s = math.inf
