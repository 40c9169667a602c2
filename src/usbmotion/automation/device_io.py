"""Homing's inputs and outputs over real (or simulated) devices, in mm, in the homing
orientation.

Each axis is seen turned so that it homes toward negative positions onto its "lower"
switch: an axis that homes onto its upper switch has its positions, velocities and
switches mirrored here, so :mod:`usbmotion.automation.homing` is written once.

Velocities are velocity-mode setpoints (control mode 2). A change of velocity is a ramp at
the axis's acceleration limit, sent with call 38 from a device tick a little ahead of now,
so it continues exactly from what the device is doing whatever the link's latency; a
velocity is held for a few polling periods, so if the host stops polling the queue runs dry
and the device brings the axis to rest by itself. The device clock each poll reads (call
20) dates the ramps. Zeroing uses the switch edge the device latched (call 36): one shift of
the counter (call 37) puts that edge at the switch's machine position, then a planned move
in position mode pulls the axis off the switch.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field

from usbmotion.automation.homing import LimitSwitchState, SwitchEdgeReading
from usbmotion.clock import Clock
from usbmotion.errors import ArgumentError, DeviceFaultError
from usbmotion.host.device import AxisScale, ControlMode, DeviceClient, Status, SwitchEdge
from usbmotion.motion.profiles import trapezoid_profile
from usbmotion.protocol import QUEUE_CAPACITY
from usbmotion.protocol.table import INT32_MAX, INT32_MIN

LEAD_S = 0.003
"""How far ahead of the device's present tick a ramp starts: covers the link's latency (a
late line loses nothing: call 38 skips what is already past)."""
REST_COUNTS = 1
"""An axis is at rest when, its queue empty, it moved at most this much over one poll."""


@dataclass(frozen=True, slots=True)
class HomingAxis:
    """What homing needs to know of one axis.

    Fields:
        client: the device.
        scale: counts per mm.
        direction: -1 homes onto the lower switch, +1 onto the upper one.
        accel_mm_s2: the ramps' acceleration.
        switch_mm: the machine position of the switch's closing edge.
        pull_off_speed_mm_s: the speed of the final move off the switch.
        velocity_gains, gains: (kp, ki, kd) of velocity mode (homing) and position mode.
        turn_counts: an absolute encoder's turn, counts (``None``: an incremental encoder).
            The zero is then the turn boundary nearest the switch's edge (LinuxCNC's index
            homing, the boundary standing for the index): it repeats to the encoder's count
            however the switch repeats, within half a turn.
    """

    client: DeviceClient
    scale: AxisScale
    direction: int
    accel_mm_s2: float
    switch_mm: float
    pull_off_speed_mm_s: float
    velocity_gains: tuple[float, float, float]
    gains: tuple[float, float, float]
    turn_counts: int | None = None


@dataclass(frozen=True, slots=True)
class MachineZero:
    """How homing set an axis's machine zero: the latched edge it zeroed on (its counter
    value then, its tick) and the shift of the counter that put the edge at the switch's
    machine position. Homing the same machine again gives a shift of 0: the spread of the
    shifts over repeated homings is the zero's repeatability, in counts."""

    edge_counts: int
    edge_tick: int
    shift_counts: int
    seen_counts: int = 0
    """The counter at the poll that first saw the switch closed (same coordinates as
    ``edge_counts``): a zero taken there would be ``seen_counts - edge_counts`` off."""
    turn_counts: int = 0
    """An absolute encoder's turn, counts (0: incremental, zeroed on the edge itself)."""
    edge_from_turn_counts: int = 0
    """With an absolute encoder: how far the switch's edge was from the turn boundary the
    zero was put on (-turn/2 to turn/2); near half a turn either way, a switch that repeats
    worse than the margin left may pick the neighbouring turn."""


@dataclass(slots=True)
class _Drive:
    """What one axis's device will do, as far as the host knows, and what it last said.

    ``queue`` is the host's copy of the device's motion queue, next value first: each status
    read trims it to the ``queued`` count the device reports (the device takes from the
    front), so the value due on any coming tick is known.
    """

    queue: list[int] = field(default_factory=list)
    last: int = 0
    """The last value the device takes (position mode holds it once the queue is dry)."""
    position_mode: bool = False
    target: int = 0
    pending: list[int] = field(default_factory=list)
    status: Status | None = None
    status_at_s: float = 0.0
    previous_actual: int | None = None
    edge: SwitchEdge | None = None
    heard_at_s: float = 0.0
    """When the host last read this axis's status (any command keeps its watchdog fed)."""


