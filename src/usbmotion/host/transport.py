"""One buffered line transport over any pyserial port: real, ``socket://``, ``loop://``, ``sim://``.

pyserial's own ``readline`` reads a byte at a time; this transport reads whatever has
arrived in one call and cuts it into lines itself, so a fast device is never throttled by
the host. Waiting is done on the port's clock: the wall clock for real ports, the virtual
clock of the simulation for ``sim://`` ports (where waiting advances the simulation).

After :meth:`LineTransport.discard_input` the next bytes may be the tail of a line the
device was printing, so they are dropped up to the next newline; a host taking over a
link therefore resynchronises with a query of its own
(:meth:`usbmotion.host.device.DeviceClient.resynchronise`).
"""

from __future__ import annotations

import contextlib
import errno
from collections import deque
from typing import Any

import serial

from usbmotion.clock import WALL_CLOCK, Clock
from usbmotion.errors import DeviceTimeoutError, LinkLostError
from usbmotion.ports import ArrivedPort, ClockedPort, ExactResetPort
from usbmotion.protocol import LineSplitter, Overlong

_MAX_REPLY_LINE = 1 << 16


def open_problem(error: BaseException) -> str:
    """Why a port could not be opened, in a few words: pyserial's message names the port
    again and nests the system's error (``[Errno 2] could not open port /dev/x: [Errno 2]
    No such file or directory: '/dev/x'``); the system's reason is enough."""
    code = getattr(error, "errno", None)
    text = str(error)
    if code in (errno.EAGAIN, errno.EBUSY) or "exclusively lock" in text:
        return "busy: another program has it open"
    if code == errno.ECONNREFUSED or "Connection refused" in text:
        return "connection refused: nothing serves that address"
    if code == errno.ENOENT or "No such file or directory" in text:
        return "no such port"
    if code == errno.EACCES or "Permission denied" in text:
        return "permission denied"
    return text


_EMPTY_READ = "device reports readiness to read but returned no data"
"""pyserial's words for a read that select called ready and that returned nothing."""
EMPTY_READS_LOST = 20
"""Such reads in a row after which the link counts as lost (a gone device gives one on
every read; a flushed terminal, one now and then)."""

