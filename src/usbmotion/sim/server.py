"""Serve simulated devices in real time on pseudo-terminals or TCP ports.

One thread runs a loop: wait up to a millisecond for bytes from any client, hand them to
the device, advance the world towards the wall clock (at most 20 ms of device time a round,
so a loop that fell behind still sends output and sees :meth:`DeviceServer.stop` between
rounds), and send the devices' output back. A
pseudo-terminal's slave side stays open in the server, so clients may come and go; a TCP
port accepts one client at a time and accepts the next when it leaves.
"""

from __future__ import annotations

import contextlib
import os
import selectors
import socket
import threading
import time
import tty
from dataclasses import dataclass, field

from usbmotion.protocol import CallNumber, encode_call
from usbmotion.sim.world import SimLink, SimWorld

_POLL_S = 0.001
_READ_CHUNK = 65536
_MAX_STEP_US = 20_000
"""The most device time one round of the serving loop advances the world by."""
_NAME_QUERY = encode_call(CallNumber.SET_DEVICE_NAME, -1)
"""The device name asked for (a read, changing nothing)."""


@dataclass(slots=True)
class Endpoint:
    """Where one device is served: ``path`` for a pseudo-terminal, ``port`` for TCP."""

    key: str
    link: SimLink
    path: str = ""
    port: int = 0
    _master: int = -1
    _slave: int = -1
    _listener: socket.socket | None = None
    _client: socket.socket | None = None
    dropped_bytes: int = 0
    _pending: bytearray = field(default_factory=bytearray)

    @property
    def name(self) -> str:
        """The device's current name."""
        return self.link.device.name


