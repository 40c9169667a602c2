"""Taking over a link the device is still printing on.

A host that dies leaves its devices printing: the diagnostics it asked for, the echo of a
batch, answers to queries it sent last, and whatever line was crossing the link when the new
host cleared its input. After a discard the transport drops bytes up to the next newline
(the tail of a line in flight) unless the port says its reset leaves the link at the start of
a line, and a new host resynchronises before it believes any answer: diagnostics off, a
query of its own, every line up to its answer skipped.

A ``sim://`` port's reset drops everything the device has printed, so on it no tail can
follow a discard. :class:`InFlightPort` gives a ``sim://`` link the behaviour of a USB serial
port: the device's output crosses in small packets, and a reset drops only the packet that
has reached the host.
"""

from __future__ import annotations

from typing import Any

import pytest
import serial

from usbmotion.device import Device, MemoryFlash
from usbmotion.host import device as device_module
from usbmotion.host.config import parse_config
from usbmotion.host.device import DeviceClient
from usbmotion.host.transport import LineTransport
from usbmotion.protocol import ReplyKind, parse_reply
from usbmotion.sim import register_url_handler
from usbmotion.sim.machine import SimulatedMachine
from usbmotion.sim.registry import set_world
from usbmotion.sim.world import SimWorld

PACKET_BYTES = 7
"""Shorter than any diagnostics line, so lines cross the link in pieces."""


class InFlightPort:
    """A ``sim://`` port with the input side of a real USB serial port.

    What the device prints crosses the link ``packet_bytes`` at a time, a packet only
    once the host has read the last one; :meth:`reset_input_buffer` drops the packet that
    has arrived, not the bytes still on the device's side. ``last_byte`` is the last byte
    the host read, so a test knows when the host holds part of a line.
    """

    def __init__(self, port: Any, *, packet_bytes: int) -> None:
        self.port = port
        self.usbmotion_clock = port.usbmotion_clock
        self.packet_bytes = packet_bytes
        self.timeout: float | None = 0
        self.last_byte = b"\n"
        self._sending = bytearray()
        self._arrived = bytearray()

    def _cross(self) -> None:
        self._sending += self.port.read(self.port.in_waiting)
        if not self._arrived:
            self._arrived += self._sending[: self.packet_bytes]
            del self._sending[: self.packet_bytes]

    @property
    def in_waiting(self) -> int:
        self._cross()
        return len(self._arrived)

    def read(self, size: int = 1) -> bytes:
        self._cross()
        if not self._arrived and self.timeout != 0:
            self.port.timeout = self.timeout
            try:
                self._sending += self.port.read(1)
            finally:
                self.port.timeout = 0
            self._cross()
        out = bytes(self._arrived[:size])
        del self._arrived[:size]
        if out:
            self.last_byte = out[-1:]
        return out

    def write(self, data: bytes) -> int:
        return int(self.port.write(data))

    def reset_input_buffer(self) -> None:
        self._arrived.clear()

    def close(self) -> None:
        self.port.close()


def named(name: str) -> Device:
    """A simulated device with ``name`` in its flash."""
    device = Device(flash=MemoryFlash())
    codes = " ".join(str(ord(c)) for c in name)
    device.feed(f"18 {len(name)} {codes}\n".encode("ascii"))
    device.take_output()
    return device


def _world(name: str, device_name: str = "X AXIS") -> SimWorld:
    world = SimWorld()
    world.add(named(device_name), key="X")
    set_world(name, world)
    return world


def _in_flight(world_name: str) -> InFlightPort:
    register_url_handler()
    port = serial.serial_for_url(f"sim://X?world={world_name}", timeout=0)
    return InFlightPort(port, packet_bytes=PACKET_BYTES)


def _read_into_a_line(transport: LineTransport, port: InFlightPort) -> list[bytes]:
    """Read until the host holds the head of a line whose tail has not arrived."""
    lines: list[bytes] = []
    for _ in range(1000):
        transport.sleep(0.0005)
        lines += transport.poll_lines()
        if lines and port.last_byte != b"\n":
            return lines
    raise AssertionError("the host never stopped in the middle of a line")


def _diagnostics_clocks(lines: list[bytes]) -> list[int]:
    clocks = []
    for line in lines:
        reply = parse_reply(line)
        assert reply.kind is ReplyKind.DIAGNOSTICS, line
        clocks.append(reply.values[0])
    return clocks


