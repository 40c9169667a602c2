"""Serve one grbl session on a pseudo-terminal or a TCP port.

One loop: wait for bytes up to the next poll (every 5 ms), hand them to the front as they
come, poll the front, and send what it wrote. A sender that connects gets the front reset
and the banner, as an Arduino resets when its port opens: on TCP each accepted connection
(a new one replaces the one before), on a pseudo-terminal each time a program opens its
slave side after none had it open (the server keeps only the master side, so it sees the
slave side closed and opened again). Output while no sender is connected is dropped.
The machine is called from the serving thread only.
"""

from __future__ import annotations

import contextlib
import os
import select
import selectors
import signal
import socket
import sys
import threading
import time
import tty
from collections.abc import Callable
from pathlib import Path
from types import FrameType

from usbmotion.errors import ArgumentError
from usbmotion.grbl.interface import GrblMachine
from usbmotion.grbl.protocol import GrblProtocol

POLL_S = 0.005
"""How often the front is polled (moves lines on to the machine)."""
_READ_CHUNK = 4096
_MAX_PENDING = 1 << 20
"""Output kept for a sender that does not read; past this it is dropped."""


class GrblServer:
    """Serve ``machine`` with a :class:`GrblProtocol` on a pseudo-terminal or a TCP port.

    Use as a context manager, or call :meth:`close`. :meth:`serve` blocks; :meth:`start`
    runs it in a thread.

    Parameters:
        machine: the machine session.
        pty: serve on a pseudo-terminal (else TCP).
        link: with ``pty``, also make a symbolic link at this path to the terminal.
        tcp_port: the TCP port (0 picks a free one); only without ``pty``.
        host: the TCP address to bind, loopback by default.
        poll_s: the poll cadence, seconds.

    Raises:
        ArgumentError: a port out of 0..65535, a link without pty, a poll period out of
            0.001..0.05 s.
        OSError: the port cannot be bound, or the link cannot be made.
    """

    def __init__(self, machine: GrblMachine, *, pty: bool = True, link: str | None = None,
                 tcp_port: int = 0, host: str = "127.0.0.1", poll_s: float = POLL_S) -> None:
        if not pty and not 0 <= tcp_port <= 65535:
            raise ArgumentError(f"tcp_port {tcp_port!r} is not a TCP port number 0..65535")
        if link is not None and not pty:
            raise ArgumentError(f"link {link!r} needs a pseudo-terminal (pty=True)")
        if not 0.001 <= poll_s <= 0.05:
            raise ArgumentError(f"poll_s {poll_s!r} s is out of range 0.001..0.05 s")
        self.protocol = GrblProtocol(machine, self._output)
        self._poll_s = poll_s
        self._selector = selectors.DefaultSelector()
        self._pending = bytearray()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._closed = False
        self._master = -1
        self._listener: socket.socket | None = None
        self._client: socket.socket | None = None
        self._connected = False
        self._link: Path | None = None
        self.path = ""
        """The pseudo-terminal's path (empty on TCP)."""
        self.port = 0
        """The TCP port (0 on a pseudo-terminal)."""
        self.connections = 0
        """How many times a sender connected."""
        self.error: BaseException | None = None
        """What ended a background serving loop, if an exception did."""
        try:
            if pty:
                self._open_pty(link)
            else:
                self._open_tcp(host, tcp_port)
        except BaseException:
            self.close()
            raise

    def _open_pty(self, link: str | None) -> None:
        master, slave = os.openpty()
        self._master = master
        try:
            tty.setraw(slave)
            self.path = os.ttyname(slave)
        finally:
            os.close(slave)
        os.set_blocking(master, False)
        if link is not None:
            path = Path(link)
            if path.is_symlink():
                path.unlink()
            path.symlink_to(self.path)
            self._link = path

    def _open_tcp(self, host: str, port: int) -> None:
        listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            listener.bind((host, port))
        except OSError as error:
            listener.close()
            raise OSError(error.errno, f"cannot listen on {host}:{port}:"
                          f" {error.strerror or error}") from error
        listener.listen(1)
        listener.setblocking(False)
        self._listener = listener
        self.port = listener.getsockname()[1]
        self._selector.register(listener, selectors.EVENT_READ)

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
            if self._master >= 0:
                self._watch_pty()
            timeout = max(0.0, next_poll - time.monotonic())
            for key, _ in self._selector.select(timeout=timeout):
                self._readable(key.fileobj)
            now = time.monotonic()
            if now >= next_poll:
                self.protocol.poll()
                next_poll = max(next_poll + self._poll_s, now)
            self._flush()

    def _watch_pty(self) -> None:
        poller = select.poll()
        poller.register(self._master, select.POLLIN)
        hung_up = any(events & select.POLLHUP for _, events in poller.poll(0))
        if hung_up and self._connected:
            self._connected = False
            self._selector.unregister(self._master)
            self._pending.clear()
        elif not hung_up and not self._connected:
            self._connected = True
            self._selector.register(self._master, selectors.EVENT_READ)
            self._new_connection()
        elif hung_up:
            self._stop.wait(self._poll_s)  # nobody there: do not spin

    def _new_connection(self) -> None:
        self.connections += 1
        self._pending.clear()
        self.protocol.connect()

    def _readable(self, source: object) -> None:
        if source is self._listener:
            self._accept()
            return
        data = b""
        if source == self._master:
            with contextlib.suppress(BlockingIOError, OSError):
                data = os.read(self._master, _READ_CHUNK)
        elif source is self._client and self._client is not None:
            try:
                data = self._client.recv(_READ_CHUNK)
            except (BlockingIOError, InterruptedError):
                return
            except OSError:
                data = b""
            if not data:
                self._drop_client()
                return
        self._hand_over(data)

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

    def _accept(self) -> None:
        assert self._listener is not None
        try:
            client, _ = self._listener.accept()
        except (BlockingIOError, InterruptedError):
            return
        self._drop_client()
        client.setblocking(False)
        client.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._client = client
        self._connected = True
        self._selector.register(client, selectors.EVENT_READ)
        self._new_connection()

    def _drop_client(self) -> None:
        client = self._client
        if client is not None:
            with contextlib.suppress(KeyError, ValueError):
                self._selector.unregister(client)
            client.close()
            self._client = None
            self._connected = False
            self._pending.clear()

    def _output(self, data: bytes) -> None:
        if self._connected:
            self._pending += data
            if len(self._pending) > _MAX_PENDING:
                self._pending.clear()

    def _flush(self) -> None:
        if not self._pending:
            return
        try:
            if self._master >= 0:
                sent = os.write(self._master, self._pending)
            elif self._client is not None:
                sent = self._client.send(self._pending)
            else:
                sent = len(self._pending)
        except (BlockingIOError, InterruptedError):
            sent = 0
        except OSError:
            self._drop_client()
            sent = len(self._pending)
        del self._pending[:sent]

    # ---- clean-up

    def close(self) -> None:
        """Stop serving and release the terminal or socket (safe twice)."""
        if self._closed:
            return
        self._closed = True
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join()
        self._drop_client()
        if self._listener is not None:
            self._listener.close()
        if self._master >= 0:
            with contextlib.suppress(OSError):
                os.close(self._master)
            self._master = -1
        if self._link is not None:
            with contextlib.suppress(OSError):
                if self._link.is_symlink() and os.readlink(self._link) == self.path:
                    self._link.unlink()
        self._selector.close()

    def __enter__(self) -> GrblServer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def serve(machine: GrblMachine, *, pty: bool, link: str | None, tcp_port: int | None,
          host: str = "127.0.0.1", announce: Callable[[str], None] | None = None) -> int:
    """Serve ``machine`` in the foreground until SIGTERM or SIGINT; the exit status.

    Parameters:
        machine: the machine session.
        pty: serve on a pseudo-terminal (its path is announced), else on ``tcp_port``.
        link: with ``pty``, a symbolic link to make to the terminal.
        tcp_port: the TCP port without ``pty`` (0 or None picks a free one).
        host: the TCP address to bind.
        announce: where the serving line goes (standard output by default).
    """
    say = announce if announce is not None else _print
    with GrblServer(machine, pty=pty, link=link, tcp_port=tcp_port or 0, host=host) as server:
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
