"""Serving a byte stream to one client at a time on a pseudo-terminal or a TCP port: what
the grbl front (``grbl/server.py``), ``usbmotion sim`` (``sim/server.py``) and the
emulated firmware's terminals (``sim/firmware.py``) share.

:class:`PtyEndpoint` is a pseudo-terminal in raw mode whose slave side the server keeps
open, so clients come and go without the master side failing; its path, and optionally a
symbolic link to it, are what clients open. :class:`TcpEndpoint` listens on a TCP port.
:class:`Serving` waits on any number of them (and on other readers a server has) and turns
what happens into :class:`Event` values: a client connected or left, bytes came, a second
client was refused or got in. Output for a client goes through a bounded :class:`Outbox`
and is written without blocking; output while no client is connected is dropped (a device
or a controller with nobody on the line), and so is output beyond the box's bound, counted
in ``dropped_bytes``.

One client at a time, as a serial port has:

- On a pseudo-terminal the server watches every open and close of the terminal (inotify,
  Linux). Linux, as with a real serial port, does not stop a second program from opening
  it; what keeps a port to one client is the client's lock: pyserial's ``exclusive=True``
  (which usbmotion's own host uses) and node-serialport's default ``lock`` (which cncjs
  uses) take an exclusive ``flock``, so a second client that locks is refused while the
  first holds it, root or not. A second program that opens it all the same is reported
  (:attr:`EventKind.SECOND_CLIENT`: its bytes and the first one's mix). A client may make
  the terminal exclusive itself (``TIOCEXCL``, as some serial libraries do when they open a
  port; then another program's open fails with ``EBUSY`` unless it has ``CAP_SYS_ADMIN``,
  as root has): on a pseudo-terminal that mode would outlive the client, so the server ends
  it when the last client leaves, as a real port forgets it at its last close, and drops
  what the client left unread. The server does not set that mode itself: it would have to
  set it after a client's open and clear it after its close, and a client that closes and
  opens again at once (discovery's probe, then the connection) would find it still set: 121
  of 300 such reopens 3 ms apart failed with ``EBUSY`` (both cores busy), for anyone but
  root.
- On TCP a second client is refused (accepted and closed at once,
  :attr:`EventKind.REFUSED`) or replaces the first (closed), as the endpoint's
  :class:`SecondClient` says: the device servers refuse (a port held by a host), the grbl
  front replaces (a sender reconnecting after its link died must get through: grbl's
  network ports behave so).

A link (``--link /tmp/ttyGRBL``) is never taken from a live terminal: a link that points at
a terminal that still exists (another server's) is refused naming the process serving it;
a stale link (its terminal gone) is replaced.
"""

from __future__ import annotations

import contextlib
import ctypes
import fcntl
import os
import selectors
import socket
import struct
import termios
import tty
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from enum import Enum
from pathlib import Path

from usbmotion.errors import ArgumentError

MAX_PENDING_BYTES = 1 << 20
"""The most output an endpoint keeps for a client that does not read; more is dropped."""
READ_CHUNK = 65536
"""The most bytes read from a client at once."""


class EventKind(Enum):
    """What :meth:`Serving.wait` reports."""

    CONNECTED = "connected"
    """A client connected (a first program opened the terminal; a TCP client was taken)."""
    DISCONNECTED = "disconnected"
    """The client left (the last program closed the terminal; the TCP client closed)."""
    DATA = "data"
    """Bytes from the client: :attr:`Event.data`."""
    REFUSED = "refused"
    """A second TCP client was refused: :attr:`Event.detail` is its address."""
    SECOND_CLIENT = "second client"
    """A second program opened the terminal while a client has it."""
    READABLE = "readable"
    """A reader added with :meth:`Serving.add_reader` can be read: :attr:`Event.source`."""


class SecondClient(Enum):
    """What a TCP endpoint does with a client that comes while it has one."""

    REFUSE = "refuse"
    """Accept it and close it at once; the first keeps the port."""
    REPLACE = "replace"
    """Close the first; the new one has the port."""


@dataclass(frozen=True, slots=True)
class Event:
    """Something that happened on an endpoint, or on a reader of the server's own.

    Fields:
        kind: what happened.
        endpoint: where (None for :attr:`EventKind.READABLE`).
        data: the bytes of :attr:`EventKind.DATA`.
        detail: who, for :attr:`EventKind.REFUSED` and :attr:`EventKind.SECOND_CLIENT`.
        source: the reader, for :attr:`EventKind.READABLE`.
    """

    kind: EventKind
    endpoint: Endpoint | None
    data: bytes = b""
    detail: str = ""
    source: object = None


