"""``sim://NAME[?world=W&latency_us=N]``: a pyserial port onto an in-process simulated device.

The device ``NAME`` (URL-quoted: ``sim://X%20AXIS``) of the world ``W`` (default
``default``) is opened; a device that is not there yet is created with the defaults and
that name. Reading with a timeout advances the world's virtual clock instead of
sleeping, so host code written for real ports runs in virtual time unchanged. The
port is a :class:`~usbmotion.ports.ClockedPort` whose clock is the world's one
:class:`VirtualClock`, an :class:`~usbmotion.ports.ExactResetPort`: resetting its
input buffer drops every byte the device has printed, in flight or not, and the device
prints whole lines, so the next byte the host reads starts a line; and an
:class:`~usbmotion.ports.ArrivedPort`, read in one call.
"""

from __future__ import annotations

import math
from typing import Any

from serial.serialutil import PortNotOpenError, SerialBase, SerialException

from usbmotion.errors import LinkLostError
from usbmotion.protocol import encode_device_name
from usbmotion.sim.registry import get_world
from usbmotion.sim.urls import parse_sim_url
from usbmotion.sim.world import SimLink, SimWorld, VirtualClock

_FOREVER_US = 10_000_000
"""How long a read without timeout waits in virtual time before giving up."""


def _ensure_device(world: SimWorld, name: str) -> None:
    if name in world.keys:
        return
    from usbmotion.device import Device  # noqa: PLC0415 - the device is only needed here

    device = Device()
    device.feed(encode_device_name(name))
    device.take_output()
    world.add(device, key=name)


class Serial(SerialBase):  # type: ignore[misc]
    """A pyserial port whose far end is a simulated device."""

    usbmotion_exact_reset = True
    """After :meth:`reset_input_buffer` the next byte read starts a line."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        self.link: SimLink | None = None
        self.usbmotion_clock: VirtualClock | None = None
        super().__init__(*args, **kwargs)

    def open(self) -> None:
        """Connect to the device named by the URL."""
        if self.link is not None and not self.link.closed:
            raise SerialException("port is already open")
        if self._port is None:
            raise SerialException("port must be configured before it can be used")
        name, world_name, latency_us = parse_sim_url(self._port)
        world = get_world(world_name)
        _ensure_device(world, name)
        self.link = world.connect(name, latency_us=latency_us)
        self.usbmotion_clock = world.clock
        self.is_open = True

    def close(self) -> None:
        """Disconnect (safe twice)."""
        if self.link is not None:
            self.link.close()
        self.is_open = False

    def _reconfigure_port(self, *args: Any, **kwargs: Any) -> None:
        """Line settings mean nothing on a simulated link."""

    def _link(self) -> SimLink:
        if not self.is_open or self.link is None:
            raise PortNotOpenError()
        if self.link.faults.disconnected:
            raise LinkLostError(f"simulated link to {self.link.key!r} was disconnected",
                                device=self.link.key)
        return self.link

    @property
    def in_waiting(self) -> int:
        """Bytes ready to read now."""
        return self._link().available()

    def read(self, size: int = 1) -> bytes:
        """Read up to ``size`` bytes, advancing virtual time up to the timeout."""
        link = self._link()
        if self._timeout != 0 and not link.available():
            timeout_us = (_FOREVER_US if self._timeout is None
                          else max(1, math.ceil(self._timeout * 1e6)))
            link.world.wait_for(link, timeout_us)
        return link.receive(size)

    def usbmotion_read_arrived(self, timeout_s: float) -> bytes:
        """Every byte that has arrived, advancing virtual time up to ``timeout_s`` for the
        first (:class:`~usbmotion.ports.ArrivedPort`)."""
        link = self._link()
        if timeout_s > 0 and not link.available():
            link.world.wait_for(link, max(1, math.ceil(timeout_s * 1e6)))
        return link.receive_all()

    def write(self, data: bytes | bytearray | memoryview) -> int:
        """Send bytes to the device."""
        payload = bytes(data)
        self._link().write(payload)
        return len(payload)

    def flush(self) -> None:
        """Nothing is buffered on the host side."""

    def reset_input_buffer(self) -> None:
        """Drop unread input."""
        self._link().discard_input()

    def reset_output_buffer(self) -> None:
        """Output is never buffered; nothing to drop."""

    @property
    def out_waiting(self) -> int:
        """Output is never buffered."""
        return 0

    def _update_break_state(self) -> None:
        return None

    def _update_rts_state(self) -> None:
        return None

    def _update_dtr_state(self) -> None:
        return None

    @property
    def cts(self) -> bool:
        """Always clear to send."""
        return True

    @property
    def dsr(self) -> bool:
        """Always ready."""
        return True

    @property
    def ri(self) -> bool:
        """Never ringing."""
        return False

    @property
    def cd(self) -> bool:
        """Always carrier."""
        return True
