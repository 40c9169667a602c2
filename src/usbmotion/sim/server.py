"""Serve simulated devices in real time on pseudo-terminals or TCP ports
(:mod:`usbmotion.serving`).

One thread runs a loop: wait up to a millisecond for bytes from any client, hand them to
the device, advance the world towards the wall clock (at most 20 ms of device time a round,
so a loop that fell behind still sends output and sees :meth:`DeviceServer.stop` between
rounds), and send the devices' output back. Each device is served to one client at a
time, as a port is held by one host: on a pseudo-terminal a second host that locks the
port (as usbmotion's does) is refused by the first one's lock, and a program that opens it
regardless is reported; a second TCP client is refused (closed at once) while one is
connected, and the port takes the next once it leaves. A client that connects starts with
the device's input empty (a line the last one left half-written is dropped); output while
no client is connected is dropped.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

from usbmotion.protocol import CallNumber, encode_call
from usbmotion.serving import (
    EventKind,
    PtyEndpoint,
    SecondClient,
    Serving,
    TcpEndpoint,
)
from usbmotion.sim.world import SimLink, SimWorld, ready

_POLL_S = 0.001
_MAX_STEP_US = 20_000
"""The most device time one round of the serving loop advances the world by."""
_NAME_QUERY = encode_call(CallNumber.SET_DEVICE_NAME, -1)
"""The device name asked for (a read, changing nothing)."""


@dataclass(slots=True)
class Endpoint:
    """Where one device is served: ``path`` for a pseudo-terminal, ``port`` for TCP."""

    key: str
    link: SimLink
    served: PtyEndpoint | TcpEndpoint

    @property
    def name(self) -> str:
        """The device's current name."""
        return self.link.device.name

    @property
    def path(self) -> str:
        """The pseudo-terminal's path (empty on TCP)."""
        return self.served.path if isinstance(self.served, PtyEndpoint) else ""

    @property
    def port(self) -> int:
        """The TCP port (0 on a pseudo-terminal)."""
        return self.served.port if isinstance(self.served, TcpEndpoint) else 0

    @property
    def dropped_bytes(self) -> int:
        """Device output no client took (none connected, or one that did not read)."""
        return self.served.dropped_bytes


class DeviceServer:
    """Serve every device of ``world`` on a pseudo-terminal each, or a TCP port each.

    Use as a context manager, or call :meth:`start` and :meth:`close`.

    Parameters:
        world: the devices; the server drives its clock from the wall clock.
        pty: serve on pseudo-terminals (else TCP).
        tcp_port: first TCP port; device ``i`` gets ``tcp_port + i`` (0 picks free ports).
        host: TCP address to bind (loopback by default).
        on_notice: where a notice goes (a second client refused, a second program on a
            terminal); dropped by default. Called from the serving thread.
    """

    def __init__(
        self, world: SimWorld, *, pty: bool = True, tcp_port: int = 0, host: str = "127.0.0.1",
        on_notice: Callable[[str], None] | None = None,
    ) -> None:
        if not pty and not 0 <= tcp_port <= 65535:
            raise ValueError(f"tcp_port {tcp_port!r} is not a TCP port number 0..65535")
        self.world = world
        self.endpoints: list[Endpoint] = []
        self._notice = on_notice or (lambda text: None)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._error: BaseException | None = None
        self._closed = False
        self._serving = Serving()
        self._by_served: dict[int, Endpoint] = {}
        try:
            for index, key in enumerate(world.keys):
                served: PtyEndpoint | TcpEndpoint = (
                    PtyEndpoint(label=key) if pty else
                    TcpEndpoint(host, tcp_port + index if tcp_port else 0, label=key,
                                second_client=SecondClient.REFUSE))
                self._serving.add(served)
                endpoint = Endpoint(key, world.connect(key), served)
                self.endpoints.append(endpoint)
                self._by_served[id(served)] = endpoint
        except BaseException:
            self.close()
            raise

    def warm_up(self, *, timeout_s: float = 1.0) -> None:
        """Ask every device for its name and run it a tick past the answer, in the world's
        virtual time, and load what a device loads at its first motion (the compiled servo
        kernel, from its file or compiled afresh: seconds), before any client
        connects: a client's first exchange is answered at once, its first move on time.

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
            ready(link.device)

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
            for event in self._serving.wait(_POLL_S):
                endpoint = self._by_served[id(event.endpoint)]
                if event.kind is EventKind.DATA:
                    endpoint.link.write(event.data)
                elif event.kind is EventKind.CONNECTED:
                    endpoint.link.discard_input()
                elif event.kind is EventKind.REFUSED:
                    self._notice(f"device {endpoint.name!r} (port {endpoint.port}): refused a"
                                 f" second client from {event.detail}: one host at a time")
                elif event.kind is EventKind.SECOND_CLIENT:
                    self._notice(f"device {endpoint.name!r}: a second program opened"
                                 f" {event.detail} while a host has it, without locking it:"
                                 " its bytes and the host's mix")
            wall_us = int((time.monotonic() - origin) * 1e6)
            self.world.advance_to(min(wall_us, self.world.time_us + _MAX_STEP_US))
            for endpoint in self.endpoints:
                output = endpoint.link.receive(1 << 30)
                if output:
                    endpoint.served.send(output)
            self._serving.flush()

    def close(self) -> None:
        """Stop serving and release every pseudo-terminal and socket (safe twice)."""
        if self._closed:
            return
        self._closed = True
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join()  # within a round: its descriptors are closed below
        self._serving.close()
        for endpoint in self.endpoints:
            endpoint.link.close()

    def __enter__(self) -> DeviceServer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
