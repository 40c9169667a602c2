"""``usbmotion grbl`` end to end, in real time: the command in its own process on the
simulated machine, a client on its pseudo-terminal's link speaking grbl 1.1 as a sender
does (banner, alarm until homed, ``$H``, streamed lines, ``G4`` answered after the motion,
``?`` with the encoders' positions and the ``FE:`` field, SIGTERM)."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import serial

from usbmotion.cli.run import default_machine

pytestmark = pytest.mark.realtime


def fast_homing_machine(directory: Path) -> Path:
    """The default machine with each axis starting 3 mm from its switch (homing in ~2 s)."""
    text = default_machine().read_text()
    text = re.sub(r"start_mm = [0-9.]+", "start_mm = 3.0", text)
    path = directory / "machine.toml"
    path.write_text(text)
    return path


class _Client:
    def __init__(self, link: Path) -> None:
        self.port = serial.Serial(str(link), 115200, timeout=0.05)
        self.seen = ""

    def send(self, data: bytes) -> None:
        self.port.write(data)

    def until(self, pattern: str, timeout_s: float = 20.0) -> str:
        """Read until ``pattern`` (a regular expression) appears: the match; what came up
        to its end is forgotten."""
        deadline = time.monotonic() + timeout_s
        while True:
            match = re.search(pattern, self.seen)
            if match:
                self.seen = self.seen[match.end():]
                return match.group(0)
            assert time.monotonic() < deadline, f"no {pattern!r} in {self.seen!r}"
            self.seen += self.port.read(4096).decode(errors="replace")

    def status(self) -> str:
        self.send(b"?")
        return self.until(r"<[^>]*>\r\n")

    def close(self) -> None:
        self.port.close()


def test_a_sender_homes_streams_and_waits_on_g4(tmp_path: Path) -> None:
    link = tmp_path / "ttyGRBL"
    process = subprocess.Popen(
        [sys.executable, "-m", "usbmotion", "grbl", "--link", str(link),
         "--machine", str(fast_homing_machine(tmp_path))],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        env={**os.environ, "PYTHONUNBUFFERED": "1"})
    try:
        assert process.stdout is not None
        line = process.stdout.readline()
        assert "grbl 1.1h serving on" in line and link.exists(), line
        client = _Client(link)
        try:
            client.until(r"Grbl 1\.1h \['\$' for help\]\r\n")
            assert client.status().startswith("<Alarm|"), "not homed: alarm"
            client.send(b"G0 X1\n")
            client.until(r"error:9\r\n")
            client.send(b"$H\n")
            client.until(r"ok\r\n", timeout_s=30)
            assert client.status().startswith("<Idle|")
            client.send(b"G21 G90\nG1 X10 Y5 F1200\nG4 P0.1\n")
            client.until(r"ok\r\nok\r\n")
            running = client.status()
            assert running.startswith("<Run|") and "|FE:" in running, running
            started = time.monotonic()
            client.until(r"ok\r\n", timeout_s=30)
            assert time.monotonic() - started > 0.3, "G4 answered only after the motion"
            done = client.status()
            where = re.search(r"MPos:([-0-9.]+),([-0-9.]+),([-0-9.]+)", done)
            assert done.startswith("<Idle|") and where is not None, done
            assert float(where.group(1)) == pytest.approx(10.0, abs=0.02)
            assert float(where.group(2)) == pytest.approx(5.0, abs=0.02)
        finally:
            client.close()
        process.send_signal(signal.SIGTERM)
        assert process.wait(timeout=20) == 0
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
        for stream in (process.stdout, process.stderr):
            if stream is not None:
                stream.close()
