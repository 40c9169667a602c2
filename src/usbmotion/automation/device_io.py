"""Homing inputs and outputs over real (or simulated) devices, in mm through each axis scale.

A target velocity is sent in velocity mode (control mode 2) as a short run of identical
velocity setpoints covering a few polling periods: if the host stops polling, the queue
runs dry and the device brings the axis to rest by itself.
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
        cover_polls: polling periods each velocity command lasts on the device.
        velocity_gains: (kp, ki, kd) of the velocity loop used while homing.
    """

    def __init__(
        self,
        clients: Mapping[str, DeviceClient],
        scales: Mapping[str, AxisScale],
        *,
        poll_period_s: float,
        motion_period_s: Mapping[str, float],
        cover_polls: int = 3,
        velocity_gains: tuple[float, float, float] = VELOCITY_GAINS,
    ) -> None:
        if not (math.isfinite(poll_period_s) and poll_period_s > 0):
            raise OutOfRangeError(f"poll_period_s {poll_period_s!r} must be > 0",
                                  reason="poll_period_s")
        if cover_polls < 1:
            raise OutOfRangeError(f"cover_polls {cover_polls!r} must be >= 1",
                                  reason="cover_polls")
        self.clients = dict(clients)
        self.scales = dict(scales)
        self.poll_period_s = poll_period_s
        self.motion_period_s = dict(motion_period_s)
        self.cover_polls = cover_polls
        self.velocity_gains = velocity_gains
        self.velocity_commands = 0

    def enter_velocity_mode(self) -> None:
        """Put every axis in velocity mode, with the velocity gains, servo enabled."""
        kp, ki, kd = self.velocity_gains
        for client in self.clients.values():
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
        status = client.status()
        if status.fault:
            raise DeviceFaultError(
                f"axis {axis}: {status.fault_name} fault while homing", device=client.name
            )
        return LimitSwitchState(at_lower_limit=status.lower_limit,
                                at_upper_limit=status.upper_limit)

    def keep_alive(self) -> None:
        """A cheap query to every device, so no watchdog trips on an axis that waits."""
        for client in self.clients.values():
            client.queue_status()

    def position_mm(self, axis: str) -> float:
        """Actual position of the axis, mm."""
        return self.scales[axis].to_mm(self.clients[axis].status().actual_counts)

    def set_target_velocity(self, axis: str, velocity_mm_s: float) -> None:
        """Replace the axis's queue with enough setpoints of this velocity to bridge polls."""
        client = self.clients[axis]
        counts_s = self.scales[axis].to_counts(velocity_mm_s)
        client.clear_queue()
        self.velocity_commands += 1
        if counts_s == 0:
            client.add_setpoints([0])
            return
        period = self.motion_period_s[axis]
        count = min(QUEUE_CAPACITY, max(2, math.ceil(self.cover_polls * self.poll_period_s
                                                     / period)))
        client.add_setpoints([counts_s] * count)

    def zero_position(self, axis: str) -> None:
        """Call 23: the present position becomes 0."""
        self.clients[axis].set_position(0)