class Outbox:
    """Bytes waiting for a writer that may take only part of them at a time, at most
    ``max_bytes``: what would go beyond is dropped and counted.

    Raises:
        ArgumentError: ``max_bytes`` below 1.
    """

    def __init__(self, max_bytes: int = MAX_PENDING_BYTES) -> None:
        if max_bytes < 1:
            raise ArgumentError(f"max_bytes {max_bytes!r} must be >= 1", reason="max_bytes")
        self.max_bytes = max_bytes
        self._pending = bytearray()
        self.dropped_bytes = 0
        """Bytes dropped so far (beyond the bound, or cleared unsent)."""

    def __len__(self) -> int:
        return len(self._pending)

    def add(self, data: bytes) -> None:
        """Queue ``data``; whatever does not fit under the bound is dropped."""
        room = self.max_bytes - len(self._pending)
        self._pending += data[:room]
        self.dropped_bytes += max(0, len(data) - room)

    def clear(self) -> None:
        """Drop what waits (counted)."""
        self.dropped_bytes += len(self._pending)
        self._pending.clear()

    def write_to(self, write: Callable[[bytearray], int]) -> None:
        """Give what waits to ``write`` (a non-blocking ``send`` or ``os.write``); what it
        did not take stays.

        Raises:
            OSError: the writer failed otherwise than by having no room now.
        """
        if not self._pending:
            return
        try:
            sent = write(self._pending)
        except (BlockingIOError, InterruptedError):
            return
        del self._pending[:sent]


class Endpoint:
    """Where one client at a time is served (:class:`PtyEndpoint`, :class:`TcpEndpoint`).

    ``label`` names it in the owner's messages (a device's key).
    """

    def __init__(self, *, label: str = "", max_pending_bytes: int = MAX_PENDING_BYTES) -> None:
        self.label = label
        self.outbox = Outbox(max_pending_bytes)
        self.connected = False
        """True while a client is connected."""
        self.connections = 0
        """How many times a client connected."""
        self._unsent_while_away = 0

    @property
    def dropped_bytes(self) -> int:
        """Output dropped: sent while no client was there, beyond the bound, or left
        unsent when a client went."""
        return self.outbox.dropped_bytes + self._unsent_while_away

    def send(self, data: bytes) -> None:
        """Queue ``data`` for the client (dropped while none is connected)."""
        if self.connected:
            self.outbox.add(data)
        else:
            self._unsent_while_away += len(data)

    def _connect(self) -> Event:
        self.connected = True
        self.connections += 1
        return Event(EventKind.CONNECTED, self)

    def _disconnect(self) -> Event:
        self.connected = False
        self.outbox.clear()
        return Event(EventKind.DISCONNECTED, self)

    def close(self) -> None:
        """Release the endpoint (safe twice)."""


# --- pseudo-terminals ---------------------------------------------------------------------

_IN_OPEN = 0x20
_IN_CLOSE = 0x08 | 0x10
_EVENT = struct.Struct("iIII")


class _OpenWatch:
    """Every open and close of one file, by any process (inotify)."""

    def __init__(self, path: str) -> None:
        libc = ctypes.CDLL(None, use_errno=True)
        self.fd = int(libc.inotify_init1(os.O_NONBLOCK | os.O_CLOEXEC))
        if self.fd < 0:
            code = ctypes.get_errno()
            raise OSError(code, f"inotify for {path}: {os.strerror(code)}")
        if libc.inotify_add_watch(self.fd, os.fsencode(path), _IN_OPEN | _IN_CLOSE) < 0:
            code = ctypes.get_errno()
            os.close(self.fd)
            raise OSError(code, f"inotify for {path}: {os.strerror(code)}")

    def changes(self) -> list[int]:
        """+1 for each open since the last call, -1 for each close, in order."""
        found: list[int] = []
        while True:
            try:
                data = os.read(self.fd, 4096)
            except (BlockingIOError, InterruptedError):
                return found
            if not data:
                return found
            offset = 0
            while offset + _EVENT.size <= len(data):
                _, mask, _, size = _EVENT.unpack_from(data, offset)
                offset += _EVENT.size + size
                if mask & _IN_OPEN:
                    found.append(1)
                if mask & _IN_CLOSE:
                    found.append(-1)

    def close(self) -> None:
        os.close(self.fd)


