"""usbmotion tune --reach: the fit, the measurement on the simulated machine, the command line."""

from __future__ import annotations

import dataclasses
import math
import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest
from tests.commands import invoke

from usbmotion.cli.run import default_machine
from usbmotion.clock import WALL_CLOCK
from usbmotion.device import Device, MemoryFlash
from usbmotion.errors import ArgumentError, ConfigError, DeviceError
from usbmotion.host.config import MachineConfig, load_config, parse_config
from usbmotion.host.machine import Machine
from usbmotion.session.homing import homed_mark
from usbmotion.sim.machine import SimulatedMachine
from usbmotion.sim.server import DeviceServer
from usbmotion.sim.world import SimWorld
from usbmotion.tuning import (
    ReachMeasurement,
    fit_saturated_run,
    measure_reach,
    stands_at_mm,
    step_response,
)

COUNTS_PER_MM = 240.0


def model_reach(*, load_torque_mnm: float = 50.0, inertia_kg_m2: float = 1.1e-3) -> tuple[
        float, float]:
    """The default gearmotor's no-load speed (mm/s) and acceleration from standstill
    (mm/s^2) at 12 V, from the model's equation in PROTOCOL.md ("The simulated motor"):
    ``(Kt V/R - T_load) / (Kt^2/R + b)`` and ``(Kt V/R - T_load) / J``."""
    kt, resistance, volts, viscous = 0.3346, 2.182, 12.0, 500e-6
    torque = kt * volts / resistance - load_torque_mnm * 1e-3
    mm_per_rad = 1920 / (2 * math.pi) / COUNTS_PER_MM
    return (torque / (kt * kt / resistance + viscous) * mm_per_rad,
            torque / inertia_kg_m2 * mm_per_rad)


# --- the fit ------------------------------------------------------------------------------


def test_the_fit_recovers_a_first_order_run() -> None:
    times = np.arange(1, 201, dtype=np.float64) / 1000
    speed, tau = 10_000.0, 0.025
    moved = np.asarray(speed * (times - tau * (1 - np.exp(-times / tau))), dtype=np.float64)
    fit = fit_saturated_run(times, moved)
    assert fit.top_speed_counts_s == pytest.approx(speed, rel=1e-6)
    assert fit.time_constant_s == pytest.approx(tau, rel=1e-5)
    assert fit.accel_counts_s2 == pytest.approx(speed / tau, rel=1e-5)
    assert fit.rms_residual_counts < 1e-3
    noisy = np.asarray(np.floor(moved), dtype=np.float64)
    rough = fit_saturated_run(times, noisy)
    assert rough.top_speed_counts_s == pytest.approx(speed, rel=2e-3)
    assert 0.2 < rough.rms_residual_counts < 0.6


@pytest.mark.parametrize(
    ("times", "moved", "message"),
    [
        (np.array([0.001, 0.002]), np.array([1.0, 2.0]), "at least 3 samples"),
        (np.array([0.0, 0.001, 0.002]), np.array([0.0, 1.0, 2.0]), "positive and increasing"),
        (np.array([0.001, 0.003, 0.002]), np.array([1.0, 2.0, 3.0]), "positive and increasing"),
        (np.array([0.001, 0.002, 0.003]), np.array([0.0, -1.0, -2.0]), "must move forward"),
    ],
)
def test_the_fit_refuses_what_is_no_run(times: np.ndarray, moved: np.ndarray,
                                        message: str) -> None:
    with pytest.raises(ArgumentError, match=message):
        fit_saturated_run(times, moved)


# --- the measurement, in virtual time -------------------------------------------------------


def measured(axis: str, *, distance_mm: float = 30.0,
             config: MachineConfig | None = None) -> tuple[ReachMeasurement, list[int]]:
    """measure_reach on the default machine; also the axis's counts after the test."""
    config = config or load_config(default_machine())
    with SimulatedMachine.connect(config) as machine:
        machine.configure()
        assert machine.world is not None
        device = machine.world.device(axis)
        assert isinstance(device, Device)
        start = device.state.actual
        result = measure_reach(machine, axis, distance_mm=distance_mm)
        state = device.state
        status = machine.axis(axis).client.status()
        assert status.mode == 1 and status.enabled and status.fault == 0
        assert not status.lower_limit and not status.upper_limit
        assert machine.axis(axis).client.gains() == pytest.approx((0.5, 5.0, 0.002))
        assert state.desired == state.actual, "left holding where it stopped"
    return result, [start, state.actual]


