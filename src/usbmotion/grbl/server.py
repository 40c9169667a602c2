"""Serve one grbl session on a pseudo-terminal or a TCP port (:mod:`usbmotion.serving`).

One loop: wait for bytes up to the next poll (every 5 ms), hand them to the front as they
come, poll the front, and send what it wrote. A sender that connects gets the front reset
and the banner, as an Arduino resets when its port opens: on TCP each accepted connection
(a new one replaces the one before, which is closed: a sender that reconnects after its
link died gets through, as with grbl's network ports), on a pseudo-terminal each time a
program opens it after none had it open (one sender at a time: see
:mod:`usbmotion.serving`). Output while no sender is connected is dropped. The machine is
called from the serving thread only.
"""

from __future__ import annotations

import signal
import sys
import threading
import time
from collections.abc import Callable
from types import FrameType

from usbmotion.errors import ArgumentError
from usbmotion.grbl.interface import GrblMachine
from usbmotion.grbl.protocol import GrblProtocol
from usbmotion.serving import (
    EventKind,
    PtyEndpoint,
    SecondClient,
    Serving,
    TcpEndpoint,
)

POLL_S = 0.005
"""How often the front is polled (moves lines on to the machine)."""
PTY_SETTLE_S = 0.1
"""How long after a program opens the terminal the front resets and greets it: a serial
client sets its port up and drops what came meanwhile (pyserial's ``open`` flushes the
input last), so a banner written at once may be lost; an Arduino's reset on opening
takes longer still. Bytes the sender writes meanwhile are kept and handed over after."""


