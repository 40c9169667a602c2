"""A bench for real-time tests: simulated devices served on pseudo-terminals by a
``usbmotion sim --pty 3`` process, a machine file pointing at them, and the real
``usbmotion`` entry point run as a separate host process that logs every write it makes to
a device with its ``time.monotonic()`` (a clock every process shares)."""

from __future__ import annotations

import contextlib
import re
import signal
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

from usbmotion.cli.run import default_machine
from usbmotion.host.config import load_config
from usbmotion.host.device import DeviceClient

NAMES = ("X AXIS", "Y AXIS", "Z AXIS")

LOGGING_HOST = r"""
import os, sys, time
log = os.open(sys.argv[1], os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)
from usbmotion.host import transport
write = transport.LineTransport.write
def logged(self, data):
    write(self, data)
    first = data.split(b"\n", 1)[0][:12].decode("ascii", "replace")
    os.write(log, f"{time.monotonic():.6f}|{self.label}|{first}\n".encode())
transport.LineTransport.write = logged
period = os.environ.get("USBMOTION_TEST_DIAGNOSTICS_S")
if period:
    from usbmotion.session import watch as run
    run.DIAGNOSTICS_PERIOD_S = float(period)
from usbmotion.cli.main import main
sys.argv = ["usbmotion", *sys.argv[2:]]
main()
"""
"""``python -c LOGGING_HOST LOG ARGS...`` runs ``usbmotion ARGS...``, logging each write as
``monotonic|device label|first 12 bytes``; ``USBMOTION_TEST_DIAGNOSTICS_S`` sets the
period of the diagnostics lines the run asks for."""


@contextlib.contextmanager
def served(flash_dir: Path) -> Iterator[dict[str, str]]:
    """``usbmotion sim --pty 3`` in a subprocess; yields device name -> terminal path once
    every device answers (the server's first servo tick may compile the servo kernel, which
    holds it for seconds: a host connecting meanwhile would time out)."""
    names = [arg for name in NAMES for arg in ("--name", name)]
    server = subprocess.Popen(
        [sys.executable, "-m", "usbmotion", "sim", "--pty", "3", "--flash-dir", str(flash_dir),
         *names],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    try:
        assert server.stdout is not None
        paths: dict[str, str] = {}
        for _ in NAMES:
            name, path = server.stdout.readline().rstrip("\n").rsplit(" ", 1)
            paths[name] = path
        assert sorted(paths) == sorted(NAMES), paths
        for name, path in paths.items():
            with DeviceClient.open(path, timeout_s=60, name=name) as client:
                client.resynchronise()
        yield paths
    finally:
        server.send_signal(signal.SIGTERM)
        try:
            server.wait(timeout=10)
        except subprocess.TimeoutExpired:
            server.kill()
            server.wait()


def bench_machine(folder: Path, paths: dict[str, str], *, watchdog_ms: int) -> Path:
    """The default machine with each axis on its terminal, carriages 5 mm inside the travel
    end they home to (X, Y above their lower switches, Z below its upper one), a quicker
    slow locate (2 mm/s after backing off 0.5 mm: still under a count a tick, so the latched
    edge is the switch's very count), so homing takes seconds in real time, and this
    watchdog."""
    text = default_machine().read_text()
    for letter in "XYZ":
        text = text.replace(f'url = "sim://{letter}"', f'url = "{paths[letter + " AXIS"]}"')
    text, count = re.subn(r"start_mm = 100\.0", "start_mm = 5.0", text)
    assert count == 2, "X and Y power up 5 mm above their lower switches"
    text, count = re.subn(r"start_mm = -50\.0", "start_mm = -5.0", text)
    assert count == 1, "Z powers up 5 mm below its upper switch"
    text, count = re.subn(r"slow_speed_mm_s = 1\.0, backoff_mm = 1\.0",
                          "slow_speed_mm_s = 2.0, backoff_mm = 0.5", text)
    assert count == 3, "every axis locates at 2 mm/s (under a count a tick) after 0.5 mm"
    text, count = re.subn(r"(?m)^watchdog_ms = \d+", f"watchdog_ms = {watchdog_ms}", text)
    assert count == 1
    path = folder / "bench.toml"
    path.write_text(text)
    config = load_config(path)
    assert config.watchdog_ms == watchdog_ms
    assert all(axis.sim is not None for axis in config.axes), "the file sets up the motors"
    return path


def logged_writes(log: Path) -> list[tuple[float, str, str]]:
    """(monotonic time, device label, first bytes) of every write the host logged."""
    if not log.exists():
        return []
    rows = []
    for line in log.read_text().splitlines():
        stamp, label, first = line.split("|", 2)
        rows.append((float(stamp), label, first))
    return rows


def host(log: Path, *args: str, diagnostics_s: float | None = None) -> subprocess.Popen[str]:
    """Start ``usbmotion ARGS`` as a logging host process."""
    import os  # noqa: PLC0415

    env = dict(os.environ)
    if diagnostics_s is not None:
        env["USBMOTION_TEST_DIAGNOSTICS_S"] = str(diagnostics_s)
    return subprocess.Popen([sys.executable, "-c", LOGGING_HOST, str(log), *args],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
