"""An operator at a bench, in real time: ``usbmotion run`` twice on the same served devices,
Ctrl-C during homing and mid-program, SIGTERM. Each run leaves the machine stopped along its
deceleration, the servos disabled without a fault latched, and a report that says why.

The devices are ``usbmotion sim --pty 3`` in another process; each host is the real
``usbmotion`` entry point in its own process (``bench.host``), which logs its writes with a
clock the test shares, so the test knows when homing began (its first call 38, a velocity
ramp) or the program did (call 31 arms the synchronised start).
"""

from __future__ import annotations

import json
import signal
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from usbmotion.host.config import load_config
from usbmotion.host.machine import Machine
from usbmotion.protocol import FaultCode

from .bench import bench_machine, logged_writes, served
from .bench import host as start_host

WATCHDOG_MS = 1250
LINE = "G21 G90\nG1 X150 F1200\nM2\n"
"""7.5 s at 20 mm/s, X's fastest."""
START_S = 30.0


def _wait_for(log: Path, what: Callable[[str], bool], process_alive: Callable[[], bool],
              *, timeout_s: float = START_S) -> float:
    """Until the host logs a write whose first bytes satisfy ``what``; its time."""
    deadline = time.monotonic() + timeout_s
    while True:
        for stamp, _, first in logged_writes(log):
            if what(first):
                return stamp
        assert process_alive(), "the host ended first"
        assert time.monotonic() < deadline, "the host never got there"
        time.sleep(0.01)


def _check_left_clean(machine_file: Path) -> dict[str, int]:
    """Every servo disabled, no fault latched, every queue empty; axis -> actual counts."""
    config = load_config(machine_file)
    with Machine.connect(config) as machine:
        where = {}
        for name, status in machine.status().items():
            assert not status.enabled, f"{name}: servo disabled at the end"
            assert status.fault == FaultCode.NONE, f"{name}: no fault latched ({status})"
            assert status.queued == 0
            where[name] = status.actual_counts
    return where


def _run(log: Path, *args: str) -> tuple[int, str, str]:
    process = start_host(log, *args)
    out, err = process.communicate(timeout=120)
    return process.returncode, out, err


@pytest.mark.realtime
def test_two_runs_in_a_row_on_the_same_served_devices_both_succeed(tmp_path: Path) -> None:
    program = tmp_path / "step.ngc"
    program.write_text("G21 G91\nG1 X4 Y3 Z-2 F900\nG90 G53 G0 Z0\nM2\n")  # up to the top
    with served(tmp_path / "flash") as paths:
        machine_file = bench_machine(tmp_path, paths, watchdog_ms=WATCHDOG_MS)
        reports = []
        for index in range(2):
            report_path = tmp_path / f"r{index}.json"
            code, out, err = _run(tmp_path / f"w{index}.log", "run", str(program), "--machine",
                                  str(machine_file), "--report", str(report_path), "-q",
                                  "--no-plot")
            assert code == 0, out + err
            reports.append(json.loads(report_path.read_text()))
            time.sleep(WATCHDOG_MS / 1000 + 0.2)
            _check_left_clean(machine_file)
        first, second = reports
        assert first["completed"] and second["completed"]
        assert first["homing_time_s"] > 0, "the first run homes the machine"
        assert second["homing_time_s"] == 0, "the second finds it homed"
        assert second["end_position_mm"]["X"] == pytest.approx(8.0, abs=0.02), (
            "the second starts where the first ended")
        assert second["end_position_mm"]["Z"] == pytest.approx(0.0, abs=0.02), (
            "from the top of Z's travel, where the servo settled, to it again")


def _interrupted(tmp_path: Path, signum: int, began: str, after_s: float) -> tuple[
        int, dict[str, Any], str]:
    """Run LINE on served devices and send ``signum`` ``after_s`` after the host first
    writes a line starting ``began``; the exit status, the report, the output. The devices
    are then checked left clean."""
    program = tmp_path / "line.ngc"
    program.write_text(LINE)
    with served(tmp_path / "flash") as paths:
        machine_file = bench_machine(tmp_path, paths, watchdog_ms=WATCHDOG_MS)
        log = tmp_path / "w.log"
        report_path = tmp_path / "r.json"
        process = start_host(log, "run", str(program), "--machine", str(machine_file),
                             "--report", str(report_path), "-q", "--no-plot")
        try:
            at = _wait_for(log, lambda first: first.startswith(began),
                           lambda: process.poll() is None, timeout_s=60)
            time.sleep(max(0.0, at + after_s - time.monotonic()))
            process.send_signal(signum)
            out, err = process.communicate(timeout=60)
        finally:
            if process.poll() is None:
                process.kill()
                process.wait()
        report = json.loads(report_path.read_text())
        _check_left_clean(machine_file)
    return process.returncode, report, out + err


