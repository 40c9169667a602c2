"""``usbmotion tune --auto``: identify one axis, place its loop, check it, and (with
``--write``) put the gains and the model into the machine file."""

from __future__ import annotations

import json
import math
from typing import TYPE_CHECKING, Any

import typer

from usbmotion.cli.exits import EXIT_BAD_INPUT, EXIT_FAULT, fail

if TYPE_CHECKING:
    from usbmotion.autotune.identify import Identification
    from usbmotion.autotune.model import AxisModel, PhysicalModel
    from usbmotion.autotune.verify import Placement
    from usbmotion.host.config import AxisConfig, MachineConfig


def auto_tune(config: MachineConfig, axis_config: AxisConfig, *, travel_mm: float,
              excite_s: float, bandwidth_hz: float | None, objective: str, write: bool,
              as_json: bool) -> None:
    """Run ``tune --auto`` on one axis and print (or write) what it found."""
    from usbmotion.autotune.identify import identify_axis  # noqa: PLC0415
    from usbmotion.autotune.verify import check_on_axis, place_loop  # noqa: PLC0415
    from usbmotion.cli.machines import default_machine  # noqa: PLC0415
    from usbmotion.errors import ArgumentError, UsbMotionError  # noqa: PLC0415
    from usbmotion.sim.machine import connect_machine  # noqa: PLC0415

    if axis_config.stepper is not None:
        fail("tune", f"--auto identifies a DC servo's motor and places its PID; axis"
             f" {axis_config.name} is a stepper ({axis_config.drive.words}): its limits are"
             " checked against its step rate and torque (usbmotion tune --reach), a closed"
             " loop's gains tried with usbmotion tune --kp", EXIT_BAD_INPUT)
    if write and config.path.resolve() == default_machine().resolve():
        fail("tune", f"--write: {config.path} is the built-in machine's file, part of the"
             " package; copy it (examples/machine.toml is the same), pass it with --machine"
             " FILE and write that", EXIT_BAD_INPUT)
    name = axis_config.name
    try:
        with connect_machine(config) as connected:
            connected.configure()
            try:
                found = identify_axis(connected, name, travel_mm=travel_mm,
                                      duration_s=excite_s)
                chosen = place_loop(found, axis_config, bandwidth_hz=bandwidth_hz,
                                    objective=objective)
                placed = check_on_axis(connected, name, found, chosen)
            finally:
                connected.stop()
    except ArgumentError as error:
        fail("tune", str(error), EXIT_BAD_INPUT)
    except UsbMotionError as error:
        fail("tune", str(error), EXIT_FAULT)
    physical = _physical(found, axis_config)
    figures = _figures(config, axis_config, found, placed, physical, objective)
    if write:
        _write(config, axis_config, found, placed, physical)
        figures["written_to"] = str(config.path)
    if as_json:
        typer.echo(json.dumps(_finite(figures), indent=2, allow_nan=False))
        return
    _print(figures, axis_config)


def _finite(value: Any) -> Any:
    """``value`` with every NaN or infinite float as None (JSON has neither)."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {key: _finite(item) for key, item in value.items()}
    if isinstance(value, list | tuple):
        return [_finite(item) for item in value]
    return value


def _physical(found: Identification, axis_config: AxisConfig) -> PhysicalModel | None:
    """The model in SI figures when the file gives the motor's torque constant and
    resistance (its ``sim`` table)."""
    from usbmotion.host.config import SimMotorConfig  # noqa: PLC0415

    sim = axis_config.sim
    if not isinstance(sim, SimMotorConfig):
        return None
    motor = sim.model()
    return found.fit.model.physical(torque_constant_nm_per_a=motor.torque_constant_nm_per_a,
                                    resistance_ohm=motor.resistance_ohm,
                                    counts_per_revolution=motor.counts_per_revolution)


def _physical_sigmas(found: Identification, axis_config: AxisConfig) -> dict[str, float]:
    """One standard error of each SI figure, from the fit's covariance (linearised)."""
    from usbmotion.host.config import SimMotorConfig  # noqa: PLC0415

    sim = axis_config.sim
    if not isinstance(sim, SimMotorConfig):
        return {}
    motor = sim.model()

    def si(model: AxisModel) -> PhysicalModel:
        return model.physical(torque_constant_nm_per_a=motor.torque_constant_nm_per_a,
                              resistance_ohm=motor.resistance_ohm,
                              counts_per_revolution=motor.counts_per_revolution)

    fit = found.fit
    return {"inertia_kg_m2": fit.sigma_of(lambda m: si(m).inertia_kg_m2),
            "viscous_nm_s_per_rad": fit.sigma_of(lambda m: si(m).viscous_nm_s_per_rad),
            "load_torque_nm": fit.sigma_of(lambda m: si(m).load_torque_nm)}


