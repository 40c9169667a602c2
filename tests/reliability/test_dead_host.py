"""A dead host: ``usbmotion run`` is killed (SIGKILL) mid-program; each device's watchdog
disables its servo; a new host takes the machine over while the devices still print the
diagnostics the dead host asked for: it reports each fault, clears it, knows the position
may be lost (a fault disabled the servo) and homes again, zeroing on the switch edge each
device latched, exact to the count.

Everything runs in real time as it would on a bench: ``usbmotion sim --pty 3`` serves three
devices on pseudo-terminals, the machine file points each axis at its terminal, and the
host is a separate process. The host process is the real ``usbmotion run`` entry point with
two additions: every write to a device is logged with its ``time.monotonic()`` (a clock all
processes share), so the test knows when each device last heard its host; and it asks for a
diagnostics line every servo tick (as ``usbmotion tune`` does), so that by the time the new
host connects each terminal is full and the server writes lines cut where the terminal had
room: the new host's first bytes are most likely the tail of a line.
"""

from __future__ import annotations

import signal
import time
from pathlib import Path

import pytest

from usbmotion.host.config import load_config
from usbmotion.host.device import Status
from usbmotion.protocol import FaultCode
from usbmotion.session import MachineSession, home_position_mm

from .bench import bench_machine, served
from .bench import host as start_host

WATCHDOG_MS = 1250
"""The shortest watchdog the default machine allows: a full queue (1000 x 1 ms) + 250 ms."""
WATCHDOG_TOLERANCE_MS = 25.0
"""How far the measured disable may be from the watchdog: the serving loop polls every
millisecond and a loaded machine delays it; measured 1250.0..1251.0 ms when idle."""

PROGRAM = "G21 G90\nG1 X20 Y10 Z-5 F300\nG1 X0 Y0 Z0\nM2\n"
"""About 9 s of motion; the host is killed about 1.5 s into it."""


def _last_writes(log: Path) -> dict[str, float]:
    """Device label -> monotonic time of the host's last write to it."""
    last: dict[str, float] = {}
    for line in log.read_text().splitlines():
        stamp, label, _ = line.split("|", 2)
        last[label] = float(stamp)
    return last


def _streaming(log: Path) -> bool:
    return log.exists() and any(
        line.split("|", 2)[2].startswith("1 ") for line in log.read_text().splitlines()
    )


def _diagnostics_left_on(log: Path) -> dict[str, int]:
    """Device label -> the diagnostics interval (call 21) the host set last, if not 0."""
    interval: dict[str, int] = {}
    for line in log.read_text().splitlines():
        _, label, first = line.split("|", 2)
        if first.startswith("21 "):
            interval[label] = int(first.split()[1])
    return {label: ticks for label, ticks in interval.items() if ticks}


@pytest.mark.realtime
def test_a_killed_host_leaves_every_servo_disabled_by_its_watchdog(tmp_path: Path) -> None:
    program = tmp_path / "move.ngc"
    program.write_text(PROGRAM)
    log = tmp_path / "writes.log"
    with served(tmp_path / "flash") as paths:
        machine_file = bench_machine(tmp_path, paths, watchdog_ms=WATCHDOG_MS)
        host = start_host(log, "run", str(program), "--machine", str(machine_file), "--no-home",
                          "-q", "--no-plot", diagnostics_s=0.001)
        try:
            deadline = time.monotonic() + 30
            while not _streaming(log):
                assert host.poll() is None, host.communicate()
                assert time.monotonic() < deadline, "the host never started streaming"
                time.sleep(0.01)
            time.sleep(1.5)
            host.send_signal(signal.SIGKILL)
            killed = time.monotonic()
            assert host.wait(timeout=10) == -signal.SIGKILL
        finally:
            if host.poll() is None:
                host.kill()
                host.wait()
        last = _last_writes(log)
        assert len(last) == 3 and all(killed - t < 1.5 for t in last.values())
        left_on = _diagnostics_left_on(log)
        assert sorted(left_on) == sorted(last) and set(left_on.values()) == {1}, left_on
        time.sleep(WATCHDOG_MS / 1000 + 0.5)

        config = load_config(machine_file)
        delays_ms: dict[str, float] = {}
        started = time.monotonic()
        with MachineSession.connect(config) as session:
            connect_ms = (time.monotonic() - started) * 1000
            machine = session.machine
            assert not session.is_homed, "a fault disabled every servo: position may be lost"
            assert sorted(session.faults_found) == ["X", "Y", "Z"]
            assert len([n for n in session.notices if "watchdog" in n]) == 3, session.notices
            for axis in config.axes:
                client = machine.axis(axis.name).client
                name = axis.device
                assert name is not None
                code, fault_tick = session.faults_found[axis.name]
                assert code == FaultCode.WATCHDOG
                status: Status = client.status()
                assert not status.enabled and status.fault == FaultCode.NONE, "cleared"
                assert status.queued == 0
                before = time.monotonic()
                clock = client.clock()
                after = time.monotonic()
                tick_s = client.servo_interval_us() * 1e-6
                fault_at = (before + after) / 2 - (clock - fault_tick) * tick_s
                label = next(label for label in last if name in label)
                delays_ms[axis.name] = (fault_at - last[label]) * 1000
                target_mm = {"X": 20.0, "Y": 10.0, "Z": -5.0}[axis.name]
                moved_mm = axis.scale.to_mm(status.actual_counts)
                assert 0 < moved_mm / target_mm < 1, "mid-program"
            for letter, delay_ms in delays_ms.items():
                assert abs(delay_ms - WATCHDOG_MS) <= WATCHDOG_TOLERANCE_MS, (letter, delays_ms)
            session.home()
            homing_s = time.monotonic() - started
            for letter, status in machine.status().items():
                axis = config.axis(letter)
                travel = axis.sim_travel_counts
                assert travel is not None
                assert status.enabled and status.fault == FaultCode.NONE
                zero = session.zeroes[letter]
                switch = travel[0] if axis.homing.direction < 0 else travel[1]  # Z: above
                assert zero.edge_counts == switch, (
                    f"{letter}: the device latched the switch's closing edge at its very count"
                    f" (counts from power-up, the dead host never homed): {zero}")
                assert status.desired_counts == axis.scale.to_counts(home_position_mm(axis))
                assert not (status.lower_limit or status.upper_limit), (
                    f"{letter} pulled off its switch")
            session.shutdown()
        assert homing_s < 15
    figures = ", ".join(f"{k} {v:.1f} ms" for k, v in delays_ms.items())
    print(f"watchdog disable after the last command: {figures}; connected over the"
          f" diagnostics in {connect_ms:.0f} ms; homed again in {homing_s:.1f} s")