class DeviceServer:
    """Serve every device of ``world`` on a pseudo-terminal each, or a TCP port each.

    Use as a context manager, or call :meth:`start` and :meth:`close`.

    Parameters:
        world: the devices; the server drives its clock from the wall clock.
        pty: serve on pseudo-terminals (else TCP).
        tcp_port: first TCP port; device ``i`` gets ``tcp_port + i`` (0 picks free ports).
        host: TCP address to bind (loopback by default).
    """

    def __init__(
        self, world: SimWorld, *, pty: bool = True, tcp_port: int = 0, host: str = "127.0.0.1"
    ) -> None:
        if not pty and not 0 <= tcp_port <= 65535:
            raise ValueError(f"tcp_port {tcp_port!r} is not a TCP port number 0..65535")
        self.world = world
        self._selector = selectors.DefaultSelector()
        self.endpoints: list[Endpoint] = []
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._error: BaseException | None = None
        self._closed = False
        try:
            for index, key in enumerate(world.keys):
                link = world.connect(key)
                endpoint = Endpoint(key, link)
                if pty:
                    self._open_pty(endpoint)
                else:
                    self._open_tcp(endpoint, host, tcp_port + index if tcp_port else 0)
                self.endpoints.append(endpoint)
        except BaseException:
            self.close()
            raise

    def _open_pty(self, endpoint: Endpoint) -> None:
        master, slave = os.openpty()
        tty.setraw(slave)
        os.set_blocking(master, False)
        endpoint._master, endpoint._slave = master, slave
        endpoint.path = os.ttyname(slave)
        self._selector.register(master, selectors.EVENT_READ, endpoint)

    def _open_tcp(self, endpoint: Endpoint, host: str, port: int) -> None:
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
        endpoint._listener = listener
        endpoint.port = listener.getsockname()[1]
        self._selector.register(listener, selectors.EVENT_READ, endpoint)

    def warm_up(self, *, timeout_s: float = 1.0) -> None:
        """Ask every device for its name and run it a tick past the answer, in the world's
        virtual time, before any client connects: whatever a device's first exchange loads
        (the compiled servo kernel, from numba's cache or compiled afresh: seconds) is
        loaded now, and a client's first exchange is answered at once.

        Parameters:
            timeout_s: device time each device has to answer, seconds.

        Raises:
            DeviceTimeoutError: a device did not answer.
            RuntimeError: the serving loop is running already.
        """
        from usbmotion.errors import DeviceTimeoutError  # noqa: PLC0415 - keeps import light

        if self._thread is not None:
            raise RuntimeError("warm_up() must come before start()")
        for endpoint in self.endpoints:
            link = endpoint.link
            link.write(_NAME_QUERY)
            if not self.world.wait_for(link, int(timeout_s * 1e6)):
                raise DeviceTimeoutError(
                    f"simulated device {endpoint.key!r} did not answer {_NAME_QUERY!r}"
                    f" within {timeout_s} s of device time")
            self.world.advance(link.device.tick_us)
            link.discard_input()

    def start(self) -> DeviceServer:
        """Run the serving loop in a background thread."""
        if self._thread is None:
            self._thread = threading.Thread(target=self._serve_logged, name="usbmotion-sim",
                                            daemon=True)
            self._thread.start()
        return self

    def stop(self) -> None:
        """Ask the serving loop to end."""
        self._stop.set()

    @property
    def serving(self) -> bool:
        """True while the background serving loop runs."""
        return self._thread is not None and self._thread.is_alive()

    @property
    def error(self) -> BaseException | None:
        """What ended the background serving loop, if an exception did."""
        return self._error

    def _serve_logged(self) -> None:
        try:
            self.serve()
        except BaseException as error:
            self._error = error
            raise

    def serve(self) -> None:
        """Serve until :meth:`stop` (blocking)."""
        origin = time.monotonic() - self.world.time_us / 1e6
        while not self._stop.is_set():
            for key, _ in self._selector.select(timeout=_POLL_S):
                self._readable(key.data, key.fileobj)
            wall_us = int((time.monotonic() - origin) * 1e6)
            self.world.advance_to(min(wall_us, self.world.time_us + _MAX_STEP_US))
            for endpoint in self.endpoints:
                self._flush(endpoint)

    def _readable(self, endpoint: Endpoint, source: object) -> None:
        if source is endpoint._listener:
            self._accept(endpoint)
            return
        data = b""
        if source == endpoint._master:
            with contextlib.suppress(BlockingIOError, OSError):
                data = os.read(endpoint._master, _READ_CHUNK)
        elif source is endpoint._client and endpoint._client is not None:
            try:
                data = endpoint._client.recv(_READ_CHUNK)
            except (BlockingIOError, InterruptedError):
                return
            except OSError:
                data = b""
            if not data:
                self._drop_client(endpoint)
                return
        if data:
            endpoint.link.write(data)

    def _accept(self, endpoint: Endpoint) -> None:
        assert endpoint._listener is not None
        try:
            client, _ = endpoint._listener.accept()
        except (BlockingIOError, InterruptedError):
            return
        self._drop_client(endpoint)
        client.setblocking(False)
        client.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        endpoint._client = client
        endpoint.link.discard_input()
        endpoint._pending.clear()
        self._selector.register(client, selectors.EVENT_READ, endpoint)

    def _drop_client(self, endpoint: Endpoint) -> None:
        client = endpoint._client
        if client is not None:
            with contextlib.suppress(KeyError, ValueError):
                self._selector.unregister(client)
            client.close()
            endpoint._client = None

    def _flush(self, endpoint: Endpoint) -> None:
        endpoint._pending += endpoint.link.receive(1 << 30)
        if not endpoint._pending:
            return
        try:
            if endpoint._master >= 0:
                sent = os.write(endpoint._master, endpoint._pending)
            elif endpoint._client is not None:
                sent = endpoint._client.send(endpoint._pending)
            else:
                endpoint.dropped_bytes += len(endpoint._pending)
                sent = len(endpoint._pending)
        except (BlockingIOError, InterruptedError):
            sent = 0
        except OSError:
            self._drop_client(endpoint)
            sent = len(endpoint._pending)
        del endpoint._pending[:sent]
        if len(endpoint._pending) > 1 << 20:
            endpoint.dropped_bytes += len(endpoint._pending)
            endpoint._pending.clear()

    def close(self) -> None:
        """Stop serving and release every pseudo-terminal and socket (safe twice)."""
        if self._closed:
            return
        self._closed = True
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join()  # within a round: its descriptors are closed below
        for endpoint in self.endpoints:
            self._drop_client(endpoint)
            for fd in (endpoint._master, endpoint._slave):
                if fd >= 0:
                    with contextlib.suppress(OSError):
                        os.close(fd)
            if endpoint._listener is not None:
                endpoint._listener.close()
            endpoint.link.close()
        self._selector.close()

    def __enter__(self) -> DeviceServer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