def _watch(path: str) -> _OpenWatch | None:
    """A watch of ``path``'s opens and closes, or None where the system has none (then the
    terminal counts as connected throughout)."""
    try:
        return _OpenWatch(path)
    except (OSError, AttributeError):
        return None


class PtyEndpoint(Endpoint):
    """A pseudo-terminal in raw mode; clients open :attr:`path` (or :attr:`link`).

    Parameters:
        link: also make a symbolic link to the terminal here (removed on close).
        label: a name for the owner's messages.
        max_pending_bytes: the bound of the output kept for the client.

    Raises:
        ArgumentError: ``link`` is a live link (a terminal another server serves) or
            something else than a link.
        OSError: the terminal or the link cannot be made.
    """

    def __init__(self, *, link: str | Path | None = None, label: str = "",
                 max_pending_bytes: int = MAX_PENDING_BYTES) -> None:
        super().__init__(label=label, max_pending_bytes=max_pending_bytes)
        self.link: Path | None = None
        self.clients = 0
        """How many programs have the terminal open now."""
        self.master, self._slave = os.openpty()
        try:
            tty.setraw(self._slave)
            os.set_blocking(self.master, False)
            self.path = os.ttyname(self._slave)
            self._watch = _watch(self.path)
            self.connected = self._watch is None
            if link is not None:
                self.link = make_link(Path(link), self.path)
        except BaseException:
            self.close()
            raise

    @property
    def watch_fd(self) -> int | None:
        """The descriptor that becomes readable when a program opens or closes the
        terminal (None without a watch)."""
        return self._watch.fd if self._watch is not None else None

    def _opens_and_closes(self) -> list[Event]:
        events: list[Event] = []
        if self._watch is None:
            return events
        for change in self._watch.changes():
            self.clients = max(0, self.clients + change)
            if change > 0 and self.clients == 1 and not self.connected:
                events.append(self._connect())
            elif change > 0 and self.clients > 1:
                events.append(Event(EventKind.SECOND_CLIENT, self, detail=self.path))
            elif change < 0 and self.clients == 0 and self.connected:
                with contextlib.suppress(OSError):  # as a port at its last close
                    fcntl.ioctl(self._slave, termios.TIOCNXCL)
                    termios.tcflush(self._slave, termios.TCIFLUSH)
                    tty.setraw(self._slave)
                events.append(self._disconnect())
        return events

    def _read(self) -> bytes:
        try:
            return os.read(self.master, READ_CHUNK)
        except (BlockingIOError, InterruptedError):
            return b""
        except OSError:  # EIO: no slave side (not while the server holds it)
            return b""

    def flush(self) -> None:
        """Write what waits for the client, as much as the terminal takes now."""
        with contextlib.suppress(OSError):
            self.outbox.write_to(lambda data: os.write(self.master, data))

    def close(self) -> None:
        """Close the terminal and remove the link if it still points at it (safe twice)."""
        if self.link is not None:
            with contextlib.suppress(OSError):
                if self.link.is_symlink() and os.readlink(self.link) == self.path:
                    self.link.unlink()
            self.link = None
        watch = getattr(self, "_watch", None)
        if watch is not None:
            watch.close()
            self._watch = None
        for fd in (self.master, self._slave):
            if fd >= 0:
                with contextlib.suppress(OSError):
                    os.close(fd)
        self.master = self._slave = -1


def link_problem(link: Path) -> str | None:
    """Why a link to a new terminal may not be made at ``link``: it is a live link (it
    points at a terminal that still exists: another server's, named with the process
    serving it when that can be found), or something else than a link; None when it is
    free or stale (its terminal gone)."""
    if link.is_symlink():
        if not os.path.exists(link):
            return None
        pointed = os.readlink(link)
        holder = terminal_server(pointed)
        served = f" (process {holder})" if holder else ""
        return (f"link {link} points at {pointed}, a terminal another server still"
                f" serves{served}; stop that server or give another link")
    if os.path.lexists(link):
        return f"link {link} is a file, not a link: remove it or give another link"
    return None


