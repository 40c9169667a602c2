"""Stepper axes: a step/direction drive (call 44) on an axis of the machine file.

The file's ``kind = "stepper"`` axes are read and checked (steps per mm, microsteps, the
loop, the driver's timing against the step rate, a simulated stepper's torque against the
limits); connecting sets each device's drive, stepper, timing and simulated stepper; the
demo and a CAM program run on ``examples/stepper.toml``; a load beyond the pull-out torque
loses steps on an open-loop axis (found at the next homing) and is seen on the tick it
happens on the closed-loop one; grbl's ``$100`` is the steps per mm.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from commands import invoke
from stepper_loads import (
    CLOSED_PROGRAM,
    EXAMPLE,
    OPEN_PROGRAM,
    full_steps,
    run_with_load,
    stepper_machine,
)
from usbmotion.device import Device
from usbmotion.device.motor import MICRO
from usbmotion.errors import ConfigError
from usbmotion.grbl.interface import Rejected
from usbmotion.grbl.reports import machine_setting_values
from usbmotion.grbl.session_machine import SessionMachine
from usbmotion.host.config import (
    SimStepperConfig,
    load_config,
    parse_config,
)
from usbmotion.motion.dialects import dialect_named
from usbmotion.protocol import Drive, FaultCode
from usbmotion.session.operator import Operator
from usbmotion.sim.machine import SimulatedMachine, connect_session

ROOT = Path(__file__).resolve().parents[1]
DEMO_1 = ROOT / "src" / "usbmotion" / "data" / "demos" / "1-rounded-square.ngc"
CAM_CORNER = ROOT / "tests" / "programs" / "cam_corner.ngc"

MIXED = """\
name = "mixed"
watchdog_ms = 0

[axes.X]
url = "sim://X"
counts_per_mm = 240
max_velocity_mm_s = 20
max_accel_mm_s2 = 500
travel_mm = [0, 200]
gains = { kp = 0.5, ki = 5.0, kd = 0.002 }

