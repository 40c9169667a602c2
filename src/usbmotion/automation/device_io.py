"""Homing inputs and outputs over real (or simulated) devices, in mm through each axis scale.

A target velocity is sent in velocity mode (control mode 2) as a short run of identical
velocity setpoints covering a few polling periods, replacing the queue in one exchange: if
the host stops polling, the queue runs dry and the device brings the axis to rest by
itself. An unchanged velocity is sent again only every other poll (the run covers twice
that), and an axis that was not spoken to in a poll gets a cheap query only as often as
``keep_alive_polls`` says, so homing costs few exchanges per poll.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

from usbmotion.automation.homing import LimitSwitchState
from usbmotion.errors import DeviceFaultError, OutOfRangeError
from usbmotion.host.device import AxisScale, ControlMode, DeviceClient
from usbmotion.protocol import QUEUE_CAPACITY

VELOCITY_GAINS = (7e-3, 1.0, 0.0)
"""PID gains of the velocity loop while homing (V per count/s, V per count, V s^2/count):
well damped on the default simulated gearmotor. The position gains drive a velocity error
of thousands of counts/s into the supply rail, so velocity mode needs its own."""


class DeviceHomingIO:
    """:class:`HomingInputs` and :class:`HomingOutputs` over device clients.

    Parameters:
        clients: axis name -> device client.
        scales: axis name -> counts per mm.
        poll_period_s: how often the homing sequence is polled; each velocity command
            covers ``cover_polls`` of these.
        motion_period_s: axis name -> seconds per queue value on that device.
        cover_polls: polling periods each velocity command lasts on the device; an
            unchanged velocity is sent again after half of them.
        velocity_gains: (kp, ki, kd) of the velocity loop used while homing: one for every
            axis, or a mapping of axis name -> gains (axes it leaves out get
            :data:`VELOCITY_GAINS`).
        keep_alive_polls: an axis no call reached gets a query every this many calls of
            :meth:`keep_alive` (keep it well below the watchdog).
    """

    def __init__(
        self,
        clients: Mapping[str, DeviceClient],
        scales: Mapping[str, AxisScale],
        *,
        poll_period_s: float,
        motion_period_s: Mapping[str, float],
        cover_polls: int = 4,
        velocity_gains: (
            tuple[float, float, float] | Mapping[str, tuple[float, float, float]]
        ) = VELOCITY_GAINS,
        keep_alive_polls: int = 1,
    ) -> None:
        if not (math.isfinite(poll_period_s) and poll_period_s > 0):
            raise OutOfRangeError(f"poll_period_s {poll_period_s!r} must be > 0",
                                  reason="poll_period_s")
        if cover_polls < 2:
            raise OutOfRangeError(f"cover_polls {cover_polls!r} must be >= 2",
                                  reason="cover_polls")
        if keep_alive_polls < 1:
            raise OutOfRangeError(f"keep_alive_polls {keep_alive_polls!r} must be >= 1",
                                  reason="keep_alive_polls")
        self.clients = dict(clients)
        self.scales = dict(scales)
        self.poll_period_s = poll_period_s
        self.motion_period_s = dict(motion_period_s)
        self.cover_polls = cover_polls
        self.velocity_gains: dict[str, tuple[float, float, float]] = (
            {name: velocity_gains.get(name, VELOCITY_GAINS) for name in self.clients}
            if isinstance(velocity_gains, Mapping)
            else dict.fromkeys(self.clients, velocity_gains)
        )
        """Axis -> (kp, ki, kd) of its velocity loop while homing."""
        self.keep_alive_polls = keep_alive_polls
        self.velocity_commands = 0
        self._sent: dict[str, tuple[int, int]] = {}
        """Axis -> (velocity counts/s last sent, calls since it was sent)."""
        self._quiet: dict[str, int] = dict.fromkeys(self.clients, 0)
        """Axis -> polls (keep-alive calls) since anything was sent to it."""

    def enter_velocity_mode(self) -> None:
        """Put every axis in velocity mode, with the velocity gains, servo enabled."""
        for axis, client in self.clients.items():
            kp, ki, kd = self.velocity_gains[axis]
            client.set_control_mode(ControlMode.VELOCITY)
            client.set_gains(kp=kp, ki=ki, kd=kd)
            client.set_servo_enable(True)

    def limit_switches(self, axis: str) -> LimitSwitchState | None:
        """The axis's switches from its status (call 20), or None for an unknown axis.

        Raises:
            DeviceFaultError: the device reports a fault (its servo is disabled, so
                homing cannot go on): names the axis and the fault.
        """
        client = self.clients.get(axis)
        if client is None:
            return None
        self._quiet[axis] = 0
        status = client.status()
        if status.fault:
            raise DeviceFaultError(
                f"axis {axis}: {status.fault_name} fault while homing", device=client.name
            )
        return LimitSwitchState(at_lower_limit=status.lower_limit,
                                at_upper_limit=status.upper_limit)

    def keep_alive(self) -> None:
        """Call once per poll: a cheap query to a device no call reached for a while.

        So no watchdog trips on an axis that waits for its turn to home.
        """
        for axis, client in self.clients.items():
            if self._quiet[axis] >= self.keep_alive_polls:
                client.queue_status()
                self._quiet[axis] = 0
            self._quiet[axis] += 1

    def position_mm(self, axis: str) -> float:
        """Actual position of the axis, mm."""
        self._quiet[axis] = 0
        return self.scales[axis].to_mm(self.clients[axis].status().actual_counts)

    def set_target_velocity(self, axis: str, velocity_mm_s: float) -> None:
        """Replace the axis's queue with enough setpoints of this velocity to bridge polls.

        An unchanged velocity is not sent again until half of the last run is used up;
        zero, once sent, needs no refill (an empty queue in velocity mode means rest).
        """
        counts_s = self.scales[axis].to_counts(velocity_mm_s)
        last = self._sent.get(axis)
        if last is not None and last[0] == counts_s:
            calls = last[1] + 1
            if counts_s == 0 or calls < self.cover_polls // 2:
                self._sent[axis] = (counts_s, calls)
                return
        self._sent[axis] = (counts_s, 0)
        self._quiet[axis] = 0
        self.velocity_commands += 1
        if counts_s == 0:
            self.clients[axis].replace_setpoints([0])
            return
        period = self.motion_period_s[axis]
        count = min(QUEUE_CAPACITY, max(2, math.ceil(self.cover_polls * self.poll_period_s
                                                     / period)))
        self.clients[axis].replace_setpoints([counts_s] * count)

    def zero_position(self, axis: str) -> None:
        """Call 23: the present position becomes 0."""
        self._quiet[axis] = 0
        self.clients[axis].set_position(0)
