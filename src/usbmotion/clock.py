"""Clocks the host waits on: the wall clock, or a simulation's virtual clock.

Host code never calls ``time.sleep`` directly: it asks its link's clock, so the same
code waits in real time on hardware and advances the simulation in virtual time.
"""

from __future__ import annotations

import time
from typing import Protocol, runtime_checkable


@runtime_checkable
class Clock(Protocol):
    """Something host code can read the time from and wait on."""

    def now(self) -> float:
        """Seconds on this clock (monotonic; the origin is arbitrary)."""
        ...

    def sleep(self, seconds: float) -> None:
        """Wait ``seconds`` on this clock."""
        ...


class WallClock:
    """The computer's monotonic clock."""

    def now(self) -> float:
        """Seconds from ``time.monotonic``."""
        return time.monotonic()

    def sleep(self, seconds: float) -> None:
        """Sleep for real."""
        if seconds > 0:
            time.sleep(seconds)


WALL_CLOCK = WallClock()


def is_paced(clock: Clock) -> bool:
    """Whether sleeping on ``clock`` takes that long on the wall clock (the wall clock, a
    real-time simulation), rather than returning as soon as the simulation has run (a
    virtual-time world, whose clock says so with ``paced = False``). Code that checks
    something every so many milliseconds while it waits checks it between slices of a
    paced clock's sleep; a virtual clock's whole sleep passes in less than a slice."""
    return bool(getattr(clock, "paced", True))


def sleep_quiet(clock: Clock, seconds: float, *, quiet_until: float) -> None:
    """Sleep ``seconds`` on ``clock``, promising to send nothing to a device before
    ``quiet_until`` (on ``clock``): a virtual-time simulation then runs its devices ahead
    to that time in one block instead of one per wake (its clock has ``sleep_quiet``);
    any other clock just sleeps. A promise broken costs the simulation time, never a
    difference in what its devices do."""
    quiet = getattr(clock, "sleep_quiet", None)
    if quiet is None:
        clock.sleep(seconds)
    else:
        quiet(seconds, quiet_until=quiet_until)
