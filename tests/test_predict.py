"""Prediction before the job (``usbmotion run --predict``): a program played on the axes'
identified models gives the following error the machine then shows, per axis and per line."""

from __future__ import annotations

import dataclasses
import json
import math
from array import array
from pathlib import Path

import numpy as np
import numpy.typing as npt
import pytest
from typer.testing import CliRunner

from usbmotion.autotune.identify import identify_axis
from usbmotion.autotune.machine_file import write_tuning
from usbmotion.autotune.model import AxisModel, true_model
from usbmotion.autotune.verify import place_loop
from usbmotion.cli.machines import default_machine
from usbmotion.cli.main import app
from usbmotion.demos import demo_path
from usbmotion.errors import ConfigError
from usbmotion.host.config import (
    MachineConfig,
    MotorModelConfig,
    PidGains,
    load_config,
    parse_config,
)
from usbmotion.session import RunReport, watch
from usbmotion.session.report import Trace, line_at, line_peaks
from usbmotion.sim.machine import connect_machine, connect_session
from usbmotion.sim.predict import IDENTIFIED, SIMULATED, model_machine, model_motor, predict

DEMO = demo_path(1)


def _machine_file(tmp_path: Path, *replace: tuple[str, str]) -> Path:
    """The default machine in ``tmp_path`` (its parameter file beside it), each replacement
    made at the first place it fits (axis X's)."""
    text = default_machine().read_text()
    for old, new in replace:
        assert old in text
        text = text.replace(old, new, 1)
    path = tmp_path / "mill.toml"
    path.write_text(text)
    return path


def _run(config: MachineConfig, program: Path = DEMO) -> RunReport:
    """Home ``config``'s simulated machine and run ``program`` in virtual time."""
    with connect_session(config) as session:
        homing_s = session.home()
        prepared = session.prepare(program, text=program.read_text())
        report, _ = session.run(prepared, homing_s=homing_s)
        session.shutdown()
    return report


def _as_figures(model: AxisModel) -> tuple[float, float, float]:
    return (model.time_constant_s, model.speed_per_volt_counts_s, model.coulomb_v)


# --- the motor a model stands for ----------------------------------------------------------

@pytest.mark.parametrize(("tau", "speed", "coulomb"), [
    (0.02123, 904.4, 0.3273),     # the default gearmotor
    (0.004, 30_000.0, 0.0),       # fast, no load: the file's torque constant does not fit
    (0.25, 120.0, 2.5),           # slow and loaded
])
def test_the_simulated_motor_of_a_model_moves_as_the_model(tau: float, speed: float,
                                                           coulomb: float) -> None:
    config = load_config(default_machine())
    axis = config.axis("X")
    model = MotorModelConfig(tau, speed, coulomb, 12.0)
    motor = model_motor(model, axis.sim, update_interval_dms=10).model()
    assert motor.viscous_nm_s_per_rad > 0
    back = true_model(torque_constant_nm_per_a=motor.torque_constant_nm_per_a,
                      resistance_ohm=motor.resistance_ohm,
                      inertia_kg_m2=motor.inertia_kg_m2,
                      viscous_nm_s_per_rad=motor.viscous_nm_s_per_rad,
                      load_torque_nm=motor.load_torque_nm,
                      counts_per_revolution=motor.counts_per_revolution,
                      supply_v=motor.source_voltage_v)
    for found, wanted in zip(_as_figures(back), (tau, speed, coulomb), strict=True):
        assert found == pytest.approx(wanted, rel=2e-3, abs=1e-6), "4 digits the device takes"


def test_a_machine_without_models_or_sim_tables_cannot_be_predicted(tmp_path: Path) -> None:
    path = _machine_file(tmp_path, ('url = "sim://X"', 'url = "socket://127.0.0.1:7000"'),
                         ("sim = { start_mm = 100.0 }\n", ""))
    config = load_config(path)
    assert config.axis("X").sim is None
    with pytest.raises(ConfigError, match=r"axis X has no identified model to predict with:"
                       r" identify it first \(usbmotion tune -a X --auto --travel MM --write\)"):
        model_machine(config, parameter_file=tmp_path / "p.var")


