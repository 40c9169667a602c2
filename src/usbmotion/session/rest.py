"""Bringing axes to rest: how far ahead a stop replaces the queued future, and the wait
until every axis has played out its queue and settled (after a take-over's stop, a run's
stop or a stopped homing)."""

from __future__ import annotations

from collections.abc import Callable, Sequence

from usbmotion.clock import Clock
from usbmotion.errors import DeviceError
from usbmotion.host.device import Status
from usbmotion.host.machine import Machine
from usbmotion.session.report import SETTLE_COUNTS

STOP_LEAD_S = 0.005
"""How far ahead of the devices' present tick a stop replaces the queued future: covers
the time the lines take to reach every device (one that arrives late skips what is past)."""
REST_TIMEOUT_S = 5.0
"""The longest a stop waits for every axis's queue to play out its deceleration."""
REST_POLL_S = 0.005
"""How often a stopped homing looks whether every axis is at rest."""
SETTLE_TIMEOUT_S = 1.0
"""How long a stopped axis then has to settle within SETTLE_COUNTS of where it was sent."""
SETTLE_STILL_S = 0.2
"""How long an axis within SETTLE_COUNTS of where it was sent, but not on it, has to stand
still before a run that ends there counts it settled (its servo holds it against friction)."""


def wait_until_settled(read: Callable[[], Sequence[Status]], clock: Clock) -> None:
    """After the last setpoint: until every axis ``read`` gives is where it was sent, or
    within :data:`SETTLE_COUNTS` of it and still for :data:`SETTLE_STILL_S` (a servo
    holding a count or two against friction), for at most :data:`SETTLE_TIMEOUT_S`."""
    start = clock.now()
    deadline = start + SETTLE_TIMEOUT_S
    last: list[int] = []
    still_since = start
    while True:
        statuses = read()
        now = clock.now()
        counts = [status.actual_counts for status in statuses]
        if counts != last:
            last = counts
            still_since = now
        worst = max((abs(s.desired_counts - s.actual_counts) for s in statuses), default=0)
        if worst == 0 or (worst <= SETTLE_COUNTS and now - still_since >= SETTLE_STILL_S):
            return
        if now >= deadline:
            return
        clock.sleep(REST_POLL_S)


def wait_for_rest(machine: Machine, names: list[str], *, stop_now: Callable[[], bool],
                  poll_s: float = 0.01) -> None:
    """Wait until every named axis that is enabled has played out its queue and settled
    (within :data:`SETTLE_COUNTS` of its commanded position, not moving); an axis that
    keeps a larger error is accepted after :data:`SETTLE_TIMEOUT_S`: its servo holds it.
    When ``stop_now`` says so (a second stop request), every axis is stopped at once.

    Raises:
        DeviceError: a queue did not play out within :data:`REST_TIMEOUT_S`.
    """
    clock = machine.clock
    deadline = clock.now() + REST_TIMEOUT_S
    settle_by: float | None = None
    last: dict[str, int] = {}
    while True:
        if stop_now():
            machine.stop()
            return
        playing = settling = False
        for name in names:
            status = machine.axis(name).client.status()
            if not status.enabled:
                continue
            moved = abs(status.actual_counts - last.get(name, 2**40)) > 1
            last[name] = status.actual_counts
            if status.queued:
                playing = True
            elif moved or abs(status.desired_counts - status.actual_counts) > SETTLE_COUNTS:
                settling = True
        now = clock.now()
        if not playing:
            settle_by = now + SETTLE_TIMEOUT_S if settle_by is None else settle_by
            if not settling or now > settle_by:
                return
        elif now > deadline:
            raise DeviceError(f"axes {', '.join(names)} did not come to rest",
                              device=", ".join(names))
        clock.sleep(poll_s)
