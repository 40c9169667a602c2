"""usbmotion tune --auto: the fit, the loop's margins and predictions, the identification on
a simulated axis (within its travel; a reversed encoder and a stall stop it), the command."""

from __future__ import annotations

import dataclasses
import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from tests.commands import invoke
from tests.test_layering import layering_violations

import usbmotion.autotune
from usbmotion.autotune.identify import MAX_DURATION_S, excitation, identify_axis
from usbmotion.autotune.loop import (
    MIN_GAIN_MARGIN_DB,
    MIN_PHASE_MARGIN_DEG,
    design,
    margins,
    quantise,
    simulate_closed_loop,
)
from usbmotion.autotune.machine_file import write_tuning
from usbmotion.autotune.model import (
    AxisModel,
    fit_model,
    simulate_open_loop,
    simulated_model,
)
from usbmotion.autotune.verify import check_on_axis, place_loop, step_and_move
from usbmotion.cli.run import default_machine
from usbmotion.device import core0
from usbmotion.device.motor import MotorConstants
from usbmotion.errors import ArgumentError, DeviceError
from usbmotion.host.config import AxisConfig, MachineConfig, PidGains, load_config, parse_config
from usbmotion.sim.machine import SimulatedMachine
from usbmotion.tuning import step_response

TICK_S = 1e-3


def default_model(axis: AxisConfig) -> AxisModel:
    """The exact model of a simulated axis's motor."""
    return simulated_model(axis)


@pytest.fixture(scope="module")
def config() -> MachineConfig:
    return load_config(default_machine())


def test_autotuning_is_host_side() -> None:
    """The tuning modules drive devices through ports: no import of the simulator or the
    device (the machine is connected by the command, the tests and the benchmark)."""
    folder = Path(usbmotion.autotune.__file__).parent
    assert layering_violations(sorted(folder.glob("*.py"))) == []


# --- the fit (pure) ------------------------------------------------------------------------


def test_the_fit_recovers_a_model_from_quantised_positions(config: MachineConfig) -> None:
    model = default_model(config.axis("X"))
    rng = np.random.default_rng(5)
    volts: list[float] = []
    for _ in range(16):
        volts += [float(rng.uniform(-6, 6))] * int(rng.integers(60, 200)) + [0.0] * 80
    voltages = np.array(volts)
    positions = np.floor(simulate_open_loop(model, voltages, tick_s=TICK_S) + 0.37)
    fit = fit_model(voltages, positions, tick_s=TICK_S, supply_v=12.0)
    assert fit.model.time_constant_s == pytest.approx(model.time_constant_s, rel=0.01)
    assert fit.model.speed_per_volt_counts_s == pytest.approx(model.speed_per_volt_counts_s,
                                                              rel=0.005)
    assert fit.model.coulomb_v == pytest.approx(model.coulomb_v, rel=0.02)
    assert 0.2 < fit.rms_residual_counts < 0.45  # the encoder's quantisation, no more
    assert 0 < fit.time_constant_sigma_s < 0.01 * model.time_constant_s
    physical = fit.model.physical(torque_constant_nm_per_a=0.3346, resistance_ohm=2.182,
                                  counts_per_revolution=1920)
    assert physical.inertia_kg_m2 == pytest.approx(1.1e-3, rel=0.01)
    assert physical.load_torque_nm == pytest.approx(0.05, rel=0.02)


def test_a_record_that_never_moves_has_nothing_to_fit() -> None:
    with pytest.raises(ArgumentError, match="nothing to fit"):
        fit_model(np.zeros(500), np.zeros(500), tick_s=TICK_S, supply_v=12.0)
    with pytest.raises(ArgumentError, match="must be one-dimensional and match"):
        fit_model(np.zeros(5), np.zeros(6), tick_s=TICK_S, supply_v=12.0)


# --- the loop (pure) -----------------------------------------------------------------------


def test_margins_of_the_default_gains(config: MachineConfig) -> None:
    found = margins(default_model(config.axis("X")), config.axis("X").gains, tick_s=TICK_S)
    assert found.stable
    assert 35 < found.phase_margin_deg < 45  # the file's gains: 10 % overshoot on a step
    assert found.gain_margin_db > 20
    assert 20 < found.crossover_hz < 30
    unstable = margins(default_model(config.axis("X")), PidGains(50.0, 0.0, 0.0),
                       tick_s=TICK_S)
    assert not unstable.stable


def test_quantised_gains_have_three_digits() -> None:
    assert quantise(PidGains(1.23456, 0.0, 0.0073149)) == PidGains(1.23, 0.0, 0.00731)