# --- the prediction against the run --------------------------------------------------------

def test_on_a_simulated_machine_the_prediction_is_its_run() -> None:
    """The default machine's axes have no identified model: their sim tables are their
    motors, so the prediction plays the very devices the run drives; the prediction starts
    where homing leaves the machine, the run where the switches put it (a count apart)."""
    config = load_config(default_machine())
    forecast = predict(config, DEMO, DEMO.read_text())
    assert set(forecast.motors.values()) == {SIMULATED}
    assert forecast.report.completed
    measured = _run(config)
    for got, want in zip(forecast.report.axes, measured.axes, strict=True):
        assert abs(got.max_error_counts - want.max_error_counts) <= 1, (got, want)
        assert got.rms_error_counts == pytest.approx(want.rms_error_counts, rel=0.01)
        assert got.max_error_line == want.max_error_line
    lines = {peak.line: peak.peak_error_counts for peak in measured.line_peaks}
    assert [peak.line for peak in forecast.report.line_peaks] == sorted(lines)
    for peak in forecast.report.line_peaks:
        for name, counts in peak.peak_error_counts.items():
            assert abs(counts - lines[peak.line][name]) <= 1, (peak, lines[peak.line])


def test_identified_models_predict_a_machine_whose_motors_the_host_does_not_know() -> None:
    """X's motor is not the machine file's (inertia x1.3, load x0.7, viscous friction x1.4,
    torque constant x0.8): identified through its device and its loop placed, the
    prediction on the model gives each axis's peak and RMS following error within 10 % or
    2 counts of the run's; a model twice as slow (its time constant doubled) does not.

    Most of the RMS error of these axes is the tick's own lag (a tick of motion at speed,
    which any model predicts); the peak, while the axis accelerates, is what the motor's
    figures decide."""
    known = load_config(default_machine())
    x = known.axis("X")
    assert x.sim is not None
    drawn = dataclasses.replace(
        x.sim, inertia_kg_m2=x.sim.inertia_kg_m2 * 1.3, load_torque_mnm=x.sim.load_torque_mnm * 0.7,
        viscous_friction_unm_per_rad_s=x.sim.viscous_friction_unm_per_rad_s * 1.4,
        torque_constant_mnm_per_a=x.sim.torque_constant_mnm_per_a * 0.8)
    truth = dataclasses.replace(known, axes=tuple(
        dataclasses.replace(a, sim=drawn) if a.name == "X" else a for a in known.axes))
    with connect_machine(truth) as machine:
        machine.configure()
        found = identify_axis(machine, "X", travel_mm=20.0)
        machine.stop()
    gains = place_loop(found, x).gains
    fit = found.fit.model
    model = MotorModelConfig(fit.time_constant_s, fit.speed_per_volt_counts_s,
                             max(0.0, fit.coulomb_v), fit.supply_v)

    def with_x(config: MachineConfig, **changes: object) -> MachineConfig:
        return dataclasses.replace(config, axes=tuple(
            dataclasses.replace(a, **changes) if a.name == "X" else a for a in config.axes))

    tuned = with_x(known, gains=gains, model=model)
    forecast = predict(tuned, DEMO, DEMO.read_text())
    assert forecast.motors["X"] == IDENTIFIED and forecast.motors["Y"] == SIMULATED
    measured = {a.name: a for a in _run(with_x(truth, gains=gains)).axes}

    def close(predicted: float, got: float) -> bool:
        return abs(predicted - got) <= max(0.1 * got, 2.0)

    for axis in forecast.report.axes:
        got = measured[axis.name]
        assert close(axis.max_error_counts, got.max_error_counts), (axis, got)
        assert close(axis.rms_error_counts, got.rms_error_counts), (axis, got)
    slow = dataclasses.replace(model, time_constant_s=2 * model.time_constant_s)
    off = {a.name: a for a in predict(with_x(tuned, model=slow), DEMO,
                                      DEMO.read_text()).report.axes}["X"]
    assert not close(off.max_error_counts, measured["X"].max_error_counts), (
        "a model twice as slow is seen to be off")