class LineTransport:
    """Lines in and out of one serial port.

    Parameters:
        port: an open pyserial port (from :func:`serial.serial_for_url`).
        label: how errors name this link (a device name or the URL).
    """

    def __init__(self, port: Any, *, label: str = "") -> None:
        self.port = port
        self.label = label or str(getattr(port, "port", "") or "serial port")
        clock = port.usbmotion_clock if isinstance(port, ClockedPort) else None
        self.clock: Clock = clock if clock is not None else WALL_CLOCK
        self._splitter = LineSplitter(max_bytes=_MAX_REPLY_LINE)
        self._lines: deque[bytes] = deque()
        self._drop_to_newline = False
        self._empty_reads = 0
        """Reads in a row that pyserial called ready but empty (see :data:`EMPTY_READS_LOST`)."""
        self.bytes_written = 0
        self.bytes_read = 0
        self._closed = False
        self._read_arrived = (port.usbmotion_read_arrived if isinstance(port, ArrivedPort)
                              else None)

    @classmethod
    def open(cls, url: str, *, baudrate: int = 115200, label: str = "") -> LineTransport:
        """Open ``url`` (a port path or any pyserial URL; ``sim://`` once ``usbmotion.sim`` is
        imported, which registers its handler with pyserial).

        Raises:
            LinkLostError: the port cannot be opened (the message names it and why).
        """
        # A port path is locked for this host alone: a second host on one device would
        # garble both hosts' exchanges.
        exclusive = {} if "://" in url else {"exclusive": True}
        try:
            port = serial.serial_for_url(url, baudrate=baudrate, timeout=0, write_timeout=5,
                                         **exclusive)
        except (serial.SerialException, OSError, ValueError) as error:
            raise LinkLostError(f"cannot open {url!r}: {open_problem(error)}",
                                device=label or url) from error
        return cls(port, label=label or url)

    @property
    def is_virtual(self) -> bool:
        """True when waiting on this link advances a simulation rather than the wall clock."""
        return self.clock is not WALL_CLOCK

    def write(self, data: bytes) -> None:
        """Send bytes.

        Raises:
            LinkLostError: the port is gone.
        """
        try:
            self.port.write(data)
        except (serial.SerialException, OSError) as error:
            raise LinkLostError(
                f"{self.label}: write failed: {error}", device=self.label
            ) from error
        self.bytes_written += len(data)

    def _pull(self, timeout_s: float) -> bool:
        """Read what has arrived, waiting up to ``timeout_s`` for the first byte."""
        try:
            if self._read_arrived is not None:
                chunk = self._read_arrived(timeout_s if timeout_s > 0 else 0.0)
            elif waiting := self.port.in_waiting:
                chunk = self.port.read(waiting)
            elif timeout_s <= 0:
                return False
            else:
                self.port.timeout = timeout_s
                try:
                    chunk = self.port.read(1)
                finally:
                    self.port.timeout = 0
                if chunk:
                    more = self.port.in_waiting
                    if more:
                        chunk += self.port.read(more)
        except (serial.SerialException, OSError) as error:
            if (isinstance(error, serial.SerialException) and str(error).startswith(_EMPTY_READ)
                    and self._empty_reads < EMPTY_READS_LOST):
                # A terminal whose input was flushed between select and read (a pty's
                # server tidying up after another program closed it) reads nothing once;
                # a device that is gone reads nothing every time.
                self._empty_reads += 1
                return False
            raise LinkLostError(f"{self.label}: read failed: {error}", device=self.label) from error
        self._empty_reads = 0
        if not chunk:
            return False
        self.bytes_read += len(chunk)
        if self._drop_to_newline:
            end = chunk.find(b"\n")
            if end < 0:
                return True
            self._drop_to_newline = False
            chunk = chunk[end + 1:]
        for line in self._splitter.feed(chunk):
            if isinstance(line, Overlong):
                self._lines.append(b"<overlong line dropped>")
            else:
                self._lines.append(line)
        return True

    def poll_lines(self) -> list[bytes]:
        """Every whole line that has arrived, without waiting."""
        self._pull(0)
        if not self._lines:
            return []
        out = list(self._lines)
        self._lines.clear()
        return out

    def read_line(self, timeout_s: float) -> bytes:
        """The next line, waiting up to ``timeout_s`` on the link's clock.

        Raises:
            DeviceTimeoutError: no whole line arrived in time.
            LinkLostError: the port is gone.
        """
        if self._lines:
            return self._lines.popleft()
        deadline = self.clock.now() + timeout_s
        while True:
            left = deadline - self.clock.now()
            if left < 1e-6:
                left = 0.0
            self._pull(left)
            if self._lines:
                return self._lines.popleft()
            if left <= 0:
                raise DeviceTimeoutError(
                    f"{self.label}: no reply within {timeout_s:g} s", device=self.label
                )

    def discard_input(self) -> None:
        """Forget every line and byte received so far, and the rest of the line in progress.

        Resetting the port's input buffer drops what has reached the host, not what is
        still on its way (in the device's USB buffer, a pseudo-terminal, a socket): the
        next bytes may be the tail of a line, even when no partial line was held here.
        So the bytes that arrive next are dropped up to and including the first newline,
        unless the port's reset is known to leave the link at the start of a line (a
        port whose ``usbmotion_exact_reset`` is true: the ``sim://`` ports, whose reset
        drops every byte the device has printed, in flight or not).

        A whole line may be dropped that way, the answer to a query sent after this call
        among them: to take over a link, use
        :meth:`usbmotion.host.device.DeviceClient.resynchronise`, which discards and then
        reads up to the answer to a query of its own.

        Raises:
            LinkLostError: the port is gone.
        """
        self._lines.clear()
        self._splitter.reset()
        try:
            self.port.reset_input_buffer()
        except (serial.SerialException, OSError) as error:
            raise LinkLostError(f"{self.label}: {error}", device=self.label) from error
        exact = isinstance(self.port, ExactResetPort) and self.port.usbmotion_exact_reset is True
        self._drop_to_newline = not exact

    def sleep(self, seconds: float) -> None:
        """Wait on the link's clock."""
        self.clock.sleep(seconds)

    def close(self) -> None:
        """Close the port (safe twice)."""
        if not self._closed:
            self._closed = True
            with contextlib.suppress(serial.SerialException, OSError):
                self.port.close()

    def __enter__(self) -> LineTransport:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