def test_the_reach_of_the_default_x_axis_is_the_model_s_within_a_percent() -> None:
    result, (start, end) = measured("X")
    speed, accel = model_reach()
    assert speed == pytest.approx(43.99, abs=0.01)
    assert result.reach.velocity_mm_s == pytest.approx(speed, rel=0.01)
    assert result.reach.accel_mm_s2 == pytest.approx(accel, rel=0.02)
    assert result.supply_v == 12.0
    assert [run.direction for run in result.runs] == [1, -1]
    for run in result.runs:
        assert np.all(run.output_v == 12.0 * run.direction), "at the rail on every tick"
        assert np.all(np.diff(run.times_s) == pytest.approx(0.001)), "one sample per tick"
        assert run.times_s[0] == pytest.approx(0.001)
        assert run.times_s[-1] >= 3 * run.fit.time_constant_s
        assert run.fit.top_speed_counts_s / COUNTS_PER_MM == pytest.approx(speed, rel=0.01)
        assert run.fit.rms_residual_counts < 1.0
    room = round(30.0 * COUNTS_PER_MM)
    first, second = result.runs
    lag = 0.02 * speed * COUNTS_PER_MM
    assert room / 2 - lag <= first.travel_counts <= room, "stops accelerating at half the room"
    assert second.travel_counts <= first.travel_counts
    assert 0 <= end - start <= room, "the test stayed on its stretch"


def test_the_reach_of_the_heavier_z_axis_and_toward_lower_positions() -> None:
    result, (start, end) = measured("Z", distance_mm=-25.0)
    speed, accel = model_reach(load_torque_mnm=80.0, inertia_kg_m2=1.5e-3)
    assert [run.direction for run in result.runs] == [-1, 1]
    assert result.reach.velocity_mm_s == pytest.approx(speed, rel=0.01)
    assert result.reach.accel_mm_s2 == pytest.approx(accel, rel=0.02)
    assert -round(25.0 * COUNTS_PER_MM) <= end - start <= 0


def test_a_distance_too_short_to_reach_top_speed_asks_for_more() -> None:
    with pytest.raises(ArgumentError, match=r"axis X: still accelerating after .* mm \(.* ms,"
                       r" .* time constants of .* ms; at least 3 needed\): give the test at"
                       r" least 1\d mm") as caught:
        measured("X", distance_mm=4.0)
    assert caught.value.reason == "distance_mm"
    with pytest.raises(ArgumentError, match=r"distance_mm 0\.0 must be a finite non-zero"):
        measured("X", distance_mm=0.0)
    with pytest.raises(ArgumentError, match="is 72 counts; a reach test needs at least 100"):
        measured("X", distance_mm=0.3)


def test_a_motor_that_cannot_turn_is_named() -> None:
    """A load above the stall torque (refused in a machine file, so set past it here)."""
    config = load_config(default_machine())
    x = config.axis("X")
    assert x.sim is not None
    stalled = dataclasses.replace(x, sim=dataclasses.replace(x.sim, load_torque_mnm=2000.0))
    config = dataclasses.replace(config, axes=(stalled, *config.axes[1:]))
    with SimulatedMachine.connect(config) as machine:
        machine.configure()
        with pytest.raises(DeviceError, match=r"axis X: moved 0 mm of the 15 mm it may"
                           r" accelerate over in 0.5 s at full voltage: is the motor"
                           r" connected, powered and free to turn\?"):
            measure_reach(machine, "X", distance_mm=30.0, run_timeout_s=0.5)
        status = machine.axis("X").client.status()
        assert status.mode == 1 and status.fault == 0