class GrblServer:
    """Serve ``machine`` with a :class:`GrblProtocol` on a pseudo-terminal or a TCP port.

    Use as a context manager, or call :meth:`close`. :meth:`serve` blocks; :meth:`start`
    runs it in a thread.

    Parameters:
        machine: the machine session.
        pty: serve on a pseudo-terminal (else TCP).
        link: with ``pty``, also make a symbolic link at this path to the terminal (a live
            link, to a terminal another server serves, is refused; a stale one replaced).
        tcp_port: the TCP port (0 picks a free one); only without ``pty``.
        host: the TCP address to bind, loopback by default.
        poll_s: the poll cadence, seconds.
        on_notice: where a notice goes (a second program on the terminal, ...);
            dropped by default.

    Raises:
        ArgumentError: a port out of 0..65535, a link without pty, a live link, a poll
            period out of 0.001..0.05 s.
        OSError: the port cannot be bound, or the link cannot be made.
    """

    def __init__(self, machine: GrblMachine, *, pty: bool = True, link: str | None = None,
                 tcp_port: int = 0, host: str = "127.0.0.1", poll_s: float = POLL_S,
                 on_notice: Callable[[str], None] | None = None) -> None:
        if not pty and not 0 <= tcp_port <= 65535:
            raise ArgumentError(f"tcp_port {tcp_port!r} is not a TCP port number 0..65535")
        if link is not None and not pty:
            raise ArgumentError(f"link {link!r} needs a pseudo-terminal (pty=True)")
        if not 0.001 <= poll_s <= 0.05:
            raise ArgumentError(f"poll_s {poll_s!r} s is out of range 0.001..0.05 s")
        self.protocol = GrblProtocol(machine, self._output)
        self._poll_s = poll_s
        self._notice = on_notice or (lambda text: None)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._closed = False
        self.error: BaseException | None = None
        """What ended a background serving loop, if an exception did."""
        self._reset_at: float | None = None
        self._early = bytearray()
        self._serving = Serving()
        try:
            if pty:
                self.endpoint: PtyEndpoint | TcpEndpoint = PtyEndpoint(link=link)
            else:
                self.endpoint = TcpEndpoint(host, tcp_port,
                                            second_client=SecondClient.REPLACE)
            self._serving.add(self.endpoint)
        except BaseException:
            self.close()
            raise

    @property
    def path(self) -> str:
        """The pseudo-terminal's path (empty on TCP)."""
        return self.endpoint.path if isinstance(self.endpoint, PtyEndpoint) else ""

    @property
    def port(self) -> int:
        """The TCP port (0 on a pseudo-terminal)."""
        return self.endpoint.port if isinstance(self.endpoint, TcpEndpoint) else 0

    @property
    def connections(self) -> int:
        """How many times a sender connected."""
        return self.endpoint.connections

    # ---- the loop

    def start(self) -> GrblServer:
        """Serve in a background thread."""
        if self._thread is None:
            self._thread = threading.Thread(target=self._serve_recorded, name="usbmotion-grbl",
                                            daemon=True)
            self._thread.start()
        return self

    def stop(self) -> None:
        """Ask the loop to end (from any thread or a signal handler)."""
        self._stop.set()

    def _serve_recorded(self) -> None:
        try:
            self.serve()
        except BaseException as error:
            self.error = error
            raise

    def serve(self) -> None:
        """Serve until :meth:`stop` (blocking)."""
        next_poll = time.monotonic()
        while not self._stop.is_set():
            wake = next_poll if self._reset_at is None else min(next_poll, self._reset_at)
            for event in self._serving.wait(max(0.0, wake - time.monotonic())):
                if event.kind is EventKind.CONNECTED:
                    self._connected()
                elif event.kind is EventKind.DISCONNECTED:
                    self._reset_at = None
                    self._early.clear()
                elif event.kind is EventKind.DATA:
                    if self._reset_at is not None:
                        self._early += event.data
                    else:
                        self._hand_over(event.data)
                elif event.kind in (EventKind.SECOND_CLIENT, EventKind.REFUSED):
                    self._notice(_said(event.kind, event.detail))
            now = time.monotonic()
            if self._reset_at is not None and now >= self._reset_at:
                self._reset_at = None
                self.protocol.connect()
                early, self._early = bytes(self._early), bytearray()
                self._hand_over(early)
            if now >= next_poll:
                self.protocol.poll()
                next_poll = max(next_poll + self._poll_s, now)
            self._serving.flush()

    def _connected(self) -> None:
        """A sender came: reset the front and greet it (on a terminal once it has settled,
        :data:`PTY_SETTLE_S`)."""
        if isinstance(self.endpoint, PtyEndpoint):
            self._reset_at = time.monotonic() + PTY_SETTLE_S
            self._early.clear()
        else:
            self.protocol.connect()

    def _hand_over(self, data: bytes) -> None:
        """Give ``data`` to the front as a serial line would: no more at once than its
        buffer has room for, polling between, so the pre-parser drains the buffer as grbl's
        main loop does while bytes arrive (a long line of spaces and comments fits)."""
        while data:
            room = max(1, self.protocol.rx_bytes_free)
            self.protocol.receive(data[:room])
            data = data[room:]
            if data:
                self.protocol.poll()

    def _output(self, data: bytes) -> None:
        self.endpoint.send(data)

    # ---- clean-up

    def close(self) -> None:
        """Stop serving and release the terminal (and its link) or the socket (safe
        twice)."""
        if self._closed:
            return
        self._closed = True
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join()
        self._serving.close()

    def __enter__(self) -> GrblServer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _said(kind: EventKind, detail: str) -> str:
    if kind is EventKind.SECOND_CLIENT:
        return (f"a second program opened {detail} while a sender has it, without locking"
                " it: its bytes and the sender's mix")
    return f"refused a second client from {detail}"


def serve(machine: GrblMachine, *, pty: bool, link: str | None, tcp_port: int | None,
          host: str = "127.0.0.1", announce: Callable[[str], None] | None = None,
          on_notice: Callable[[str], None] | None = None) -> int:
    """Serve ``machine`` in the foreground until SIGTERM or SIGINT; the exit status.

    Parameters:
        machine: the machine session.
        pty: serve on a pseudo-terminal (its path is announced), else on ``tcp_port``.
        link: with ``pty``, a symbolic link to make to the terminal.
        tcp_port: the TCP port without ``pty`` (0 or None picks a free one).
        host: the TCP address to bind.
        announce: where the serving line goes (standard output by default).
        on_notice: where notices go (as :class:`GrblServer`'s).
    """
    say = announce if announce is not None else _print
    with GrblServer(machine, pty=pty, link=link, tcp_port=tcp_port or 0, host=host,
                    on_notice=on_notice) as server:
        if pty:
            where = server.path + (f" (link {link})" if link else "")
        else:
            where = f"{host}:{server.port}"
        say(f"grbl 1.1h serving on {where}")

        def _stop(signum: int, frame: FrameType | None) -> None:
            server.stop()

        previous = {number: signal.signal(number, _stop)
                    for number in (signal.SIGTERM, signal.SIGINT)}
        try:
            server.serve()
        finally:
            for number, handler in previous.items():
                signal.signal(number, handler)
    return 0


def _print(text: str) -> None:
    print(text, file=sys.stdout, flush=True)
