"""Emulated RP2040s served in real time (``FirmwareServer``, ``usbmotion sim --firmware``) and
in a virtual-time world (``FirmwareSimDevice``)."""

from __future__ import annotations

import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from usbmotion.errors import DeviceError
from usbmotion.sim.firmware import (
    FirmwareServer,
    FirmwareSimDevice,
    OutputChunk,
    Span,
    default_uf2,
    read_recording,
)

from .emulated import require_emulator


@pytest.fixture(scope="module")
def uf2() -> Path:
    require_emulator()
    return default_uf2()


def _ask(link: socket.socket, line: bytes) -> bytes:
    link.sendall(line)
    received = b""
    deadline = time.monotonic() + 10
    while not received.endswith(b"\n") and time.monotonic() < deadline:
        received += link.recv(4096)
    return received


def test_names_are_written_once_kept_in_flash_and_sessions_recorded(
        uf2: Path, tmp_path: Path) -> None:
    flash, records = tmp_path / "flash", tmp_path / "records"
    with FirmwareServer(uf2, 2, names=["X AXIS"], flash_dir=flash, record_dir=records) as srv:
        assert [e.name for e in srv.endpoints] == ["X AXIS", "GENERIC USB MOTION DEVICE"]
        with socket.create_connection((srv.host, srv.endpoints[0].port)) as link:
            assert _ask(link, b"18 -1\n") == b"DEVICE_NAME X AXIS\n"
            assert _ask(link, b"2 -1\n") == b"MOTION_QUEUE 0 1000\n"
        assert srv.stopped() == ""
    assert sorted(p.name for p in flash.iterdir()) == ["device-1.flash", "x-axis.flash"]
    first = read_recording(records / "x-axis.rec")
    assert b"".join(data for _, data in first) == (
        b"18 -1\n18 6 88 32 65 88 73 83\n18 -1\n" b"18 -1\n2 -1\n")
    ticks = [tick for tick, _ in first]
    assert ticks == sorted(ticks) and ticks[-1] > ticks[0]
    # again on the same flash: the name is there, so only asked
    with FirmwareServer(uf2, 1, names=["X AXIS"], flash_dir=flash, record_dir=records) as srv:
        assert srv.endpoints[0].name == "X AXIS"
    assert [data for _, data in read_recording(records / "x-axis.rec")] == [b"18 -1\n"]


def test_bad_arguments_and_recordings_are_refused(uf2: Path, tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="2 names for 1 devices"):
        FirmwareServer(uf2, 1, names=["A", "B"])
    with pytest.raises(ValueError, match="printable ASCII"):
        FirmwareServer(uf2, 1, names=["X" * 26])
    bad = tmp_path / "bad.rec"
    bad.write_text("5 3132\n4 33\n")
    with pytest.raises(ValueError, match="out of order"):
        read_recording(bad)
    bad.write_text("5 zz\n")
    with pytest.raises(ValueError, match="is not `TICK HEX`"):
        read_recording(bad)
    done = subprocess.run([sys.executable, "-m", "usbmotion", "sim", "--pty", "1", "--record",
                           str(tmp_path)], capture_output=True, text=True, check=False)
    assert done.returncode == 2 and "--record needs --firmware" in done.stderr


def test_the_command_line_serves_emulated_devices_on_tcp(uf2: Path, tmp_path: Path) -> None:
    server = subprocess.Popen(
        [sys.executable, "-m", "usbmotion", "sim", "--firmware", str(uf2), "--tcp", "0",
         "--count", "2", "--name", "A", "--flash-dir", str(tmp_path)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert server.stdout is not None
        lines = [server.stdout.readline().split() for _ in range(2)]
        assert [line[0] for line in lines] == ["A", "GENERIC"]
        host, port = lines[0][-1].removeprefix("socket://").rsplit(":", 1)
        with socket.create_connection((host, int(port))) as link:
            assert _ask(link, b"18 -1\n") == b"DEVICE_NAME A\n"
    finally:
        server.terminate()
        out, _ = server.communicate(timeout=30)
    assert out.endswith("stopped\n")


def test_a_world_device_that_parts_from_the_python_device_is_caught(uf2: Path) -> None:
    device = FirmwareSimDevice(uf2, name="X AXIS")
    try:
        device.feed(b"20 -1\n21 5\n3 1\n0 40\n")
        device.run(12)
        assert [data for _, data in device.take_timed_output()][:1] == [
            b"STATUS 0 0 0 0 0 0 1 0 0\n"]
        assert device.lines_compared == 3
        real = device.chip.run

        def one_count_off(ticks: int) -> Span:
            span = real(ticks)
            chunks = [OutputChunk(c.tick, c.data.replace(b"D 15 40 ", b"D 15 41 "))
                      for c in span.output]
            return Span(span.tick, tuple(chunks), span.busy_cycles, span.emulated_ns)

        device.chip.run = one_count_off  # type: ignore[method-assign]
        device.run(5)
        with pytest.raises(DeviceError, match="parted from the Python device at tick 15"):
            device.take_timed_output()
    finally:
        device.close()