def make_link(link: Path, target: str) -> Path:
    """A symbolic link at ``link`` to the terminal ``target``, made at once (a stale link,
    whose terminal is gone, is replaced).

    Raises:
        ArgumentError: :func:`link_problem` says why not.
        OSError: the link cannot be made.
    """
    problem = link_problem(link)
    if problem is not None:
        raise ArgumentError(problem, reason="link")
    temporary = link.with_name(f".{link.name}.{os.getpid()}")
    temporary.unlink(missing_ok=True)
    temporary.symlink_to(target)
    try:
        os.replace(temporary, link)
    except BaseException:
        temporary.unlink(missing_ok=True)
        raise
    return link


def terminal_server(terminal: str) -> str:
    """``1234 (python3)``: the process holding the master side of the pseudo-terminal
    ``terminal`` (``/dev/pts/N``), or ``""`` when none can be found (another user's)."""
    index = terminal.removeprefix("/dev/pts/")
    if not index.isdigit():
        return ""
    wanted = f"tty-index:\t{index}"
    for process in Path("/proc").iterdir():
        if not process.name.isdigit():
            continue
        try:
            for fd in (process / "fd").iterdir():
                if os.readlink(fd) == "/dev/ptmx" and wanted in (
                        process / "fdinfo" / fd.name).read_text().splitlines():
                    name = (process / "comm").read_text().strip()
                    return f"{process.name} ({name})"
        except OSError:
            continue
    return ""


# --- TCP ------------------------------------------------------------------------------------


def listening_socket(host: str, port: int, *, backlog: int = 64) -> socket.socket:
    """A TCP socket bound to ``host``:``port`` (IPv6 for an IPv6 address; port 0: a free
    one) and listening, for a server that accepts on it itself (the web dashboard's).

    Raises:
        ArgumentError: a port out of 0..65535.
        OSError: the port cannot be bound.
    """
    if not 0 <= port <= 65535:
        raise ArgumentError(f"port {port!r} is not a TCP port number 0..65535", reason="port")
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    listener = socket.socket(family, socket.SOCK_STREAM)
    listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        listener.bind((host, port))
        listener.listen(backlog)
    except OSError:
        listener.close()
        raise
    return listener


class TcpEndpoint(Endpoint):
    """A TCP port clients connect to, one at a time.

    Parameters:
        host: the address to bind.
        port: the port (0: a free one, then :attr:`port` says which).
        second_client: what a client that comes while one is connected gets.
        label: a name for the owner's messages.
        max_pending_bytes: the bound of the output kept for the client.

    Raises:
        ArgumentError: a port out of 0..65535.
        OSError: the port cannot be bound (``cannot listen on HOST:PORT: ...``).
    """

    def __init__(self, host: str = "127.0.0.1", port: int = 0, *,
                 second_client: SecondClient = SecondClient.REFUSE, label: str = "",
                 max_pending_bytes: int = MAX_PENDING_BYTES) -> None:
        if not 0 <= port <= 65535:
            raise ArgumentError(f"tcp_port {port!r} is not a TCP port number 0..65535",
                                reason="tcp_port")
        super().__init__(label=label, max_pending_bytes=max_pending_bytes)
        self.second_client = second_client
        self.client: socket.socket | None = None
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
        self.listener = listener
        self.host: str = listener.getsockname()[0]
        self.port: int = listener.getsockname()[1]

    def _accept(self) -> list[Event]:
        try:
            client, address = self.listener.accept()
        except (BlockingIOError, InterruptedError):
            return []
        peer = f"{address[0]}:{address[1]}"
        if self.client is not None and self.second_client is SecondClient.REFUSE:
            client.close()
            return [Event(EventKind.REFUSED, self, detail=peer)]
        events = [self._drop()] if self.client is not None else []
        client.setblocking(False)
        client.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.client = client
        events.append(self._connect())
        return events

    def _drop(self) -> Event:
        client, self.client = self.client, None
        if client is not None:
            client.close()
        return self._disconnect()

    def _read(self) -> tuple[bytes, bool]:
        """(bytes, the client left)."""
        if self.client is None:
            return b"", False
        try:
            data = self.client.recv(READ_CHUNK)
        except (BlockingIOError, InterruptedError):
            return b"", False
        except OSError:
            return b"", True
        return data, not data

    def flush(self) -> bool:
        """Write what waits for the client; False when the client is gone (the write
        failed: reset, broken pipe)."""
        client = self.client
        if client is None:
            return True
        try:
            self.outbox.write_to(client.send)
        except OSError:
            return False
        return True

    def close(self) -> None:
        """Close the client and the listening socket (safe twice)."""
        if self.client is not None:
            self.client.close()
            self.client = None
        self.listener.close()


