"""Faults while a program runs: a stalled motor and a limit switch.

The device trips on the servo tick the fault happens; the host sees it at its next fault
check (every ``FAULT_CHECK_S`` of program time) and stops every other axis. Each test
measures both in device ticks: the fault tick from the device (call 30), and the tick on
which each other axis received its ``3 0`` (watched on the simulated devices). The report
must name the axis, the fault, the time and the program line.

``tests/test_job.py`` shows a following-error fault through ``usbmotion run`` with a
heavy load; here the load is above the motor's stall torque and the trip is checked to
the tick, and the limit-switch fault gets its own command-line run.
"""

from __future__ import annotations

import json
import subprocess
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from usbmotion.cli.run import default_machine
from usbmotion.device import Device
from usbmotion.device.motor import MICRO, MotorParams
from usbmotion.host.config import MachineConfig, load_config, parse_config
from usbmotion.host.machine import Machine
from usbmotion.job import FAULT_CHECK_S, RunReport, plan_program, run_program
from usbmotion.motion.gcode import parse_gcode
from usbmotion.motion.sampler import sample_plan
from usbmotion.protocol.table import Fault

STALL_PROGRAM = "G21 G90\nG1 X50 F600\nG1 Y50\nM2\n"
LIMIT_PROGRAM = "G21 G90\nG1 X10 Y10 F1200\nG1 X250 Y60\nG1 X0 Y0\nM2\n"
"""Line 3 drives X to 250 mm on an axis whose travel ends at 200 mm."""


@dataclass
class Outcome:
    """What a run left: the report, each device's end state, and when each was disabled."""

    report: RunReport
    start_tick: int
    devices: dict[str, Device]
    disabled_at: dict[str, list[int]]
    """Device clock at every ``3 0`` the axis received."""

    def first_disable_after(self, axis: str, tick: int) -> int:
        return min(t for t in self.disabled_at[axis] if t >= tick)


def _watch_disables(device: Device, ticks: list[int]) -> Callable[[bytes], None]:
    feed = device.feed

    def watched(data: bytes) -> None:
        if any(line.strip() == b"3 0" for line in bytes(data).split(b"\n")):
            ticks.append(device.clock)
        feed(data)

    return watched


def _run(config: MachineConfig, text: str, *, home: bool) -> Outcome:
    program = parse_gcode(text, file="fault.ngc")
    plan = plan_program(program, config)
    with Machine.connect(config) as machine:
        assert machine.world is not None
        devices: dict[str, Device] = {}
        disabled: dict[str, list[int]] = {}
        for name in machine.axes:
            device = machine.world.device(name)
            assert isinstance(device, Device)
            devices[name] = device
            disabled[name] = []
            device.feed = _watch_disables(device, disabled[name])  # type: ignore[method-assign]
        report, trace = run_program(machine, program, plan, home=home)
    return Outcome(report, trace.start_tick, devices, disabled)


def _setpoints(config: MachineConfig, text: str) -> np.ndarray:
    plan = plan_program(parse_gcode(text, file="fault.ngc"), config)
    scale = [config.axis(n).counts_per_mm for n in "XYZ"]
    return sample_plan(plan, period_s=config.motion_period_s, counts_per_mm=scale)


def _check_every_axis_stopped(outcome: Outcome, fault_tick: int, tick_s: float) -> float:
    """Every servo off and every queue empty; returns the slowest host stop, seconds."""
    slowest = 0.0
    for name, device in outcome.devices.items():
        state = device.state
        assert state.enable == 0, f"{name} is disabled"
        assert state.queued == 0, f"{name}'s queue is cleared"
        assert state.output_mv == 0
        if state.fault == Fault.NONE:
            stop = outcome.first_disable_after(name, fault_tick)
            slowest = max(slowest, (stop - fault_tick) * tick_s)
    assert slowest <= FAULT_CHECK_S + 0.01, "the host stops the others at its next check"
    return slowest


