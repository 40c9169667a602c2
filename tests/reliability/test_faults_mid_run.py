"""Faults while a program runs: a stalled motor and a limit switch.

The device trips on the servo tick the fault happens; the host sees it at its next fault
check (every ``FAULT_CHECK_S`` of program time) and stops every other axis along the path
at its planned deceleration (call 50 replaces what each has queued). Each test measures both
in device ticks: the fault tick from the device (call 30), and the tick on which each other
axis received its ``50`` (watched on the simulated devices). The report must name the axis,
the fault, the time and the program line.

``tests/test_job.py`` shows a following-error fault through ``usbmotion run``; here the load
is raised above the motor's stall torque on the device (a machine file refuses a motor that
cannot move its own load) and the trip is checked to the tick. A switch cannot be reached on
a homed machine (soft limits refuse the program before anything moves), so the limit-switch
fault runs an unhomed machine, whose devices count from where they powered up.
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
from usbmotion.host.config import MachineConfig, load_config
from usbmotion.motion.sampler import sample_plan
from usbmotion.protocol import FaultCode
from usbmotion.session import RunReport, plan_gcode
from usbmotion.session.watch import FAULT_CHECK_S
from usbmotion.sim.machine import connect_session

STALL_PROGRAM = "G21 G90\nG1 X50 F600\nG1 Y50\nM2\n"
LIMIT_PROGRAM = "G21 G90\nG1 X10 Y10 F1200\nG1 X250 Y60\nG1 X0 Y0\nM2\n"
"""Line 3 drives X to 250 mm on an axis whose travel ends at 200 mm."""


@dataclass
class Outcome:
    """What a run left: the report, each device's end state, and when each was stopped."""

    report: RunReport
    start_tick: int
    devices: dict[str, Device]
    stopped_at: dict[str, list[int]]
    """Device clock at every ``50`` (a stop replacing the queue) the axis received."""

    def first_stop_after(self, axis: str, tick: int) -> int:
        return min(t for t in self.stopped_at[axis] if t >= tick)


def _watch_stops(device: Device, ticks: list[int]) -> Callable[[bytes], None]:
    feed = device.feed

    def watched(data: bytes) -> None:
        if any(line.startswith(b"50 ") for line in bytes(data).split(b"\n")):
            ticks.append(device.clock)
        feed(data)

    return watched


def _run(config: MachineConfig, text: str, *, home: bool,
         load_mnm: float | None = None) -> Outcome:
    with connect_session(config) as session:
        machine = session.machine
        assert machine.world is not None
        devices: dict[str, Device] = {}
        stopped: dict[str, list[int]] = {}
        for name in machine.axes:
            device = machine.world.device(name)
            assert isinstance(device, Device)
            devices[name] = device
            stopped[name] = []
            device.feed = _watch_stops(device, stopped[name])  # type: ignore[method-assign]
        if load_mnm is not None:
            machine.axis("X").client.set_sim_value(33, load_mnm, label="load_torque_mnm")
        homing_s = session.home() if home else 0.0
        prepared = session.prepare("fault.ngc", text=text, unhomed=not home)
        report, trace = session.run(prepared, homing_s=homing_s)
        session.shutdown()
    return Outcome(report, trace.start_tick, devices, stopped)


def _setpoints(config: MachineConfig, text: str, *, start_mm: tuple[float, float, float]
               ) -> np.ndarray:
    _, plan = plan_gcode(config, text, start_mm=start_mm)
    scale = [config.axis(n).counts_per_mm for n in "XYZ"]
    return sample_plan(plan, period_s=config.motion_period_s, counts_per_mm=scale)


def _check_every_axis_stopped(outcome: Outcome, fault_tick: int, tick_s: float) -> float:
    """Every servo off and every queue empty at the end; the others were stopped along the
    path at the host's next check; returns the slowest, seconds."""
    slowest = 0.0
    for name, device in outcome.devices.items():
        state = device.state
        assert state.enable == 0, f"{name} is disabled at the end"
        assert state.queued == 0, f"{name}'s queue is empty"
        assert state.output_mv == 0
        if state.fault == FaultCode.NONE:
            stop = outcome.first_stop_after(name, fault_tick)
            slowest = max(slowest, (stop - fault_tick) * tick_s)
    assert slowest <= FAULT_CHECK_S + 0.01, "the host stops the others at its next check"
    return slowest


def test_a_stalled_motor_trips_on_the_first_tick_beyond_the_following_error_limit() -> None:
    base = load_config(default_machine())
    sim = base.axis("X").sim
    assert sim is not None
    stall_mnm = sim.torque_constant_mnm_per_a * sim.source_voltage_v / sim.winding_resistance_ohm
    load_mnm = round(1.1 * stall_mnm)
    config = base
    limit = config.axis("X").following_error_limit_counts
    assert limit > 0
    setpoints = _setpoints(config, STALL_PROGRAM, start_mm=(0.0, 0.0, 0.0))
    first_over = int(np.argmax(setpoints[:, 0] > limit))

    outcome = _run(config, STALL_PROGRAM, home=False, load_mnm=load_mnm)
    x = outcome.devices["X"].state
    tick_s = config.servo_period_s
    assert (x.fault, x.enable) == (FaultCode.FOLLOWING_ERROR, 0)
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
          f" (limit {limit}); reported at {fault.time_s:.3f} s; Y and Z stopped along the"
          f" path {slowest * 1e3:.0f} ms later")


def _switch_mm(config: MachineConfig, axis: str) -> float:
    """Where the axis's upper switch closes, in mm of the unhomed device's counts (0 where
    it powered up)."""
    settings = config.axis(axis)
    travel = settings.sim_travel_counts
    assert travel is not None
    return travel[1] / settings.counts_per_mm


def test_a_limit_switch_mid_run_stops_every_axis_and_says_where() -> None:
    config = load_config(default_machine())
    x_axis = config.axis("X")
    assert _switch_mm(config, "X") < 250, "line 3 goes past the switch"
    switch_counts = x_axis.scale.to_counts(_switch_mm(config, "X"))
    setpoints = _setpoints(config, LIMIT_PROGRAM, start_mm=(0.0, 0.0, 0.0))
    reaches = int(np.argmax(setpoints[:, 0] >= switch_counts))
    tick_s = config.servo_period_s

    outcome = _run(config, LIMIT_PROGRAM, home=False)
    x = outcome.devices["X"].state
    assert (x.fault, x.enable) == (FaultCode.LIMIT_SWITCH, 0)
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
        assert outcome.devices[name].state.fault == FaultCode.NONE, "stopped by the host"
    print(f"limit: X tripped at {fault_s:.3f} s (reaches the switch at {planned_s:.3f} s),"
          f" coasted {coast_counts} counts; reported at {fault.time_s:.3f} s; Y and Z stopped"
          f" along the path {slowest * 1e3:.0f} ms later")


def test_usbmotion_run_exits_1_and_names_the_switch(tmp_path: Path) -> None:
    program = tmp_path / "far.ngc"
    program.write_text(LIMIT_PROGRAM)
    report_path = tmp_path / "report.json"
    done = subprocess.run(
        [sys.executable, "-m", "usbmotion", "run", str(program), "--report", str(report_path),
         "--no-home", "-q", "--no-plot"],
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
    assert "STOPPED (fault: axis X limit switch) at program line 3" in done.stdout
    assert "Traceback" not in done.stderr