def test_the_measured_reach_in_the_machine_file_holds_its_limits(tmp_path: Path) -> None:
    """The reach line as measured loads; limits beyond 90 % of it are refused, naming it."""
    result, _ = measured("X")
    reach = result.reach
    line = (f"reach = {{ velocity_mm_s = {reach.velocity_mm_s:.4g},"
            f" accel_mm_s2 = {reach.accel_mm_s2:.4g} }}")
    text = default_machine().read_text()
    anchor = 'sim = { start_mm = 100.0 }'
    with_reach = text.replace(anchor, anchor + "\n" + line, 1)
    assert with_reach != text
    config = parse_config(with_reach, path="measured.toml")
    assert config.axis("X").reach is not None
    assert config.axis("Y").reach is None
    too_fast = with_reach.replace("max_velocity_mm_s = 20.0", "max_velocity_mm_s = 39.8", 1)
    with pytest.raises(ConfigError, match=r"axes\.X\.max_velocity_mm_s: 39\.8 mm/s leaves the"
                       r" PID less than 10% of the supply to correct errors: its no-load speed"):
        parse_config(too_fast, path="measured.toml")
    without_sim = with_reach.replace(anchor, "", 1).replace('url = "sim://X"\n', "", 1)
    too_fast = without_sim.replace("max_velocity_mm_s = 20.0", "max_velocity_mm_s = 39.8", 1)
    with pytest.raises(ConfigError, match=r"measured\.toml:\d+: axes\.X\.max_velocity_mm_s:"
                       r" 39\.8 mm/s leaves the PID less than 10% of the supply to correct"
                       r" errors: its top speed measured by usbmotion tune --reach is 43\.9\d"
                       r" mm/s \(axes\.X\.reach\.velocity_mm_s\); allowed: <= 39\.5\d mm/s"):
        parse_config(too_fast, path="measured.toml")


# --- the command line ---------------------------------------------------------------------


def _usbmotion(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "usbmotion", *args], capture_output=True,
                          text=True, timeout=120, check=False)


def test_tune_reach_prints_the_figures_and_the_line_for_the_machine_file() -> None:
    done = _usbmotion("tune", "--axis", "x", "--reach")
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    assert lines[0] == "axis X: at full voltage (12 V) from where it stood, 30 mm toward + and back"
    assert lines[-2] == f"put in [axes.X] of {default_machine()}:"
    table = tomllib.loads(lines[-1])["reach"]
    speed, accel = model_reach()
    assert set(table) == {"velocity_mm_s", "accel_mm_s2"}
    assert table["velocity_mm_s"] == pytest.approx(speed, rel=0.01)
    assert table["accel_mm_s2"] == pytest.approx(accel, rel=0.02)
    assert "keeping 10% of the supply for the PID, the machine file may set" in done.stdout
    assert "(it sets 20 and 500)" in done.stdout
    assert "lower them" not in done.stdout


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (("--reach", "--kp", "1"), "usbmotion tune: --kp does not apply to --reach"),
        (("--reach", "--step-mm", "1", "--plot", "p.png"),
         "usbmotion tune: --step-mm, --plot do not apply to --reach"),
        (("--distance-mm", "10"), "usbmotion tune: --distance-mm applies to --reach only"),
        (("--reach", "--distance-mm", "3"), "give the test at least"),
    ],
)
def test_tune_reach_refuses_what_does_not_apply(args: tuple[str, ...], message: str) -> None:
    code, _, err = invoke("tune", "--axis", "X", *args)
    assert code == 2
    assert message in err
    assert "Traceback" not in err


@pytest.mark.parametrize(("args", "message"), [
    (("--axis", "X", "--step-mm", "150"), "usbmotion tune: axis X: a step of +150 mm from"
     " 100.000 mm would leave its travel_mm [0, 200]: the room from there is -100.000 to"
     " +100.000 mm; nothing moved\n"),
    (("--axis", "z", "--step-mm", "-50.5"), "usbmotion tune: axis Z: a step of -50.5 mm from"
     " -50.000 mm would leave its travel_mm [-100, 0]: the room from there is -50.000 to"
     " +50.000 mm; nothing moved\n"),
    (("--axis", "Z", "--reach", "--distance-mm", "60"), "usbmotion tune: axis Z: a reach"
     " test of +60 mm from -50.000 mm would leave its travel_mm [-100, 0]: the room from"
     " there is -50.000 to +50.000 mm; nothing moved\n"),
])
def test_tune_refuses_a_test_beyond_the_travel_before_anything_moves(
        args: tuple[str, ...], message: str) -> None:
    assert invoke("tune", *args) == (2, "", message)