def _figures(config: MachineConfig, axis_config: AxisConfig, found: Identification,
             placed: Placement, physical: PhysicalModel | None,
             objective: str) -> dict[str, Any]:
    from usbmotion.autotune.verify import predicted_versus_measured  # noqa: PLC0415

    scale = axis_config.counts_per_mm
    fit = found.fit
    model = fit.model
    chosen = placed.design
    out: dict[str, Any] = {
        "axis": axis_config.name,
        "machine": str(config.path),
        "identification": {
            "duration_s": float(found.times_s[-1]) if found.times_s.size else 0.0,
            "ticks": int(found.times_s.size),
            "servo_period_s": found.tick_s,
            "origin_mm": found.origin_mm,
            "allowed_from_origin_mm": [(found.low_counts - found.origin_counts) / scale,
                                       (found.high_counts - found.origin_counts) / scale],
            "reached_from_origin_mm": [
                (found.reached_low_counts - found.origin_counts) / scale,
                (found.reached_high_counts - found.origin_counts) / scale],
            "probe_v": found.probe_v,
            "probe_counts": found.probe_counts,
            "stretches": fit.segments,
            "samples": fit.samples,
            "rms_residual_counts": fit.rms_residual_counts,
            "uncertainty": fit.uncertainty,
        },
        "model": {
            "time_constant_s": model.time_constant_s,
            "time_constant_sigma_s": fit.time_constant_sigma_s,
            "speed_per_volt_counts_s": model.speed_per_volt_counts_s,
            "speed_per_volt_sigma_counts_s": fit.speed_per_volt_sigma_counts_s,
            "coulomb_v": model.coulomb_v,
            "coulomb_sigma_v": fit.coulomb_sigma_v,
            "accel_per_volt_counts_s2": model.accel_per_volt_counts_s2,
            "supply_v": model.supply_v,
        },
        "gains": {"kp": chosen.gains.kp, "ki": chosen.gains.ki, "kd": chosen.gains.kd},
        "loop": {
            "objective": objective,
            "bandwidth_hz": chosen.crossover_hz,
            "crossover_hz": chosen.margins.crossover_hz,
            "phase_margin_deg": chosen.margins.phase_margin_deg,
            "gain_margin_db": chosen.margins.gain_margin_db,
            "gain_reduction_margin_db": chosen.margins.gain_reduction_db,
            "stable": chosen.margins.stable,
        },
        "checks": {},
    }
    if physical is not None:
        sigmas = _physical_sigmas(found, axis_config)
        out["physical"] = {
            "torque_constant_nm_per_a": physical.torque_constant_nm_per_a,
            "resistance_ohm": physical.resistance_ohm,
            "inertia_kg_m2": physical.inertia_kg_m2,
            "inertia_sigma_kg_m2": sigmas["inertia_kg_m2"],
            "viscous_nm_s_per_rad": physical.viscous_nm_s_per_rad,
            "viscous_sigma_nm_s_per_rad": sigmas["viscous_nm_s_per_rad"],
            "load_torque_nm": physical.load_torque_nm,
            "load_torque_sigma_nm": sigmas["load_torque_nm"],
        }
    for check in (placed.step, placed.move):
        if check is None:
            continue
        pairs = predicted_versus_measured(check)
        entry: dict[str, Any] = {"distance_counts": check.distance_counts,
                                 "distance_mm": check.distance_counts / scale,
                                 "peak_output_v": [float(abs(check.predicted.output_v).max()),
                                                   float(abs(check.measured.output_v).max())]}
        for key, (predicted, measured) in pairs.items():
            entry[key] = {"predicted": predicted, "measured": measured}
        out["checks"][check.what] = entry
    return out


