"""Homing a machine: grbl's cycle on every axis in the configured order
(:mod:`usbmotion.automation.homing`), machine zero set once from the switch edge the device
latched, and the homed mark a device carries afterwards.

:meth:`MachineSession.home` runs a :class:`HomingCycle` and keeps the machine's state.
"""

from __future__ import annotations

import zlib
from collections.abc import Callable, Sequence
from dataclasses import replace

from usbmotion.automation.device_io import DeviceHomingIO, HomingAxis, MachineZero
from usbmotion.automation.homing import Home, MoveAxisHome
from usbmotion.automation.sequence import run_sequence
from usbmotion.errors import DeviceError, SequenceFaultError, StopRequestedError, UsbMotionError
from usbmotion.host.config import AxisConfig, MachineConfig
from usbmotion.host.machine import Machine
from usbmotion.session.rest import REST_POLL_S, REST_TIMEOUT_S

HOMING_POLL_HZ = 50.0


def homed_mark(config: MachineConfig, axis: AxisConfig) -> int:
    """The homed mark (1..255) a device of this machine carries once homed: it names the
    machine and the axis's switch position, so another machine file's homing does not
    pass for this one's."""
    text = f"{config.name}|{axis.name}|{axis.homing.position_mm!r}|{axis.counts_per_mm!r}"
    if axis.stepper is not None:
        text += f"|stepper {axis.stepper.loop} {axis.stepper.microsteps_per_rev}"
    return 1 + zlib.crc32(text.encode("utf-8")) % 255


def home_position_mm(axis: AxisConfig) -> float:
    """Where homing leaves an axis: the switch's machine position, pulled off toward the
    travel (an axis homed by declaring: the position declared)."""
    if axis.homing.declare:
        return axis.homing.position_mm
    return axis.homing.position_mm - axis.homing.direction * axis.homing.pull_off_mm


def homing_timeout_s(config: MachineConfig) -> float:
    """The longest homing may take: every group's worst axis, seek to pull-off, twice."""
    total = 0.0
    for group in config.homing_order or (config.axis_names,):
        worst = 0.0
        for name in group:
            homing = config.axis(name).homing
            locate = 2 * (5 * homing.backoff_mm + 1.0) / homing.slow_speed_mm_s
            worst = max(worst, homing.search_mm / homing.speed_mm_s + locate
                        + homing.pull_off_mm / homing.speed_mm_s)
        total += worst
    return 2 * total + 10.0


class HomingCycle:
    """grbl's homing cycle on every axis of a connected machine, in the configured order.

    Parameters:
        machine: the connected machine.
        axes: the axes to home (default: every axis).
        keep_alive_period_s: how often the devices' watchdogs need a command (0: none).
        stop_now: True once a stop must not wait for the deceleration (every axis is then
            stopped at once).
    """

    def __init__(self, machine: Machine, *, keep_alive_period_s: float,
                 stop_now: Callable[[], bool], axes: Sequence[str] | None = None) -> None:
        self.machine = machine
        self.stop_now = stop_now
        config = machine.config
        self.names = list(machine.axes) if axes is None else list(axes)
        """The axes this cycle homes."""
        self.io = DeviceHomingIO(
            {name: HomingAxis(
                client=axis.client, scale=axis.scale, direction=axis.config.homing.direction,
                accel_mm_s2=axis.config.max_accel_mm_s2, switch_mm=axis.config.homing.position_mm,
                pull_off_speed_mm_s=axis.config.homing.speed_mm_s,
                velocity_gains=(axis.config.velocity_gains.kp, axis.config.velocity_gains.ki,
                                axis.config.velocity_gains.kd),
                gains=(axis.config.gains.kp, axis.config.gains.ki, axis.config.gains.kd),
                turn_counts=(None if axis.config.absolute_encoder is None
                             else axis.config.absolute_encoder.turn_counts),
            ) for name, axis in machine.axes.items() if name in self.names},
            clock=machine.clock, poll_period_s=1.0 / HOMING_POLL_HZ,
            tick_s=config.servo_period_s, motion_scalar=config.motion_scalar,
            keep_alive_s=keep_alive_period_s or 1.0,
        )
        groups = [[name for name in group if name in self.names]
                  for group in config.homing_order]
        order = [group for group in groups if group] or None
        self.sequence = Home(self.names, self._axis_home, order=order)
        self.positions_mm: dict[str, float] = {}
        """Axis -> its position as last read while homing, mm."""

    def _axis_home(self, name: str) -> MoveAxisHome:
        homing = self.machine.axis(name).config.homing
        return MoveAxisHome(name, homing.speed_mm_s, slow_speed_mm_s=homing.slow_speed_mm_s,
                            backoff_mm=homing.backoff_mm, search_mm=homing.search_mm,
                            pull_off_mm=homing.pull_off_mm)

    def enter_velocity_mode(self) -> None:
        """Every axis in velocity mode with its velocity gains, queue empty, servo enabled."""
        self.io.enter_velocity_mode()

    def run(self, *, should_stop: Callable[[], str],
            on_positions: Callable[[dict[str, float]], None] | None = None,
            ) -> dict[str, MachineZero]:
        """Run the cycle (after :meth:`enter_velocity_mode`); returns each axis's machine
        zero. A stop or a fault brings every axis to rest before the error propagates.
        ``on_positions`` is called at every poll with each axis's position as last read,
        mm (device counts scaled until its zero is set).

        Raises:
            StopRequestedError: ``should_stop`` gave a reason.
            SequenceFaultError: a switch was not found, did not open, or closed the wrong
                way round (names the axis).
            DeviceError: a device faulted or refused.
        """
        machine, io, sequence = self.machine, self.io, self.sequence
        try:
            run_sequence(sequence, io, io, clock=machine.clock, rate_hz=HOMING_POLL_HZ,
                         timeout_s=homing_timeout_s(machine.config),
                         on_poll=lambda _: self._after_poll(on_positions),
                         should_stop=should_stop)
        except StopRequestedError:
            self._settle()
            raise
        except (SequenceFaultError, UsbMotionError) as error:
            try:
                sequence.stop(io)
                self._settle()
            except UsbMotionError as also:
                error.add_note(f"bringing the axes to rest afterwards failed too: {also}")
                try:
                    machine.stop()
                except UsbMotionError as stop_failed:
                    error.add_note(f"and disabling them failed: {stop_failed}")
            raise
        zeroes: dict[str, MachineZero] = {}
        for name, zero in io.zeroes.items():
            seen_mm = sequence.axes[name].seen_closed_mm
            seen = zero.edge_counts if seen_mm is None else machine.axis(name).scale.to_counts(
                -machine.axis(name).config.homing.direction * seen_mm)
            zeroes[name] = replace(zero, seen_counts=seen)
        return zeroes

    def _after_poll(self, on_positions: Callable[[dict[str, float]], None] | None) -> None:
        if on_positions is not None:
            self.positions_mm.update(self.io.read_positions_mm())
            on_positions(dict(self.positions_mm))
        self.io.after_poll()

    def _settle(self) -> None:
        """After a stopped homing: wait until every axis has ramped to rest."""
        machine, io = self.machine, self.io
        deadline = machine.clock.now() + REST_TIMEOUT_S
        names = self.names
        while True:
            if self.stop_now():
                machine.stop()
                return
            if all(io.at_rest(name) for name in names):
                return
            if machine.clock.now() > deadline:
                raise DeviceError("the axes did not come to rest after homing stopped",
                                  device=", ".join(names))
            io.after_poll()
            machine.clock.sleep(REST_POLL_S)