def test_a_stalled_motor_trips_on_the_first_tick_beyond_the_following_error_limit() -> None:
    base = load_config(default_machine())
    sim = base.axis("X").sim
    assert sim is not None
    stall_mnm = sim.torque_constant_mnm_per_a * sim.source_voltage_v / sim.winding_resistance_ohm
    load_mnm = round(1.1 * stall_mnm)
    text = default_machine().read_text().replace(
        "sim = { start_mm = 100.0 }", f"sim = {{ start_mm = 100.0, load_torque_mnm = {load_mnm} }}",
        1,
    )
    config = parse_config(text, path="stalled.toml")
    assert config.axis("X").sim is not None and config.axis("Y").sim == sim
    limit = config.axis("X").following_error_limit_counts
    assert limit > 0
    setpoints = _setpoints(config, STALL_PROGRAM)
    first_over = int(np.argmax(setpoints[:, 0] > limit))

    outcome = _run(config, STALL_PROGRAM, home=False)
    x = outcome.devices["X"].state
    tick_s = config.servo_period_s
    assert (x.fault, x.enable) == (Fault.FOLLOWING_ERROR, 0)
    assert x.fault_tick == outcome.start_tick + first_over + 1, "the tick the error passed"
    assert limit < x.desired - x.actual <= limit + int(np.max(np.diff(setpoints[:, 0])))
    assert abs(x.shaft_micro_counts) < MICRO, "a load above stall: the shaft never turned"

    report = outcome.report
    assert not report.completed and report.stopped_at_line == 2
    (fault,) = report.faults
    assert (fault.axis, fault.fault, fault.line) == ("X", "following error", 2)
    fault_s = (x.fault_tick - outcome.start_tick) * tick_s
    assert fault_s <= fault.time_s <= fault_s + FAULT_CHECK_S + 2 * tick_s
    slowest = _check_every_axis_stopped(outcome, x.fault_tick, tick_s)
    print(f"stall: X tripped at {fault_s:.3f} s, {x.desired - x.actual} counts behind"
          f" (limit {limit}); reported at {fault.time_s:.3f} s; Y and Z off {slowest * 1e3:.0f}"
          " ms later")


def _switch_mm(config: MachineConfig, axis: str) -> float:
    """Where the axis's upper switch closes, in machine mm once homed."""
    settings = config.axis(axis)
    travel = settings.sim_travel_counts
    assert travel is not None and settings.sim is not None
    return settings.sim.start_mm + travel[1] / settings.counts_per_mm


def test_a_limit_switch_mid_run_stops_every_axis_and_says_where() -> None:
    config = load_config(default_machine())
    x_axis = config.axis("X")
    assert _switch_mm(config, "X") < 250, "line 3 goes past the switch"
    switch_counts = x_axis.scale.to_counts(_switch_mm(config, "X"))
    setpoints = _setpoints(config, LIMIT_PROGRAM)
    reaches = int(np.argmax(setpoints[:, 0] >= switch_counts))
    tick_s = config.servo_period_s

    outcome = _run(config, LIMIT_PROGRAM, home=True)
    x = outcome.devices["X"].state
    assert (x.fault, x.enable) == (Fault.LIMIT_SWITCH, 0)
    assert x.limits == 2, "X rests on its upper switch"
    planned_s = reaches * tick_s
    fault_s = (x.fault_tick - outcome.start_tick) * tick_s
    assert abs(fault_s - planned_s) <= 0.01, "the switch trips as the carriage reaches it"
    upper = MotorParams().overtravel_counts
    travel = x_axis.sim_travel_counts
    assert travel is not None
    coast_counts = x.shaft_micro_counts // MICRO - travel[1]
    assert 0 <= coast_counts < upper, "X coasts to rest before the hard stop"

    report = outcome.report
    assert not report.completed and report.stopped_at_line == 3
    (fault,) = report.faults
    assert (fault.axis, fault.fault, fault.line) == ("X", "limit switch", 3)
    assert fault_s <= fault.time_s <= fault_s + FAULT_CHECK_S + 2 * tick_s
    slowest = _check_every_axis_stopped(outcome, x.fault_tick, tick_s)
    for name in ("Y", "Z"):
        assert outcome.devices[name].state.fault == Fault.NONE, "stopped by the host"
    print(f"limit: X tripped at {fault_s:.3f} s (reaches the switch at {planned_s:.3f} s),"
          f" coasted {coast_counts} counts; reported at {fault.time_s:.3f} s; Y and Z off"
          f" {slowest * 1e3:.0f} ms later")


def test_usbmotion_run_exits_1_and_names_the_switch(tmp_path: Path) -> None:
    program = tmp_path / "far.ngc"
    program.write_text(LIMIT_PROGRAM)
    report_path = tmp_path / "report.json"
    done = subprocess.run(
        [sys.executable, "-m", "usbmotion", "run", str(program), "--report", str(report_path),
         "-q", "--no-plot"],
        capture_output=True, text=True, timeout=240, check=False,
    )
    assert done.returncode == 1, done.stdout + done.stderr
    report = json.loads(report_path.read_text())
    assert report["completed"] is False
    assert [(f["axis"], f["fault"], f["line"]) for f in report["faults"]] == [
        ("X", "limit switch", 3)]
    assert report["faults"][0]["time_s"] > 0
    assert report["stopped_at_line"] == 3
    assert "axis X: limit switch at" in done.stdout
    assert "STOPPED at program line 3" in done.stdout
    assert "Traceback" not in done.stderr