# --- each line's peak -------------------------------------------------------------------------

def test_each_lines_peak_is_the_largest_error_of_the_ticks_it_executed(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """With a diagnostics line every servo tick, each program line's peak equals the largest
    |desired - actual| of the ticks the plan gives that line, computed apart; the same
    ticks in 10 ms periods give each line the peak of every period one of its ticks is in
    (a period spanning two lines counts for both), the largest the device's own statistic."""
    config = load_config(default_machine())
    monkeypatch.setattr(watch, "DIAGNOSTICS_PERIOD_S", config.servo_period_s)
    monkeypatch.setattr(watch, "TRACE_POINTS", 10**6)
    with connect_session(config) as session:
        session.home()
        prepared = session.prepare(DEMO, text=DEMO.read_text())
        dense, trace = session.run(prepared)
        session.shutdown()
    exact: dict[int, dict[str, int]] = {}
    for name in prepared.plan.axes:
        times, desired, actual = trace.arrays(name)
        counted = times > 0  # the devices' statistics count from the first tick of the run
        for time_s, error in zip(times[counted], np.abs(desired - actual)[counted], strict=True):
            line = line_at(prepared.plan, min(float(time_s), prepared.plan.duration_s - 1e-9))
            row = exact.setdefault(line, dict.fromkeys(prepared.plan.axes, 0))
            row[name] = max(row[name], int(error))
    got = {peak.line: dict(peak.peak_error_counts) for peak in dense.line_peaks}
    assert got == exact
    # The same ticks in 10 ms diagnostics periods: each period's peak counts for every line
    # one of its ticks executed.
    plan, window = prepared.plan, 10
    coarse = Trace(tick_s=trace.tick_s, start_tick=trace.start_tick)
    expected: dict[int, dict[str, int]] = {}
    for name in plan.axes:
        clock = trace.column(trace.clock, name)
        errors = np.abs(trace.column(trace.desired, name) - trace.column(trace.actual, name))
        errors[clock <= trace.start_tick] = 0  # not counted before the run's first tick
        for first in range(0, clock.size, window):
            ticks, worst = clock[first:first + window], int(errors[first:first + window].max())
            coarse.clock.setdefault(name, array("q")).append(int(ticks[-1]))
            coarse.peak.setdefault(name, array("q")).append(worst)
            for tick in ticks:
                time_s = (int(tick) - trace.start_tick) * trace.tick_s
                line = line_at(plan, min(max(time_s, 0.0), plan.duration_s - 1e-9))
                row = expected.setdefault(line, dict.fromkeys(plan.axes, 0))
                row[name] = max(row[name], worst)

    def segments(ticks: npt.NDArray[np.int64]) -> npt.NDArray[np.int64]:
        times = np.clip((ticks - trace.start_tick) * trace.tick_s, 0.0,
                        plan.duration_s - 1e-9)
        return np.maximum(np.searchsorted(plan.start_time_s, times, side="right") - 1, 0)

    spans = {peak.line: dict(peak.peak_error_counts)
             for peak in line_peaks(plan, coarse, segments)}
    assert spans == expected
    assert any(spans[line] != got[line] for line in got), "periods that span two lines"
    for axis in dense.axes:
        assert max(row[axis.name] for row in spans.values()) == axis.max_error_counts


# --- the machine file --------------------------------------------------------------------------

def test_tune_auto_writes_a_model_table_the_machine_file_reads(tmp_path: Path) -> None:
    path = _machine_file(tmp_path)
    text = path.read_text()
    model = MotorModelConfig(0.0212345678, 904.41234, 0.32734, 12.0)
    once = write_tuning(text, "Y", PidGains(1.14, 12.0, 0.00734), ["identified"], model)
    assert parse_config(once, path=path).axis("Y").model == MotorModelConfig(
        0.0212346, 904.412, 0.32734, 12.0)
    again = write_tuning(once, "Y", PidGains(1.14, 12.0, 0.00734), ["identified again"],
                         dataclasses.replace(model, coulomb_v=-0.01))
    assert again.count("model = ") == 1
    read = parse_config(again, path=path)
    assert read.axis("Y").model == MotorModelConfig(0.0212346, 904.412, 0.0, 12.0)
    assert read.axis("X").model is None


@pytest.mark.parametrize(("model", "problem"), [
    ("{ time_constant_s = 0.02, speed_per_volt_counts_s = 900, coulomb_v = 0.3 }",
     "axes.X.model.supply_v: missing"),
    ("{ time_constant_s = 0, speed_per_volt_counts_s = 900, coulomb_v = 0.3, supply_v = 12 }",
     "axes.X.model.time_constant_s: 0"),
    ("{ time_constant_s = 0.02, speed_per_volt_counts_s = 900, coulomb_v = 12, supply_v = 12 }",
     "axes.X.model.coulomb_v: 12.0 V is not below supply_v (12.0 V)"),
])
def test_a_bad_model_table_is_refused_naming_its_key(tmp_path: Path, model: str,
                                                     problem: str) -> None:
    path = _machine_file(tmp_path, ("sim = { start_mm = 100.0 }",
                                    f"sim = {{ start_mm = 100.0 }}\nmodel = {model}"))
    with pytest.raises(ConfigError) as caught:
        load_config(path)
    assert problem in str(caught.value)


# --- the command --------------------------------------------------------------------------------

def test_run_predict_only_prints_the_prediction_and_moves_nothing(tmp_path: Path) -> None:
    machine = _machine_file(tmp_path)
    runner = CliRunner()
    base = ["run", str(DEMO), "--machine", str(machine), "--no-plot", "--quiet"]
    done = runner.invoke(app, [*base, "--predict-only", "--tolerance", "1"])
    assert done.exit_code == 0, done.output
    assert "motors       X, Y, Z: its sim table (not identified)" in done.output
    assert "tolerance      1 mm: every line within it" in done.output
    assert "executed time" not in done.output, "nothing ran"
    refused = runner.invoke(app, [*base, "--predict-only", "--tolerance", "0.05"])
    assert refused.exit_code == 2, refused.output
    assert "line(s) predicted beyond it: 5 (X 0.05" in refused.output
    assert "the run is refused, nothing moved" in refused.output
    bad = runner.invoke(app, [*base, "--predict", "--tolerance", "-1"])
    assert bad.exit_code == 2 and "--tolerance: -1.0 is not a following error" in bad.output
    assert not (tmp_path / "mill.var").exists(), "no run, no parameter file"


def test_run_predict_puts_the_prediction_beside_the_measured(tmp_path: Path) -> None:
    machine = _machine_file(tmp_path)
    report = tmp_path / "report.json"
    done = CliRunner().invoke(app, ["run", str(DEMO), "--machine", str(machine), "--no-plot",
                                    "--quiet", "--predict", "--report", str(report)])
    assert done.exit_code == 0, done.output
    assert done.output.index("predicted following error") < done.output.index("executed time")
    assert "predicted vs measured following error (counts):" in done.output
    assert "lines of the largest peaks (predicted | measured; 13 lines" in done.output
    figures = json.loads(report.read_text())
    prediction = figures["prediction"]
    assert prediction["completed"] and prediction["motors"] == dict.fromkeys("XYZ", SIMULATED)
    assert [p["line"] for p in prediction["line_peaks"]] == [
        p["line"] for p in figures["line_peaks"]] == list(range(5, 18))
    for predicted, measured in zip(prediction["axes"], figures["axes"], strict=True):
        assert abs(predicted["max_error_counts"] - measured["max_error_counts"]) <= 1
        assert math.isclose(predicted["rms_error_counts"], measured["rms_error_counts"],
                            rel_tol=0.01)


def test_run_predict_refuses_a_program_beyond_the_tolerance_before_anything_moves(
        tmp_path: Path) -> None:
    machine = _machine_file(tmp_path)
    done = CliRunner().invoke(app, ["run", str(DEMO), "--machine", str(machine), "--no-plot",
                                    "--quiet", "--predict", "--tolerance", "0.03"])
    assert done.exit_code == 2, done.output
    assert "homing" not in done.output and "executed time" not in done.output