def _print(figures: dict[str, Any], axis_config: AxisConfig) -> None:
    ident, model, loop = figures["identification"], figures["model"], figures["loop"]
    low, high = ident["allowed_from_origin_mm"]
    reached_low, reached_high = ident["reached_from_origin_mm"]
    origin = ident["origin_mm"]
    echo = typer.echo
    where = f" (machine {origin:.3f} mm)" if origin is not None else ""
    echo(f"axis {figures['axis']}: identified from {ident['duration_s']:.2f} s of moves within"
         f" [{low:+.3f}, {high:+.3f}] mm of where it stood{where}; it went {reached_low:+.3f}"
         f" .. {reached_high:+.3f} mm; the probe's {ident['probe_v']:+.2f} V moved it"
         f" {ident['probe_counts']} counts")

    def pm(value: float, sigma: float, unit: str, digits: int = 4) -> str:
        share = f" ({sigma / abs(value) * 100:.2g} %)" if value else ""
        return f"{value:.{digits}g} {unit} +- {sigma:.2g}{share}"

    how = ("jackknife over the stretches" if ident["uncertainty"] == "jackknife"
           else "least squares")
    echo(f"model as the drive sees it (volts in, counts out; 1 sigma, {how}):")
    echo(f"  time constant        {pm(model['time_constant_s'] * 1000, model['time_constant_sigma_s'] * 1000, 'ms')}")  # noqa: E501
    echo(f"  speed per volt       {pm(model['speed_per_volt_counts_s'], model['speed_per_volt_sigma_counts_s'], 'counts/s per V')}")  # noqa: E501
    echo(f"  Coulomb voltage      {pm(model['coulomb_v'], model['coulomb_sigma_v'], 'V')}")
    echo(f"  accel per volt       {model['accel_per_volt_counts_s2']:.4g} counts/s^2 per V;"
         f" fit RMS {ident['rms_residual_counts']:.2f} counts over {ident['samples']} ticks"
         f" in {ident['stretches']} stretches from rest")
    physical = figures.get("physical")
    if physical is not None:
        echo(f"with the file's motor: Kt {physical['torque_constant_nm_per_a'] * 1000:.4g}"
             f" mNm/A, R {physical['resistance_ohm']:.4g} ohm:")
        echo(f"  inertia              {pm(physical['inertia_kg_m2'], physical['inertia_sigma_kg_m2'], 'kg m^2')}")  # noqa: E501
        echo(f"  viscous friction     {pm(physical['viscous_nm_s_per_rad'] * 1e6, physical['viscous_sigma_nm_s_per_rad'] * 1e6, 'uNm per rad/s')}")  # noqa: E501
        echo(f"  load torque          {pm(physical['load_torque_nm'] * 1000, physical['load_torque_sigma_nm'] * 1000, 'mNm')}")  # noqa: E501
    gains = figures["gains"]
    echo(f"gains for {loop['bandwidth_hz']:g} Hz: kp {gains['kp']:g} ki {gains['ki']:g}"
         f" kd {gains['kd']:g} (as the device holds them; least {loop['objective']} following"
         " error on a move over half the travel)")
    echo(f"loop: crossover {loop['crossover_hz']:.1f} Hz, phase margin"
         f" {loop['phase_margin_deg']:.1f} deg, gain margin {loop['gain_margin_db']:.1f} dB")
    echo(" " * 32 + "predicted".rjust(12) + "measured".rjust(12))
    for what, check in figures["checks"].items():
        echo(f"{what} {check['distance_counts']} counts ({check['distance_mm']:g} mm)"
             + (" there and back" if what == "move" else ""))
        for key, label, unit, factor in (
                ("overshoot_pct", "overshoot", "%", 1.0),
                ("settling_time_s", "settling time", "ms", 1000.0),
                ("peak_following_error_counts", "peak following error", "counts", 1.0),
                ("ise_counts2_s", "ISE", "counts^2 s", 1.0),
                ("ise_aligned_counts2_s", "ISE, tick's start", "counts^2 s", 1.0)):
            predicted = check[key]["predicted"] * factor
            measured = check[key]["measured"] * factor
            echo(f"  {(label + ' (' + unit + ')').ljust(30)}{predicted:12.4g}{measured:12.4g}")
    if "written_to" in figures:
        echo(f"written to {figures['written_to']}: axes.{axis_config.name}.gains and"
             f" axes.{axis_config.name}.model (usbmotion run --predict plays programs on it),"
             " the identification's record as comments")


def _write(config: MachineConfig, axis_config: AxisConfig, found: Identification,
           placed: Placement, physical: PhysicalModel | None) -> None:
    from usbmotion.autotune.machine_file import write_tuning_file  # noqa: PLC0415
    from usbmotion.errors import ConfigError  # noqa: PLC0415
    from usbmotion.sim.urls import URL_CHECKS  # noqa: PLC0415

    path = config.path
    try:
        write_tuning_file(path, axis_config.name, found, placed, physical,
                          url_checks=URL_CHECKS)
    except ConfigError as error:
        fail("tune", f"--write: {error}", EXIT_BAD_INPUT)
    except OSError as error:
        fail("tune", f"--write: cannot write {path}: {error.strerror or error}", EXIT_FAULT)


__all__ = ["auto_tune"]