class DeviceHomingIO:
    """:class:`~usbmotion.automation.homing.HomingInputs` and ``HomingOutputs`` over device
    clients.

    Call :meth:`after_poll` after every poll of the sequence (``run_sequence``'s
    ``on_poll``): it lets the next poll read the devices afresh, tops up planned moves and
    keeps waiting axes' watchdogs fed.

    Parameters:
        axes: axis name -> its :class:`HomingAxis`.
        clock: the host's clock (the devices' links run on it).
        poll_period_s: how often the sequence is polled.
        tick_s: the servo period; motion_scalar: servo ticks per queue value.
        cover_polls: polling periods a held velocity lasts on the device.
        keep_alive_s: an axis whose status nothing read for this long (on ``clock``) gets a
            query, so its watchdog never starves however slowly the polls come.
    """

    def __init__(
        self,
        axes: Mapping[str, HomingAxis],
        *,
        clock: Clock,
        poll_period_s: float,
        tick_s: float,
        motion_scalar: int,
        cover_polls: int = 4,
        keep_alive_s: float = 0.5,
    ) -> None:
        for name, value in (("poll_period_s", poll_period_s), ("tick_s", tick_s),
                            ("keep_alive_s", keep_alive_s)):
            if not (math.isfinite(value) and value > 0):
                raise ArgumentError(f"{name} {value!r} must be > 0", reason=name)
        if cover_polls < 2:
            raise ArgumentError(f"cover_polls {cover_polls!r} must be >= 2",
                                  reason="cover_polls")
        self.axes = dict(axes)
        self.clock = clock
        self.poll_period_s = poll_period_s
        self.tick_s = tick_s
        self.motion_scalar = motion_scalar
        self.period_s = tick_s * motion_scalar
        self.cover_polls = cover_polls
        self.keep_alive_s = keep_alive_s
        self.velocity_commands = 0
        self.zeroes: dict[str, MachineZero] = {}
        """Axis -> how its machine zero was set (once it was)."""
        self._drives = {name: _Drive(heard_at_s=clock.now()) for name in self.axes}

    # --- set-up ------------------------------------------------------------------------------

    def enter_velocity_mode(self) -> None:
        """Every axis in velocity mode with its velocity gains, queue empty, servo enabled."""
        for name, axis in self.axes.items():
            kp, ki, kd = axis.velocity_gains
            client = axis.client
            client.set_gains(kp=kp, ki=ki, kd=kd)
            client.set_control_mode(ControlMode.VELOCITY)
            client.set_servo_enable(True)
            self._drives[name] = _Drive(heard_at_s=self.clock.now())

    # --- reading -----------------------------------------------------------------------------

    def _status(self, name: str) -> Status:
        drive = self._drives[name]
        if drive.status is None:
            axis = self.axes[name]
            status = axis.client.status()
            drive.status = status
            drive.status_at_s = drive.heard_at_s = self.clock.now()
            if status.queued <= len(drive.queue):
                del drive.queue[: len(drive.queue) - status.queued]
            else:
                drive.queue = [drive.last] * status.queued
            if status.fault:
                raise DeviceFaultError(
                    f"axis {name}: {status.fault_name} fault while homing",
                    device=axis.client.name)
        return drive.status

    def _sign(self, name: str) -> int:
        return -self.axes[name].direction

    def limit_switches(self, axis: str) -> LimitSwitchState | None:
        """The axis's switches (home side as "lower"), or None for an unknown axis.

        Raises:
            DeviceFaultError: the device reports a fault (its servo is off: homing cannot go
                on); names the axis and the fault.
        """
        if axis not in self.axes:
            return None
        status = self._status(axis)
        if self.axes[axis].direction < 0:
            return LimitSwitchState(status.lower_limit, status.upper_limit)
        return LimitSwitchState(status.upper_limit, status.lower_limit)

    def read_positions_mm(self) -> dict[str, float]:
        """Each axis whose status this poll read: its actual position, mm, in machine
        orientation (device counts scaled until the axis's zero is set)."""
        return {name: self.axes[name].scale.to_mm(drive.status.actual_counts)
                for name, drive in self._drives.items() if drive.status is not None}

    def position_mm(self, axis: str) -> float:
        """Where the axis is, mm, in the homing orientation."""
        return self._sign(axis) * self.axes[axis].scale.to_mm(self._status(axis).actual_counts)

    def switch_edge(self, axis: str) -> SwitchEdgeReading:
        """The latched last edge of the switch the axis homes onto (call 36)."""
        drive = self._drives[axis]
        if drive.edge is None:
            config = self.axes[axis]
            drive.edge = config.client.switch_edge(1 if config.direction < 0 else 2)
        edge = drive.edge
        return SwitchEdgeReading(edge.edges, edge.closed,
                                 self._sign(axis) * self.axes[axis].scale.to_mm(
                                     edge.position_counts))

    def at_rest(self, axis: str) -> bool:
        """True when the queue has played out, nothing is left to send and the axis moved at
        most :data:`REST_COUNTS` since the previous poll."""
        drive = self._drives[axis]
        status = self._status(axis)
        previous = drive.previous_actual
        return (not drive.pending and status.queued == 0 and previous is not None
                and abs(status.actual_counts - previous) <= REST_COUNTS)

    # --- driving -----------------------------------------------------------------------------

    def _tick_ahead(self, name: str) -> int:
        """A device tick a little ahead of the present one, from the last status read."""
        drive = self._drives[name]
        status = self._status(name)
        elapsed_s = max(0.0, self.clock.now() - drive.status_at_s)
        return status.clock + math.ceil((elapsed_s + LEAD_S) / self.tick_s)

    def _due_index(self, name: str, tick: int) -> int:
        """Which of the queued values the device takes on ``tick`` (the front one on the
        tick after the last status read)."""
        status = self._status(name)
        return max(0, (tick - status.clock) // self.motion_scalar)

    def _value_at(self, name: str, tick: int) -> int:
        """The value the device uses on ``tick``: velocity mode runs dry to 0, position
        mode holds the last value."""
        drive = self._drives[name]
        index = self._due_index(name, tick)
        if index < len(drive.queue):
            return drive.queue[index]
        return drive.last if drive.position_mode else 0

    def _replace(self, name: str, tick: int, values: list[int], *, stop: bool = False) -> None:
        """Call 38 from ``tick`` (``stop``: call 50, which a late arrival delays rather than
        cuts short), and the host's copy of the queue to match."""
        drive = self._drives[name]
        index = min(self._due_index(name, tick), len(drive.queue))
        client = self.axes[name].client
        if stop:
            stopped = client.stop_from(tick, values)
            kept_count, added = stopped.kept, [v + stopped.offset for v in values]
        else:
            replaced = client.replace_from(tick, values)
            kept_count, added = replaced.kept, values[replaced.skipped :]
        kept = drive.queue[max(0, index - kept_count) : index]
        drive.queue = kept + added
        if drive.queue:
            drive.last = drive.queue[-1]

    def set_target_velocity(self, axis: str, velocity_mm_s: float) -> None:
        """Ramp the axis to this velocity at its acceleration and hold it a few polls.

        An unchanged velocity is sent again only once half of what is held has played out.
        """
        config = self.axes[axis]
        drive = self._drives[axis]
        if drive.position_mode:
            if velocity_mm_s == 0:
                self._stop_position_move(axis)
            return
        target = config.scale.to_counts(self._sign(axis) * velocity_mm_s)
        tick = self._tick_ahead(axis)
        cover_ticks = self.cover_polls * self.poll_period_s / self.tick_s
        held_ticks = (len(drive.queue) - self._due_index(axis, tick)) * self.motion_scalar
        if target == drive.target and (target == 0 or held_ticks > cover_ticks / 2):
            return
        start = self._value_at(axis, tick)
        step = max(1.0, config.scale.counts_per_mm * config.accel_mm_s2 * self.period_s)
        count = math.ceil(abs(target - start) / step)
        values = [round(start + (target - start) * k / count) for k in range(1, count + 1)]
        if target != 0:
            hold = max(2, math.ceil(cover_ticks / self.motion_scalar))
            values += [target] * hold
        values = values[:QUEUE_CAPACITY] or [0]
        self._replace(axis, tick, values, stop=target == 0)
        self.velocity_commands += 1
        drive.target = target

    def zero_and_pull_off(self, axis: str, edge: SwitchEdgeReading, pull_off_mm: float) -> None:
        """Machine zero from the latched edge, once, then the planned move off the switch.

        The axis is at rest on the switch: position mode (its gains first; the loop starts
        afresh where the axis stands), one shift of the counter so that the latched edge
        reads the switch's machine position, and a trapezoidal move ``pull_off_mm`` away
        at the pull-off speed and the axis's acceleration.
        """
        config = self.axes[axis]
        drive = self._drives[axis]
        latched = drive.edge
        if latched is None or latched.edges != edge.edges:
            latched = config.client.switch_edge(1 if config.direction < 0 else 2)
        client = config.client
        kp, ki, kd = config.gains
        client.set_gains(kp=kp, ki=ki, kd=kd)
        client.set_control_mode(ControlMode.POSITION)
        switch_counts = config.scale.to_counts(config.switch_mm)
        turn = config.turn_counts
        from_turn = 0
        if turn is not None:
            # the turn boundary nearest the edge: where the encoder reads angle 0
            zero = client.encoder().zero
            from_turn = (latched.position_counts - zero + turn // 2) % turn - turn // 2
        shift = wrap_int32(switch_counts - (latched.position_counts - from_turn))
        client.shift_position(shift)
        self.zeroes[axis] = MachineZero(latched.position_counts, latched.tick, shift,
                                        turn_counts=turn or 0,
                                        edge_from_turn_counts=from_turn)
        here = client.status().actual_counts
        # off the switch: the pull-off from the switch's position, and with an absolute
        # encoder (whose edge reads the switch's position plus its distance from the turn
        # boundary) at least the pull-off from the edge, whichever is further from the
        # switch: so the axis rests off the switch and never beyond the incremental axis's
        # rest towards it (the end of the travel, on a machine whose switch is there)
        target = config.scale.to_counts(config.switch_mm - config.direction * pull_off_mm)
        target = (min if config.direction > 0 else max)(target, target + from_turn)
        values: list[int] = []
        if target != here:
            profile = trapezoid_profile(float(target - here),
                                        config.pull_off_speed_mm_s * config.scale.counts_per_mm,
                                        config.accel_mm_s2 * config.scale.counts_per_mm)
            values = [here + round(p) for p in profile.sample(self.period_s)[1:].tolist()]
        drive.position_mode = True
        drive.target = target
        drive.queue, drive.last, drive.pending = [], here, values
        self._top_up(axis)

    def _top_up(self, name: str) -> None:
        """Send what the queue has room for of a planned move (a long one over polls)."""
        drive = self._drives[name]
        if not drive.pending:
            return
        client = self.axes[name].client
        _, free = client.queue_status()
        batch = drive.pending[:free]
        if batch:
            client.add_setpoints(batch)
            drive.queue += batch
            drive.last = batch[-1]
            del drive.pending[: len(batch)]

    def _stop_position_move(self, name: str) -> None:
        """Stop a planned move along its deceleration: from a tick just ahead, the rest of
        it is replaced by a ramp down at the axis's acceleration."""
        drive = self._drives[name]
        config = self.axes[name]
        drive.pending.clear()
        tick = self._tick_ahead(name)
        index = self._due_index(name, tick)
        if index + 1 >= len(drive.queue):
            return
        where = float(drive.queue[index - 1] if index else self._status(name).desired_counts)
        speed = drive.queue[index] - where
        step = config.scale.counts_per_mm * config.accel_mm_s2 * self.period_s * self.period_s
        values: list[int] = []
        while abs(speed) > step:
            speed -= math.copysign(step, speed)
            where += speed
            values.append(round(where))
        self._replace(name, tick, values or [round(where)], stop=True)

    def after_poll(self) -> None:
        """Between polls: top up planned moves, feed the watchdogs of axes nothing reached,
        and forget this poll's readings."""
        for name, drive in self._drives.items():
            if drive.status is not None:
                drive.previous_actual = drive.status.actual_counts
            self._top_up(name)
            now = self.clock.now()
            if drive.status is None and now - drive.heard_at_s >= self.keep_alive_s:
                self.axes[name].client.queue_status()
                drive.heard_at_s = now
            drive.status = None
            drive.edge = None


def wrap_int32(value: int) -> int:
    """``value`` wrapped as the device's int32 counter wraps."""
    span = INT32_MAX - INT32_MIN + 1
    return (value - INT32_MIN) % span + INT32_MIN