def test_the_design_keeps_its_margins_and_overshoot(config: MachineConfig) -> None:
    model = default_model(config.axis("X"))
    step, move = step_and_move(4800, counts_per_mm=240.0, max_velocity_mm_s=20.0,
                               max_accel_mm_s2=500.0, tick_s=TICK_S)
    chosen = design(model, tick_s=TICK_S, step_desired=step, move_desired=move,
                    crossover_hz=40.0)
    assert chosen.gains == quantise(chosen.gains)
    assert chosen.margins.stable
    assert chosen.margins.phase_margin_deg >= MIN_PHASE_MARGIN_DEG
    assert chosen.margins.gain_margin_db >= MIN_GAIN_MARGIN_DB
    assert chosen.margins.crossover_hz == pytest.approx(40.0, rel=0.05)
    progress = (chosen.step.actual - step[0]) / (step[-1] - step[0])
    assert float(np.max(progress)) <= 1.04
    with pytest.raises(ArgumentError, match="try a lower bandwidth"):
        design(model, tick_s=TICK_S, step_desired=step, move_desired=move, crossover_hz=400.0)


def test_the_prediction_follows_the_device_to_a_count(config: MachineConfig) -> None:
    with SimulatedMachine.connect(config) as machine:
        machine.configure()
        measured = step_response(machine, "X", step_mm=1.0, duration_s=0.3)
    predicted = simulate_closed_loop(default_model(config.axis("X")), config.axis("X").gains,
                                     measured.desired, tick_s=TICK_S,
                                     start_counts=float(measured.actual[0]))
    assert float(np.max(np.abs(predicted.actual - measured.actual))) <= 1.0


def test_the_excitation_stays_within_its_room() -> None:
    plan = excitation(4800, max_velocity_counts_s=4800, max_accel_counts_s2=120000,
                      period_s=TICK_S, duration_s=MAX_DURATION_S)
    assert plan.size * TICK_S <= MAX_DURATION_S
    assert float(plan.min()) >= 0.0 and float(plan.max()) <= 0.95 * 4800 + 1e-9
    after_the_first_move = plan[np.argmax(plan >= 0.05 * 4800):]
    assert float(after_the_first_move.min()) >= 0.05 * 4800 - 1e-9
    assert float(np.max(np.abs(np.diff(plan)))) <= 4800 * TICK_S + 1e-9


# --- on a simulated axis --------------------------------------------------------------------


def test_identification_stays_within_the_travel_and_finds_the_model(
        config: MachineConfig) -> None:
    axis = config.axis("Z")
    with SimulatedMachine.connect(config) as machine:
        machine.configure()
        start = machine.axis("Z").client.status().actual_counts
        found = identify_axis(machine, "Z", travel_mm=-8.0, duration_s=3.0)
        placed = check_on_axis(machine, "Z", found,
                               place_loop(found, axis, bandwidth_hz=40.0))
    assert (found.low_counts, found.high_counts) == (start - 8 * 240, start)
    assert found.low_counts <= found.reached_low_counts
    assert found.reached_high_counts <= found.high_counts
    assert found.low_counts <= float(found.positions.min())
    assert float(found.positions.max()) <= found.high_counts
    assert found.times_s[-1] <= MAX_DURATION_S
    truth = default_model(axis)
    model = found.fit.model
    assert model.time_constant_s == pytest.approx(truth.time_constant_s, rel=0.02)
    assert model.speed_per_volt_counts_s == pytest.approx(truth.speed_per_volt_counts_s,
                                                          rel=0.01)
    assert model.coulomb_v == pytest.approx(truth.coulomb_v, rel=0.03)
    for check in (placed.step, placed.move):
        assert check is not None
        assert check.measured.actual.min() >= found.low_counts
        assert check.measured.actual.max() <= found.high_counts
        assert check.measured_figures.overshoot_pct <= 5.0
        assert abs(check.measured_figures.peak_following_error_counts
                   - check.predicted_figures.peak_following_error_counts) <= 2


def _broken_drive(monkeypatch: pytest.MonkeyPatch, factor: int) -> None:
    """The simulated motor turns ``factor`` times its drive: -1 wires it (or its encoder)
    reversed, 0 leaves it stalled."""
    original = getattr(core0, "derive_constants")  # noqa: B009

    def wired(*args: object, **kwargs: object) -> MotorConstants:
        constants: MotorConstants = original(*args, **kwargs)
        coefficient, exponent = constants.drive
        return dataclasses.replace(constants, drive=(factor * coefficient, exponent))

    monkeypatch.setattr(core0, "derive_constants", wired)


@pytest.mark.parametrize(("factor", "message"), [
    (-1, "against the voltage: the encoder counts backwards or the motor is wired reversed"),
    (0, "stalled"),
])
def test_a_reversed_encoder_or_a_stall_stops_the_axis(
        config: MachineConfig, monkeypatch: pytest.MonkeyPatch, factor: int,
        message: str) -> None:
    _broken_drive(monkeypatch, factor)
    with SimulatedMachine.connect(config) as machine:
        machine.configure()
        client = machine.axis("X").client
        start = client.status().actual_counts
        with pytest.raises(DeviceError, match=message) as raised:
            identify_axis(machine, "X", travel_mm=10.0, duration_s=2.0)
        assert "servo is disabled" in str(raised.value)
        status = client.status()
        assert not status.enabled
        assert abs(status.actual_counts - start) < 100  # the probe's few counts, no runaway


