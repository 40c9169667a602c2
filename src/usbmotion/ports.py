"""What a port can say about itself beyond pyserial's interface.

A plain serial port says nothing: the host waits on the wall clock and, after discarding
input, drops bytes up to the next newline (the tail of a line in flight). A port that knows
better declares it with these attributes; the host checks for the protocol, never for the
kind of port (``isinstance(port, ClockedPort)``), so any port can offer them.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

from usbmotion.clock import Clock


@runtime_checkable
class ClockedPort(Protocol):
    """A port that carries its own clock: waiting on it is waiting on that clock (a
    simulated device's port waits in the simulation's virtual time)."""

    usbmotion_clock: Clock | None
    """The clock; ``None`` until the port is open."""


@runtime_checkable
class ExactResetPort(Protocol):
    """A port whose input reset is exact: after ``reset_input_buffer`` the next byte read
    starts a line (the far end prints whole lines and none is left in flight)."""

    usbmotion_exact_reset: bool


@runtime_checkable
class ArrivedPort(Protocol):
    """A port that hands over what has arrived in one call, waiting for it on its own
    clock (a simulated device's port: pyserial's ``in_waiting``, ``timeout`` and ``read``
    are three steps, each through the port's settings)."""

    def usbmotion_read_arrived(self, timeout_s: float) -> bytes:
        """Every byte that has arrived, waiting up to ``timeout_s`` (0: not at all) for the
        first; empty when none came."""
        ...