[axes.Z]
url = "sim://Z"
kind = "stepper"
steps_per_mm = 400
max_velocity_mm_s = 20
max_accel_mm_s2 = 500
travel_mm = [-80, 0]
homing = { direction = 1, speed_mm_s = 8 }
"""


# --- the machine file -----------------------------------------------------------------------


def test_the_example_reads_as_stepper_axes() -> None:
    config = load_config(EXAMPLE)
    x, y, z = (config.axis(name) for name in "XYZ")
    for axis in (x, y):
        assert axis.kind == "stepper" and axis.drive is Drive.STEP_OPEN
        assert axis.counts_per_mm == 400.0 and axis.count_words == "microsteps"
        assert axis.gains == axis.velocity_gains and axis.gains.kp == 0.0
    assert z.drive is Drive.STEP_CLOSED and z.stepper is not None
    assert z.stepper.encoder_counts_per_rev == 4000 and z.stepper.microsteps_per_rev == 3200
    assert z.velocity_gains == z.gains, "homing runs the position loop's gains"
    assert isinstance(z.sim, SimStepperConfig) and z.sim.update_interval_dms == 1
    assert z.stepper.steps_per_tick(1000) == 4807


def test_a_machine_mixes_servo_and_stepper_axes() -> None:
    config = parse_config(MIXED)
    assert (config.axis("X").kind, config.axis("Z").kind) == ("servo", "stepper")
    z = config.axis("Z")
    assert z.stepper is not None and (z.stepper.loop, z.stepper.microsteps) == ("open", 16)
    assert isinstance(z.sim, SimStepperConfig), "a sim:// stepper gets the default stepper"


def _refused(text: str) -> str:
    with pytest.raises(ConfigError) as caught:
        parse_config(text)
    return str(caught.value)


@pytest.mark.parametrize(
    ("old", "new", "words"),
    [
        ('kind = "stepper"', 'kind = "stpper"',
         ("axes.Z.kind", "'stpper' is not a kind of axis", "'servo', 'stepper'")),
        ("steps_per_mm = 400", "counts_per_mm = 400",
         ("axes.Z.counts_per_mm", "a servo axis's key", "give steps_per_mm")),
        ("counts_per_mm = 240", "counts_per_mm = 240\nmicrosteps = 16",
         ("axes.X.microsteps", "a stepper axis's key", "kind = 'stepper'")),
        ('kind = "stepper"', 'kind = "stepper"\nvelocity_gains = { kp = 0.1, ki = 0, kd = 0 }',
         ("axes.Z.velocity_gains", "runs its position loop")),
        ('kind = "stepper"', 'kind = "stepper"\ngains = { kp = 0.2, ki = 0, kd = 0 }',
         ("axes.Z.gains", "an open-loop stepper runs no PID")),
        ('kind = "stepper"', 'kind = "stepper"\nloop = "closed"',
         ("axes.Z.encoder_counts_per_rev", "missing required key")),
        ('kind = "stepper"', 'kind = "stepper"\nencoder_counts_per_rev = 4000',
         ("axes.Z.encoder_counts_per_rev", "an open-loop stepper reads no encoder")),
        ('kind = "stepper"', 'kind = "stepper"\nloop = "half"',
         ("axes.Z.loop", "'half' is not a stepper loop", "'open', 'closed'")),
        ('kind = "stepper"', 'kind = "stepper"\nmicrosteps = 512',
         ("axes.Z.microsteps", "512 is out of range", "1..256")),
        ('kind = "stepper"', 'kind = "stepper"\nstep_pulse_ns = 50',
         ("axes.Z.step_pulse_ns", "50 is out of range", "100..1000000")),
        # 100 us pulses: 4 steps a 1 ms tick, 4000 steps/s = 10 mm/s at 400 steps/mm
        ('kind = "stepper"', 'kind = "stepper"\nstep_pulse_ns = 100000',
         ("axes.Z.max_velocity_mm_s", "20.0 mm/s is 8000 microsteps/s", "4 steps a 1000 us",
          "allowed: <= 10 mm/s", "a shorter step_pulse_ns")),
        ('kind = "stepper"', 'kind = "stepper"\nstep_pulse_ns = 600000',
         ("axes.Z.step_pulse_ns", "fits no step in a 1000 us servo tick")),
        ('kind = "stepper"', 'kind = "stepper"\nsim = { corner_rpm = 5 }',
         ("axes.Z.max_velocity_mm_s", "needs more than 40% of the torque of axes.Z.sim",
          "falling as 1/speed", "loses steps", "allowed: <=")),
        ("max_accel_mm_s2 = 500\ntravel_mm = [-80, 0]",
         "max_accel_mm_s2 = 200000\ntravel_mm = [-80, 0]",
         ("axes.Z.max_accel_mm_s2", "200000.0 mm/s^2 at max_velocity_mm_s 20 mm/s needs",
          "the simulated stepper (axes.Z.sim's defaults)", "allowed: <=")),
        ('kind = "stepper"', 'kind = "stepper"\nsim = { detent_torque_mnm = 900 }',
         ("axes.Z.sim.detent_torque_mnm", "900 is out of range",
          "at most holding_torque_mnm")),
        ('kind = "stepper"', 'kind = "stepper"\nsim = { source_voltage_v = 24 }',
         ("axes.Z.sim.source_voltage_v", "unknown key", "holding_torque_mnm")),
    ],
)
def test_a_bad_stepper_axis_is_refused_naming_the_key(old: str, new: str,
                                                      words: tuple[str, ...]) -> None:
    assert old in MIXED
    message = _refused(MIXED.replace(old, new, 1))
    for word in words:
        assert word in message, message


# --- connecting ----------------------------------------------------------------------------


def test_connecting_sets_the_drive_the_stepper_and_its_simulated_motor(tmp_path: Path) -> None:
    config = stepper_machine(tmp_path)
    with connect_session(config) as session:
        machine = session.machine
        assert isinstance(machine, SimulatedMachine)
        for name, drive in (("X", Drive.STEP_OPEN), ("Z", Drive.STEP_CLOSED)):
            client = machine.axis(name).client
            assert client.drive() is drive
            assert client.stepper() == (200, 16)
            assert client.step_timing() == (100, 20)
            assert client.steps().max_per_tick == 480
            assert client.sim_stepper() == (590, 20, 760)
            assert client.gains() == pytest.approx((0.5, 1.0, 0.005) if name == "Z"
                                                   else (0.0, 0.0, 0.0))
            assert client.following_error_limit() == 400
        assert machine.axis("Z").client.query(16, -1).values == (4000,)
        session.home()
        marks = {name: axis.client.homed_marker() for name, axis in machine.axes.items()}
        machine.configure()  # the same drive: no restart of the counter, the mark kept
        assert {n: a.client.homed_marker() for n, a in machine.axes.items()} == marks
        assert all(session.homed.values())
        session.shutdown()


def test_homing_latches_the_step_count_at_the_switch_edge(tmp_path: Path) -> None:
    config = stepper_machine(tmp_path)
    with connect_session(config) as session:
        machine = session.machine
        assert isinstance(machine, SimulatedMachine)
        session.home()
        for name in "XYZ":
            axis = config.axis(name)
            zero = session.zeroes[name]
            sim = axis.sim
            assert sim is not None
            # The edge is where the simulated switch closes, counted from power-up.
            switch_counts = (axis.homing.position_mm - sim.start_mm) * axis.counts_per_mm
            assert abs(zero.edge_counts - switch_counts) <= 2, (name, zero)
            status = machine.axis(name).client.status()
            assert status.enabled and status.fault == FaultCode.NONE
            home = axis.homing.position_mm - axis.homing.direction * axis.homing.pull_off_mm
            assert abs(status.actual_counts - home * axis.counts_per_mm) <= 2
        session.shutdown()


# --- programs on examples/stepper.toml -----------------------------------------------------


@pytest.mark.parametrize(("program", "origin", "planned_s"),
                         [(DEMO_1, {}, 17.508),
                          (CAM_CORNER, {"X": 100.0, "Y": 100.0, "Z": -40.0}, 13.915)])
def test_programs_run_to_the_end_on_the_stepper_machine(tmp_path: Path, program: Path,
                                                        origin: dict[str, float],
                                                        planned_s: float) -> None:
    config = stepper_machine(tmp_path)
    with connect_session(config) as session:
        machine = session.machine
        assert isinstance(machine, SimulatedMachine)
        homing_s = session.home()
        if origin:
            session.set_work_origin(origin)
        dialect = dialect_named("grbl") if program == CAM_CORNER else None
        prepared = session.prepare(program, text=program.read_text(), dialect=dialect)
        report, _ = session.run(prepared, homing_s=homing_s)
        slipped = {}
        for name in "XYZ":
            device = machine.world.device(name)
            assert isinstance(device, Device)
            issued = machine.axis(name).client.steps().issued
            slipped[name] = issued - device.state.shaft_micro_counts / MICRO
        session.shutdown()
    assert report.completed, report.stop_reason
    assert report.planned_time_s == pytest.approx(planned_s, abs=0.002)
    assert report.executed_time_s == pytest.approx(planned_s, abs=0.002)
    peaks = {axis.name: axis.max_error_counts for axis in report.axes}
    assert peaks["X"] == peaks["Y"] == 0, "open loop: every step issued on its tick"
    assert 0 < peaks["Z"] <= 20, "closed loop: the encoder's error, microsteps"
    assert report.max_endpoint_miss_mm < 0.05
    assert any("open loop: its position is the steps issued" in n for n in report.notes)
    assert abs(slipped["X"]) < 2 and abs(slipped["Y"]) < 2, f"no step lost: {slipped}"
    assert abs(slipped["Z"]) < 32, f"Z's rotor never slipped a cycle (64): {slipped}"
    print(f"{program.name} on {EXAMPLE.name}: {report.executed_time_s:.3f} s (planned"
          f" {report.planned_time_s:.3f} s), following error peaks {peaks} microsteps, Z rms"
          f" {report.axes[2].rms_error_counts:.2f}; shafts vs steps issued {slipped}")


# --- a load beyond the pull-out torque ------------------------------------------------------


def test_open_loop_loses_steps_and_the_next_homing_finds_them(tmp_path: Path) -> None:
    """700 mNm on X (its stepper holds 590) for 0.3 s of a 20 mm/s move: the shaft stalls
    while the steps go on; the run completes, and homing X again latches its switch edge
    that many steps off (a whole number of the stepper's 4-full-step cycles)."""
    config = stepper_machine(tmp_path)
    x = config.axis("X")
    run = run_with_load(config, OPEN_PROGRAM, axis="X", load_mnm=700.0, on_s=2.0, for_s=0.3)
    report = run.report
    assert report.completed, report.stop_reason
    assert {a.name: a.max_error_counts for a in report.axes}["X"] == 0, "no error shows"
    lost = run.slipped_microsteps
    assert lost > 1000, "the shaft stood still while the steps went on"
    assert lost % 64 in (0, 1, 63), "a whole number of electrical cycles (4 full steps)"
    assert run.rehome_shift is not None and abs(run.rehome_shift + lost) <= 2, (
        "homing finds the loss to a microstep or two")
    print(f"X open loop, {run.load_mnm:g} mNm from {run.on_s:.2f} s to {run.off_s:.2f} s:"
          f" {lost} microsteps slipped ({full_steps(x, lost):g} full steps,"
          f" {lost / x.counts_per_mm:.3f} mm); the next homing shifted X by"
          f" {run.rehome_shift} microsteps ({run.rehome_shift / x.counts_per_mm:.3f} mm)")


def test_open_loop_below_its_pull_out_torque_loses_nothing(tmp_path: Path) -> None:
    config = stepper_machine(tmp_path)
    run = run_with_load(config, OPEN_PROGRAM, axis="X", load_mnm=400.0, on_s=2.0, for_s=0.3)
    assert run.report.completed
    assert abs(run.slipped_microsteps) <= 1
    assert run.rehome_shift is not None and abs(run.rehome_shift) <= 2


def test_closed_loop_below_its_holding_torque_catches_up(tmp_path: Path) -> None:
    """560 mNm on Z (holding 590): Z falls behind on the tick the load comes, by tens of
    microsteps, and catches up; the run completes with the peak in its report."""
    config = stepper_machine(tmp_path)
    run = run_with_load(config, CLOSED_PROGRAM, axis="Z", load_mnm=560.0, on_s=2.0,
                        for_s=0.3, rehome=False)
    report = run.report
    assert report.completed, report.stop_reason
    z = next(axis for axis in report.axes if axis.name == "Z")
    assert 20 < z.max_error_counts < config.axis("Z").following_error_limit_counts
    assert run.on_s - 0.05 <= z.max_error_time_s <= run.off_s + 0.05, "seen while loaded"
    assert abs(run.slipped_microsteps) <= 16, "the field never led by more than a full step"


def test_closed_loop_beyond_its_holding_torque_stops_every_axis(tmp_path: Path) -> None:
    """700 mNm on Z mid-line: the encoder shows the stall, the following error passes
    call 29's 400 microsteps and Z faults; the host stops X and Y along the path."""
    config = stepper_machine(tmp_path)
    run = run_with_load(config, CLOSED_PROGRAM, axis="Z", load_mnm=700.0, on_s=2.0,
                        for_s=0.3)
    report = run.report
    assert not report.completed and report.stop_reason.startswith("fault")
    (fault,) = report.faults
    assert (fault.axis, fault.fault, fault.line, fault.code) == (
        "Z", "following error", 2, FaultCode.FOLLOWING_ERROR)
    assert run.on_s <= fault.time_s <= run.on_s + 0.5
    x_mm, y_mm = report.end_position_mm["X"], report.end_position_mm["Y"]
    assert 0 < x_mm < 120 and x_mm / y_mm == pytest.approx(120 / 90, rel=1e-3), (
        "X and Y came to rest on the line's path")
    limit_mm = config.axis("Z").following_error_limit_mm
    seen_mm = 20.0 * 0.015  # the feed (F1200) over the host's 15 ms to see the fault
    assert 0 < report.stop_planned_mm <= report.stop_distance_mm <= (
        report.stop_planned_mm + limit_mm + seen_mm + 0.05), (
        "the planned stop, Z's lag at the fault and the path until the host saw it")
    print(f"Z closed loop, {run.load_mnm:g} mNm from {run.on_s:.2f} s: {fault.fault} at"
          f" {fault.time_s:.3f} s, line {fault.line}; X and Y stopped on the path at"
          f" X {x_mm:.3f} Y {y_mm:.3f} (the stop {report.stop_distance_mm:.3f} mm from the"
          f" commanded point with Z's lag, planned {report.stop_planned_mm:.3f} mm)")


# --- grbl ---------------------------------------------------------------------------------


def test_grbl_shows_and_sets_the_steps_per_mm_and_the_step_pulse(tmp_path: Path) -> None:
    path = tmp_path / "mixed.toml"
    path.write_text(MIXED.replace("steps_per_mm = 400", "steps_per_mm = 400.0"))
    config = load_config(path)
    with connect_session(config) as session:
        session.home()
        operator = Operator(session, file="<grbl>")
        front = SessionMachine(operator, keep_settings=True)
        try:
            values = machine_setting_values(front.settings())
            assert (values[100], values[101]) == (240.0, 400.0)
            assert not isinstance(front.set_setting(101, 800.0), Rejected)
            assert load_config(path).axis("Z").counts_per_mm == 800.0
            assert "steps_per_mm = 800.0" in path.read_text()
            assert machine_setting_values(front.settings())[101] == 800.0
            assert not isinstance(front.set_setting(100, 250.0), Rejected)
            assert load_config(path).axis("X").counts_per_mm == 250.0
            # $0: the step pulse, microseconds, on every stepper axis, sent to the driver
            assert values[0] == 2.0
            assert not isinstance(front.set_setting(0, 0.5), Rejected)
            stepper = load_config(path).axis("Z").stepper
            assert stepper is not None and stepper.step_pulse_ns == 500
            assert session.machine.axis("Z").client.step_timing() == (500, 1000)
            assert machine_setting_values(front.settings())[0] == 0.5
        finally:
            operator.close()
        session.shutdown()


# --- usbmotion tune ---------------------------------------------------------------------------


def test_tune_reach_on_a_stepper_says_what_limits_it(tmp_path: Path) -> None:
    path = tmp_path / "stepper.toml"
    stepper_machine(tmp_path)
    code, out, err = invoke("tune", "-a", "X", "--reach", "-m", str(path))
    assert code == 0, err
    assert "480 steps a 100 us tick (call 48)" in out
    assert "torque     not measured: open loop the device counts the steps it issues" in out
    assert "keeping 60% of it" in out and "no reach line" in out
    code, out, err = invoke("tune", "-a", "Z", "--reach", "-m", str(path))
    assert code == 0, err
    assert "closed loop keeps the rest to catch up" in out and "keeping 10% of it" in out
    code, _, err = invoke("tune", "-a", "Z", "--auto", "--travel", "5", "-m", str(path))
    assert code == 2 and "identifies a DC servo's motor" in err