# --- the transport ---------------------------------------------------------------------------


def test_the_tail_of_a_line_in_flight_is_not_delivered_after_a_discard(world_name: str) -> None:
    _world(world_name)
    port = _in_flight(world_name)
    with LineTransport(port, label="X") as transport:
        transport.write(b"21 1\n")
        before = _diagnostics_clocks(_read_into_a_line(transport, port))
        transport.discard_input()
        after = [transport.read_line(0.01) for _ in range(20)]
    clocks = _diagnostics_clocks(after)
    assert clocks == list(range(clocks[0], clocks[0] + 20)), "whole lines, one per tick"
    assert clocks[0] > before[-1] + 1, "the line cut by the discard is dropped whole"


def test_a_port_that_cannot_tell_drops_up_to_the_next_newline_even_at_a_line_start(
    world_name: str,
) -> None:
    _world(world_name)
    port = _in_flight(world_name)
    port.packet_bytes = 4096
    with LineTransport(port, label="X") as transport:
        transport.discard_input()
        transport.write(b"2 -1\n20 -1\n")
        first = parse_reply(transport.read_line(0.01))
    assert (first.kind, first.call) == (ReplyKind.QUERY, 20), "MOTION_QUEUE was dropped"


def test_a_discard_on_a_sim_port_keeps_the_next_line(world_name: str) -> None:
    _world(world_name)
    with LineTransport.open(f"sim://X?world={world_name}") as transport:
        transport.write(b"21 1\n")
        transport.read_line(0.01)
        transport.write(b"21 0\n")
        transport.sleep(0.01)
        transport.discard_input()
        transport.write(b"2 -1\n")
        assert transport.read_line(0.01) == b"MOTION_QUEUE 0 1000"


# --- a new host ---------------------------------------------------------------------------


def test_a_new_client_resynchronises_over_a_half_read_line(world_name: str) -> None:
    world = _world(world_name)
    port = _in_flight(world_name)
    transport = LineTransport(port, label="X")
    with DeviceClient(transport, name="X", timeout_s=0.05) as client:
        transport.write(b"21 1\n")
        _read_into_a_line(transport, port)
        client.resynchronise(stop_diagnostics=True)
        assert client.device_name() == "X AXIS"
        status = client.status()
        assert (status.enabled, status.queued, status.fault) == (False, 0, 0)
        assert client.queue_status() == (0, 1000)
        assert world.device("X").settings.diagnostics_interval == 0
        transport.sleep(0.05)
        assert transport.poll_lines() == [], "no diagnostics after the take-over"


def test_machine_connect_takes_over_a_device_a_dead_host_left_printing(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    world = SimWorld()
    world.add(named("X AXIS"), key="X")
    dead = world.connect("X", latency_us=5000)
    dead.write(b"21 1\n")
    world.advance(20_000)
    dead.write(
        b"8 1 1\n1 3 10 20 30\n2 -1\n20 -1\n"  # a batch echoed, the answers to its last queries
        b"8 63 7\n8 63 -1\n8 63 0\n"            # the marker of its own take-over
        b"1 2 5"                                 # and half a line when it died
    )
    dead.close()
    monkeypatch.setattr(device_module._MARKERS, "randint", lambda low, high: 8)
    config = parse_config(
        'watchdog_ms = 0\n[axes.X]\nurl = "sim://X"\ndevice = "X AXIS"\ncounts_per_mm = 240\n'
        "max_velocity_mm_s = 20\nmax_accel_mm_s2 = 500\ntravel_mm = [0, 200]\n"
        "following_error_limit_mm = 1.5\ngains = { kp = 0.5, ki = 5.0, kd = 0.002 }\n"
    )
    with SimulatedMachine.connect(config, world=world) as machine:
        client = machine.axis("X").client
        assert client.device_name() == "X AXIS"
        machine.configure()
        status = client.status()
        assert (status.enabled, status.queued, status.fault) == (False, 0, 0)
        assert machine.ping() == {"X": (0, 1000)}
        settings = world.device("X").settings
        assert settings.diagnostics_interval == 0
        assert dict(settings.debug_flags) == {1: 1}, "the marker's flag is back to 0"
        client.transport.sleep(0.05)
        assert client.transport.poll_lines() == [], "nothing stale is left, no diagnostics"