def test_a_travel_beyond_the_soft_limits_or_too_short_is_refused(config: MachineConfig) -> None:
    with SimulatedMachine.connect(config) as machine:
        machine.configure()
        with pytest.raises(ArgumentError, match="would leave its travel_mm"):
            identify_axis(machine, "X", travel_mm=150.0)
        with pytest.raises(ArgumentError, match="needs at least 200"):
            identify_axis(machine, "X", travel_mm=0.5)
        with pytest.raises(ArgumentError, match=r"duration_s 11\.0 is out of range"):
            identify_axis(machine, "X", travel_mm=10.0, duration_s=11.0)


# --- the machine file and the command ------------------------------------------------------


def test_writing_keeps_the_comments_and_replaces_the_old_block() -> None:
    text = default_machine().read_text(encoding="utf-8")
    once = write_tuning(text, "Y", PidGains(1.14, 12.0, 0.00734), ["earliest", "a = 1"])
    twice = write_tuning(once, "Y", PidGains(1.15, 13.0, 0.00735), ["second"])
    assert "# tune --auto axis Y: second" in twice
    assert "earliest" not in twice and "a = 1" not in twice
    assert "# The simulated 3-axis XYZ machine" in twice
    assert "# position loop: V/count, V/(count s), V s/count" in twice
    loaded = parse_config(twice, path="machine.toml")
    assert loaded.axis("Y").gains == PidGains(1.15, 13.0, 0.00735)
    assert loaded.axis("X").gains == PidGains(0.5, 5.0, 0.002)
    examples = Path(__file__).resolve().parents[1] / "examples" / "real-machine.toml"
    tables = examples.read_text(encoding="utf-8")  # gains in an [axes.X.gains] table
    first = write_tuning(tables, "X", PidGains(1.14, 12.0, 0.00734), ["earliest", "a = 1"])
    again = write_tuning(write_tuning(first, "X", PidGains(1.0, 1.0, 0.0), ["second"]),
                         "X", PidGains(1.14, 12.0, 0.00734), ["earliest", "a = 1"])
    assert again == first  # a block replaces the last, blank lines and all
    assert parse_config(first, path="real.toml").axis("X").gains == PidGains(1.14, 12.0, 0.00734)
    with pytest.raises(Exception, match=r"no \[axes.Q\] table"):
        write_tuning(text, "Q", PidGains(1.0, 1.0, 0.0), ["x"])


def _usbmotion(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "usbmotion", *args], capture_output=True,
                          text=True, timeout=240, check=False)


def test_the_command_prints_json_and_writes_the_machine_file(tmp_path: Path) -> None:
    machine_file = tmp_path / "machine.toml"
    shutil.copy(default_machine(), machine_file)
    done = _usbmotion("tune", "-a", "Y", "--auto", "--travel", "10", "--excite-s", "2",
                      "--bandwidth-hz", "40", "--json", "--write", "-m", str(machine_file))
    assert done.returncode == 0, done.stderr
    figures = json.loads(done.stdout)
    assert figures["loop"]["phase_margin_deg"] >= MIN_PHASE_MARGIN_DEG
    low, high = figures["identification"]["allowed_from_origin_mm"]
    reached_low, reached_high = figures["identification"]["reached_from_origin_mm"]
    assert (low, high) == (0.0, 10.0)
    assert low <= reached_low and reached_high <= high
    for what in ("step", "move"):
        check = figures["checks"][what]
        assert set(check) >= {"overshoot_pct", "settling_time_s", "peak_following_error_counts",
                              "ise_counts2_s", "ise_aligned_counts2_s"}
        assert check["overshoot_pct"]["measured"] is not None
    assert figures["physical"]["inertia_kg_m2"] == pytest.approx(1.1e-3, rel=0.03)
    written = load_config(machine_file)
    gains = figures["gains"]
    assert written.axis("Y").gains == PidGains(gains["kp"], gains["ki"], gains["kd"])
    text = machine_file.read_text(encoding="utf-8")
    assert "# tune --auto axis Y: identified" in text
    assert "# The simulated 3-axis XYZ machine" in text


@pytest.mark.parametrize(("args", "message"), [
    (("--auto",), "--auto needs --travel MM"),
    (("--auto", "--travel", "10", "--kp", "1"), "--kp does not apply to --auto"),
    (("--travel", "10"), "--travel applies to --auto only"),
    (("--auto", "--travel", "10", "--objective", "best"), "--objective 'best' is not one of"),
    (("--auto", "--travel", "10", "--write"), "is the built-in machine's file"),
])
def test_bad_auto_command_lines_are_clear(args: tuple[str, ...], message: str) -> None:
    code, _, err = invoke("tune", "-a", "X", *args)
    assert code == 2
    assert message in err
    assert "Traceback" not in err