def test_a_step_is_checked_from_where_the_axis_stands() -> None:
    """Homed, the axis stands at its home (0 mm here): a step down is refused, one up taken;
    not homed and without a simulated motor, only a step longer than the travel is."""
    config = load_config(default_machine())
    with SimulatedMachine.connect(config) as machine:
        machine.configure()
        client = machine.axis("X").client
        assert stands_at_mm(machine, "X") == pytest.approx(100.0)
        with pytest.raises(ArgumentError, match=r"a step of -100\.5 mm from 100\.000 mm"
                           r" would leave") as caught:
            step_response(machine, "X", step_mm=-100.5)
        assert caught.value.reason == "step_mm"
        assert client.status().enabled is False, "nothing moved"
        client.set_position(0)
        client.set_homed_marker(homed_mark(config, config.axis("X")))
        assert stands_at_mm(machine, "X") == 0.0
        with pytest.raises(ArgumentError, match=r"from 0\.000 mm would leave its travel_mm"):
            step_response(machine, "X", step_mm=-1.0)
        assert step_response(machine, "X", step_mm=1.0).metrics.step_counts == 240
        machine.stop()
    with SimulatedMachine.connect(config) as simulated:
        simulated.configure()
        unknown = Machine(config, [dataclasses.replace(axis, config=dataclasses.replace(
            axis.config, sim=None)) for axis in simulated.axes.values()])
        assert stands_at_mm(unknown, "X") is None, "as a real axis not homed"
        with pytest.raises(ArgumentError, match=r"axis X: a step of \+201 mm is longer than"
                           r" its whole travel_mm \[0, 200\] \(it is not homed"):
            step_response(unknown, "X", step_mm=201.0)


# --- served devices, in real time -------------------------------------------------------------


@pytest.mark.realtime
def test_the_reach_of_a_served_device_over_a_pseudo_terminal() -> None:
    """In real time the host sees each line late: the fit still starts on the right tick."""
    world = SimWorld()
    device = Device(flash=MemoryFlash())
    device.feed(b"18 6 88 32 65 88 73 83\n")
    device.take_output()
    world.add(device, key="0")
    with DeviceServer(world, pty=True).start() as server:
        deadline = WALL_CLOCK.now() + 60
        while world.time_us == 0 and WALL_CLOCK.now() < deadline:
            WALL_CLOCK.sleep(0.01)
        config = parse_config(
            f'watchdog_ms = 2000\n[axes.X]\nurl = "{server.endpoints[0].path}"\n'
            'device = "X AXIS"\ncounts_per_mm = 240\nmax_velocity_mm_s = 20\n'
            "max_accel_mm_s2 = 500\ntravel_mm = [0, 200]\n"
            "gains = { kp = 0.5, ki = 5.0, kd = 0.002 }\nsim = { start_mm = 100 }\n",
            path="served.toml",
        )
        with Machine.connect(config, search_ports=False) as machine:
            machine.configure()
            result = measure_reach(machine, "X", distance_mm=30.0)
            machine.stop()
    speed, accel = model_reach()
    assert result.reach.velocity_mm_s == pytest.approx(speed, rel=0.01)
    assert result.reach.accel_mm_s2 == pytest.approx(accel, rel=0.02)
    assert all(run.fit.rms_residual_counts < 1.0 for run in result.runs)


def test_tune_writes_its_plot_unless_told_not_to(tmp_path: Path,
                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    """As run: ``--no-plot`` writes none, ``--plot`` names it, and both at once are refused."""
    monkeypatch.chdir(tmp_path)
    code, out, _ = invoke("tune", "--axis", "X", "--no-plot")
    assert code == 0 and "overshoot" in out and "plot" not in out
    assert list(tmp_path.iterdir()) == []
    code, out, _ = invoke("tune", "--axis", "X", "--plot", "step.png")
    assert code == 0 and (tmp_path / "step.png").is_file()
    message = "--plot step.png and --no-plot: give one or the other"
    assert invoke("tune", "--axis", "X", "--plot", "step.png", "--no-plot") == (
        2, "", f"usbmotion tune: {message}\n")
    (tmp_path / "p.ngc").write_text("G0 X1\n")
    code, _, err = invoke("run", "p.ngc", "--plot", "step.png", "--no-plot")
    assert (code, err) == (2, f"usbmotion run: {message}\n")