@pytest.mark.realtime
def test_ctrl_c_during_homing_stops_within_100_ms(tmp_path: Path) -> None:
    code, report, output = _interrupted(tmp_path, signal.SIGINT, "38 ", 0.4)
    assert code == 130, output
    assert report["stop_reason"] == "interrupted by the user (while homing)"
    assert not report["completed"]
    assert 0 < report["stop_latency_s"] < 0.1, report["stop_latency_s"]
    assert "every axis at rest" in output
    print(f"Ctrl-C while homing: every axis at rest {report['stop_latency_s'] * 1e3:.0f} ms"
          " after the interrupt")


@pytest.mark.realtime
def test_ctrl_c_mid_run_stops_within_the_planned_deceleration(tmp_path: Path) -> None:
    code, report, output = _interrupted(tmp_path, signal.SIGINT, "31 ", 2.5)
    assert code == 130, output
    assert report["stop_reason"] == "interrupted by the user"
    planned = 20.0**2 / (2 * 500.0)
    assert report["stop_planned_mm"] == pytest.approx(planned, rel=0.05)
    run_on = 20.0 * report["stop_late_s"]  # the host held up: on at speed until it arrived
    assert report["stop_distance_mm"] <= float(report["stop_planned_mm"]) + run_on + 0.05, report
    assert report["stop_distance_mm"] > 0.5 * planned, "a deceleration, not a dead stop"
    assert report["faults"] == []
    assert "STOPPED (interrupted by the user)" in output
    print(f"Ctrl-C mid-run at 20 mm/s: stopped in {report['stop_distance_mm']:.3f} mm against"
          f" v^2/2a = {report['stop_planned_mm']:.3f} mm, at rest"
          f" {float(report['stop_latency_s']) * 1e3:.0f} ms after the interrupt")


@pytest.mark.realtime
def test_sigterm_mid_run_stops_the_same_way_and_exits_143_with_a_report(
        tmp_path: Path) -> None:
    code, report, output = _interrupted(tmp_path, signal.SIGTERM, "31 ", 2.5)
    assert code == 143, output
    assert report["stop_reason"] == "terminated (SIGTERM)"
    run_on = 20.0 * report["stop_late_s"]
    assert report["stop_distance_mm"] <= float(report["stop_planned_mm"]) + run_on + 0.05, report
    assert report["stop_distance_mm"] > 0.5 * float(report["stop_planned_mm"]) + run_on, (
        "a deceleration, not a dead stop", report)


@pytest.mark.realtime
def test_the_console_keeps_an_idle_machine_enabled_past_its_watchdog(tmp_path: Path) -> None:
    """Homed, then left at the prompt for more than twice the watchdog: still enabled, no
    fault (the console feeds the watchdogs while it waits for the operator)."""
    import subprocess  # noqa: PLC0415
    import sys  # noqa: PLC0415

    with served(tmp_path / "flash") as paths:
        machine_file = bench_machine(tmp_path, paths, watchdog_ms=WATCHDOG_MS)
        console = subprocess.Popen(
            [sys.executable, "-m", "usbmotion", "console", "--machine", str(machine_file)],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            assert console.stdin is not None and console.stdout is not None
            console.stdin.write("$r\n")
            console.stdin.flush()
            while "homed in" not in (line := console.stdout.readline()):
                assert line, "the console ended before homing"
            time.sleep(2.5 * WATCHDOG_MS / 1000)
            console.stdin.write("?\n$q\n")
            console.stdin.flush()
            out, err = console.communicate(timeout=60)
        finally:
            if console.poll() is None:
                console.kill()
                console.wait()
        assert console.returncode == 0, out + err
        axes = [line for line in out.splitlines() if line[:2] in ("X:", "Y:", "Z:")]
        assert len(axes) == 3, out
        for line in axes:
            assert "enabled" in line and "fault none" in line, line
        _check_left_clean(machine_file)