# --- the loop -----------------------------------------------------------------------------


class Serving:
    """The endpoints of one server and its other readers, waited on together.

    Use as a context manager, or call :meth:`close` (which closes the endpoints too).
    Call :meth:`wait` and :meth:`flush` from one thread.
    """

    def __init__(self, endpoints: Sequence[Endpoint] = ()) -> None:
        self._selector = selectors.DefaultSelector()
        self.endpoints: list[Endpoint] = []
        self._later: list[Event] = []
        self._closed = False
        try:
            for endpoint in endpoints:
                self.add(endpoint)
        except BaseException:
            self.close()
            raise

    def add(self, endpoint: Endpoint) -> Endpoint:
        """Serve ``endpoint`` too (it is closed with the others)."""
        self.endpoints.append(endpoint)
        if isinstance(endpoint, PtyEndpoint):
            self._selector.register(endpoint.master, selectors.EVENT_READ, (endpoint, "data"))
            if endpoint.watch_fd is not None:
                self._selector.register(endpoint.watch_fd, selectors.EVENT_READ,
                                        (endpoint, "watch"))
        elif isinstance(endpoint, TcpEndpoint):
            self._selector.register(endpoint.listener, selectors.EVENT_READ,
                                    (endpoint, "listener"))
        return endpoint

    def add_reader(self, source: socket.socket | int) -> None:
        """Report ``source`` (a socket or a descriptor of the server's own) when it can be
        read, as :attr:`EventKind.READABLE`."""
        self._selector.register(source, selectors.EVENT_READ, (None, "reader"))

    def remove_reader(self, source: socket.socket | int) -> None:
        """Stop watching ``source``."""
        with contextlib.suppress(KeyError, ValueError):
            self._selector.unregister(source)

    def wait(self, timeout_s: float) -> list[Event]:
        """What happened within ``timeout_s`` (at once when something had): the opens and
        closes of each terminal before the bytes that came on it."""
        events, self._later = self._later, []
        ready = self._selector.select(timeout=0 if events else timeout_s)
        for endpoint in {key.data[0] for key, _ in ready if key.data[1] == "data"}:
            assert isinstance(endpoint, PtyEndpoint)
            events += endpoint._opens_and_closes()
        for key, _ in ready:
            endpoint, role = key.data
            if role == "watch":
                events += endpoint._opens_and_closes()
            elif role == "data":
                data = endpoint._read()
                if data:
                    events.append(Event(EventKind.DATA, endpoint, data))
            elif role == "listener":
                events += self._accepted(endpoint)
            elif role == "client":
                data, gone = endpoint._read()
                if data:
                    events.append(Event(EventKind.DATA, endpoint, data))
                if gone:
                    events.append(self._dropped(endpoint))
            else:
                events.append(Event(EventKind.READABLE, None, source=key.fileobj))
        return events

    def _accepted(self, endpoint: TcpEndpoint) -> list[Event]:
        before = endpoint.client
        events = endpoint._accept()
        if endpoint.client is not before:
            if before is not None:
                with contextlib.suppress(KeyError, ValueError):
                    self._selector.unregister(before)
            if endpoint.client is not None:
                self._selector.register(endpoint.client, selectors.EVENT_READ,
                                        (endpoint, "client"))
        return events

    def _dropped(self, endpoint: TcpEndpoint) -> Event:
        if endpoint.client is not None:
            with contextlib.suppress(KeyError, ValueError):
                self._selector.unregister(endpoint.client)
        return endpoint._drop()

    def flush(self) -> None:
        """Write what waits for each endpoint's client, without blocking; a TCP client
        found gone is reported by the next :meth:`wait`."""
        for endpoint in self.endpoints:
            if isinstance(endpoint, PtyEndpoint):
                endpoint.flush()
            elif isinstance(endpoint, TcpEndpoint) and not endpoint.flush():
                self._later.append(self._dropped(endpoint))

    def close(self) -> None:
        """Close every endpoint and stop watching (safe twice)."""
        if self._closed:
            return
        self._closed = True
        for endpoint in self.endpoints:
            endpoint.close()
        self._selector.close()

    def __enter__(self) -> Serving:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


__all__ = ["MAX_PENDING_BYTES", "Endpoint", "Event", "EventKind", "Outbox", "PtyEndpoint",
           "SecondClient", "Serving", "TcpEndpoint", "link_problem", "make_link",
           "terminal_server"]
