"""Automatic tuning against the relay / Ziegler-Nichols baseline on random simulated axes.

    python benchmarks/autotune.py [--machines 17] [--seed 31] [--travel-mm 20] [--json]

Each machine is the built-in simulated XYZ machine whose three motors are drawn at random
(fixed seeds): inertia, viscous friction, load torque and torque constant each uniformly
within +-50 % of the axis's default (X and Y: the default gearmotor; Z: its heavier load),
winding resistance and supply as they are; an axis's max_velocity_mm_s and max_accel_mm_s2
are lowered, where the drawn motor cannot reach them, to what it reaches keeping the
machine file's 10 % margin (both methods then run the same plan). On every axis:

1. ``tune --auto``'s steps through the library (``usbmotion.autotune``): identification
   within ``--travel-mm`` of where the axis stands after power-up, gains placed for the
   best bandwidth, a step and a move on the axis, each beside the model's prediction.
   The identified model is compared with the truth (the drawn motor's figures): the
   three identifiable combinations (time constant, speed per volt, Coulomb voltage), and
   inertia, viscous friction and load torque given the true torque constant and
   resistance (what a datasheet gives; the torque constant is not identifiable from
   volts and counts alone: ``usbmotion.autotune.model``).
2. The baseline, as Klipper's PID_CALIBRATE and LinuxCNC's at_pid tune: relay feedback,
   then Ziegler-Nichols' classic PID rules. The relay is the device's own loop: position
   mode with a proportional gain so large (``999e6`` V/count) that the output is the
   ceiling's sign of the error (0 at no error: a one-count dead zone), the ceiling the
   supply (full power, as PID_CALIBRATE heats); the axis oscillates about a setpoint 5
   counts away for 1 s; over the last 0.7 s the amplitude ``A`` (half the peak to peak,
   counts) and the period ``Tu`` (between the output's rising switches) give
   ``Ku = 4 h / (pi A)``, and ``Kp = 0.6 Ku``, ``Ki = Kp / (Tu / 2)``,
   ``Kd = Kp Tu / 8``, rounded to the device's 3 digits.
3. Demo 1 (``usbmotion.demos.demo_path(1)``) run on the machine homed, once with the
   automatic gains on every axis and once with the baseline's: the integrated squared
   following error of each axis (from the device's statistics, every tick: RMS^2 x
   ticks x period, counts^2 s), and its ratio baseline / automatic.

Targets (issue 31): parameters within 5 %; on every axis the step's overshoot at most 5 %
and its settling time within 10 % of the prediction; ISE at least 2 x lower than the
baseline's.
"""

from __future__ import annotations

import dataclasses
import math
import statistics
import sys
import time
from typing import Any

import numpy as np

from _common import argument_parser, emit, parse_arguments
from usbmotion.autotune.identify import identify_axis
from usbmotion.autotune.loop import (
    following_ise,
    margins,
    overshoot_pct,
    quantise,
    simulate_closed_loop,
)
from usbmotion.autotune.model import AxisModel, simulated_model
from usbmotion.autotune.verify import check_on_axis, place_loop, step_and_move
from usbmotion.cli.machines import default_machine
from usbmotion.demos import demo_path
from usbmotion.errors import UsbMotionError
from usbmotion.host.config import (
    AxisConfig,
    MachineConfig,
    PidGains,
    load_config,
    simulated_reach,
)
from usbmotion.host.device import ControlMode, Diagnostics
from usbmotion.host.machine import Machine
from usbmotion.motion.sampler import sample_axis
from usbmotion.protocol import CallNumber
from usbmotion.sim.machine import SimulatedMachine, connect_session

SPREAD = 0.5
"""Each drawn figure is the default times a factor uniform in [1 - SPREAD, 1 + SPREAD]."""
RELAY_GAIN = 999e6
RELAY_S = 1.0
RELAY_SETTLE_S = 0.3
RELAY_OFFSET_COUNTS = 5


def draw_machine(base: MachineConfig, rng: np.random.Generator) -> MachineConfig:
    """``base`` with each axis's motor drawn at random (and its limits within reach)."""
    axes = []
    for axis in base.axes:
        sim = axis.sim
        assert sim is not None
        factors = rng.uniform(1 - SPREAD, 1 + SPREAD, size=4)
        drawn = dataclasses.replace(
            sim,
            inertia_kg_m2=float(f"{sim.inertia_kg_m2 * factors[0]:.4g}"),
            viscous_friction_unm_per_rad_s=float(
                f"{sim.viscous_friction_unm_per_rad_s * factors[1]:.4g}"),
            load_torque_mnm=float(f"{sim.load_torque_mnm * factors[2]:.4g}"),
            torque_constant_mnm_per_a=float(f"{sim.torque_constant_mnm_per_a * factors[3]:.4g}"),
        )
        reach = simulated_reach(drawn, axis.counts_per_mm)
        velocity = min(axis.max_velocity_mm_s, math.floor(reach.usable_velocity_mm_s))
        accel = min(axis.max_accel_mm_s2, math.floor(reach.usable_accel_mm_s2(velocity)))
        axes.append(dataclasses.replace(axis, sim=drawn, max_velocity_mm_s=float(velocity),
                                        max_accel_mm_s2=float(accel),
                                        max_jerk_mm_s3=20.0 * accel))
    return dataclasses.replace(base, axes=tuple(axes))


def truth(axis: AxisConfig) -> AxisModel:
    """The drawn motor's model, from the figures the device simulates (4 digits)."""
    return simulated_model(axis)


def relay_gains(machine: Machine, axis: str) -> tuple[PidGains, dict[str, float]]:
    """The relay experiment on ``axis`` and Ziegler-Nichols' classic PID from it."""
    client = machine.axis(axis).client
    supply = client.sim_value(CallNumber.SET_SIM_SOURCE_VOLTAGE)
    records: list[Diagnostics] = []
    with client.listening(diagnostics=records.append):
        client.set_gains(kp=RELAY_GAIN, ki=0.0, kd=0.0)
        client.set_control_mode(ControlMode.POSITION)
        client.set_servo_enable(True)
        setpoint = client.status().actual_counts + RELAY_OFFSET_COUNTS
        client.set_diagnostics_interval(1)
        client.add_setpoint(setpoint)
        machine.clock.sleep(RELAY_S)
        client.set_diagnostics_interval(0)
        client.sync()
    machine.set_mode(ControlMode.POSITION, axes=[axis])
    tick_s = machine.config.servo_period_s
    tail = records[round(RELAY_SETTLE_S / tick_s):]
    position = np.array([r.actual_counts - setpoint for r in tail], dtype=np.float64)
    output = np.array([r.output_mv for r in tail], dtype=np.float64)
    rising = np.nonzero((output[1:] > 0) & (output[:-1] <= 0))[0]
    amplitude = (float(position.max()) - float(position.min())) / 2
    period_s = float(np.mean(np.diff(rising))) * tick_s if rising.size > 1 else math.nan
    ultimate = 4 * supply / (math.pi * amplitude) if amplitude > 0 else math.inf
    kp = 0.6 * ultimate
    gains = quantise(PidGains(kp, kp / (period_s / 2), kp * period_s / 8))
    return gains, {"relay_v": supply, "amplitude_counts": amplitude, "period_s": period_s,
                   "ultimate_gain_v_per_count": ultimate}


def demo_ise(config: MachineConfig, gains: dict[str, PidGains]) -> dict[str, Any]:
    """Demo 1 on ``config`` with ``gains``: per axis the ISE the device's statistics
    measured (counts^2 s) and the peak error, and, on the drawn motors' exact models, the
    predicted ISE both ways (``usbmotion.autotune.loop.following_ise``)."""
    tuned = dataclasses.replace(config, axes=tuple(
        dataclasses.replace(a, gains=gains[a.name]) for a in config.axes))
    tick_s = config.servo_period_s
    try:
        with connect_session(tuned) as session:
            session.home()
            prepared = session.prepare(demo_path(1))
            report, _ = session.run(prepared)
    except UsbMotionError as error:
        return {"completed": False, "reason": str(error)}
    if not report.completed:
        return {"completed": False, "reason": report.stop_reason}
    axes: dict[str, Any] = {}
    measured = {a.name: a for a in report.axes}
    for index, name in enumerate(prepared.plan.axes):
        axis = config.axis(name)
        desired = sample_axis(prepared.plan, index, period_s=config.motion_period_s,
                              counts_per_mm=axis.counts_per_mm).astype(np.float64)
        desired = np.repeat(desired, config.motion_scalar)
        run = simulate_closed_loop(truth(axis), gains[name], desired, tick_s=tick_s,
                                   start_counts=float(desired[0]))
        result = measured[name]
        axes[name] = {
            "ise_counts2_s": result.rms_error_counts ** 2 * result.ticks * tick_s,
            "peak_counts": result.max_error_counts,
            "predicted_ise_counts2_s": following_ise(run, tick_s=tick_s, objective="device"),
            "predicted_aligned_ise_counts2_s": following_ise(run, tick_s=tick_s),
        }
    return {"completed": True, "axes": axes}


def relative(found: float, true: float) -> float:
    return found / true - 1.0


def one_machine(base: MachineConfig, index: int, seed: int, travel_mm: float
                ) -> list[dict[str, Any]]:
    """Every axis of the ``index``-th random machine: identification, placement, checks,
    baseline, demo 1 both ways."""
    rng = np.random.default_rng([seed, index])
    config = draw_machine(base, rng)
    rows: dict[str, dict[str, Any]] = {}
    auto: dict[str, PidGains] = {}
    device_objective: dict[str, PidGains] = {}
    baseline: dict[str, PidGains] = {}
    with SimulatedMachine.connect(config) as machine:
        machine.configure()
        for axis in config.axes:
            row: dict[str, Any] = {"machine": index, "axis": axis.name}
            assert axis.sim is not None
            row["drawn"] = {"inertia_kg_m2": axis.sim.inertia_kg_m2,
                            "viscous_unm_per_rad_s": axis.sim.viscous_friction_unm_per_rad_s,
                            "load_torque_mnm": axis.sim.load_torque_mnm,
                            "torque_constant_mnm_per_a": axis.sim.torque_constant_mnm_per_a}
            direction = 1.0 if axis.homing.direction < 0 else -1.0
            started = time.perf_counter()
            found = identify_axis(machine, axis.name, travel_mm=direction * travel_mm)
            chosen = place_loop(found, axis)
            placed = check_on_axis(machine, axis.name, found, chosen)
            row["tune_wall_s"] = time.perf_counter() - started
            fit, exact = found.fit.model, truth(axis)
            motor = axis.sim.model()
            physical = fit.physical(torque_constant_nm_per_a=motor.torque_constant_nm_per_a,
                                    resistance_ohm=motor.resistance_ohm,
                                    counts_per_revolution=motor.counts_per_revolution)
            row["errors"] = {
                "time_constant": relative(fit.time_constant_s, exact.time_constant_s),
                "speed_per_volt": relative(fit.speed_per_volt_counts_s,
                                           exact.speed_per_volt_counts_s),
                "coulomb_v": relative(fit.coulomb_v, exact.coulomb_v),
                "inertia": relative(physical.inertia_kg_m2, motor.inertia_kg_m2),
                "viscous": relative(physical.viscous_nm_s_per_rad, motor.viscous_nm_s_per_rad),
                "viscous_of_damping": ((physical.viscous_nm_s_per_rad
                                        - motor.viscous_nm_s_per_rad)
                                       / motor.damping_nm_s_per_rad),
                "load_torque": relative(physical.load_torque_nm, motor.load_torque_nm),
            }
            row["z_scores"] = {
                "time_constant": ((fit.time_constant_s - exact.time_constant_s)
                                  / found.fit.time_constant_sigma_s),
                "speed_per_volt": ((fit.speed_per_volt_counts_s - exact.speed_per_volt_counts_s)
                                   / found.fit.speed_per_volt_sigma_counts_s),
                "coulomb_v": (fit.coulomb_v - exact.coulomb_v) / found.fit.coulomb_sigma_v,
            }
            row["uncertainty"] = found.fit.uncertainty
            row["sigmas"] = {
                "time_constant": found.fit.time_constant_sigma_s / fit.time_constant_s,
                "speed_per_volt": (found.fit.speed_per_volt_sigma_counts_s
                                   / fit.speed_per_volt_counts_s),
                "coulomb_v": found.fit.coulomb_sigma_v / fit.coulomb_v,
            }
            step = placed.step
            assert step is not None
            row["auto"] = {
                "gains": dataclasses.asdict(chosen.gains),
                "bandwidth_hz": chosen.crossover_hz,
                "phase_margin_deg": chosen.margins.phase_margin_deg,
                "gain_margin_db": chosen.margins.gain_margin_db,
                "step_counts": step.distance_counts,
                "overshoot_pct": [step.predicted_figures.overshoot_pct,
                                  step.measured_figures.overshoot_pct],
                "settling_s": [step.predicted_figures.settling_time_s,
                               step.measured_figures.settling_time_s],
            }
            gains, relay = relay_gains(machine, axis.name)
            found_margins = margins(exact, gains, tick_s=config.servo_period_s)
            shape, _ = step_and_move(found.high_counts - found.low_counts,
                                     counts_per_mm=axis.counts_per_mm,
                                     max_velocity_mm_s=axis.max_velocity_mm_s,
                                     max_accel_mm_s2=axis.max_accel_mm_s2,
                                     tick_s=config.servo_period_s)
            zn_step = simulate_closed_loop(exact, gains, shape, tick_s=config.servo_period_s)
            row["baseline"] = {"gains": dataclasses.asdict(gains), **relay,
                               "step_overshoot_pct": overshoot_pct(zn_step, 0.0,
                                                                   float(shape[-1])),
                               "stable": found_margins.stable,
                               "phase_margin_deg": found_margins.phase_margin_deg,
                               "gain_margin_db": found_margins.gain_margin_db}
            auto[axis.name] = chosen.gains
            lagging = place_loop(found, axis, objective="device")
            device_objective[axis.name] = lagging.gains
            row["auto_device_objective"] = {"gains": dataclasses.asdict(lagging.gains),
                                            "bandwidth_hz": lagging.crossover_hz,
                                            "phase_margin_deg": lagging.margins.phase_margin_deg}
            baseline[axis.name] = gains
            rows[axis.name] = row
        machine.stop()
    runs = {"auto": demo_ise(config, auto), "baseline": demo_ise(config, baseline),
            "device": demo_ise(config, device_objective)}
    for name, row in rows.items():
        demo: dict[str, Any] = {}
        for label, run in runs.items():
            demo[f"{label}_completed"] = run["completed"]
            demo[f"{label}_reason"] = run.get("reason", "")
            figures = run["axes"][name] if run["completed"] else {}
            for key in ("ise_counts2_s", "peak_counts", "predicted_ise_counts2_s",
                        "predicted_aligned_ise_counts2_s"):
                demo[f"{label}_{key}"] = figures.get(key, math.nan)
        if runs["auto"]["completed"] and runs["baseline"]["completed"]:
            demo["ratio"] = demo["baseline_ise_counts2_s"] / demo["auto_ise_counts2_s"]
            demo["aligned_ratio"] = (demo["baseline_predicted_aligned_ise_counts2_s"]
                                     / demo["auto_predicted_aligned_ise_counts2_s"])
        if runs["device"]["completed"] and runs["baseline"]["completed"]:
            demo["device_ratio"] = (demo["baseline_ise_counts2_s"]
                                    / demo["device_ise_counts2_s"])
            demo["device_aligned_ratio"] = (demo["baseline_predicted_aligned_ise_counts2_s"]
                                            / demo["device_predicted_aligned_ise_counts2_s"])
        row["demo1"] = demo
    return list(rows.values())


def summary(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """The figures over every axis."""
    out: dict[str, Any] = {"axes": len(rows)}
    for key in ("time_constant", "speed_per_volt", "coulomb_v", "inertia", "viscous",
                "viscous_of_damping", "load_torque"):
        errors = [abs(r["errors"][key]) for r in rows]
        out[f"{key}_error_max"] = max(errors)
        out[f"{key}_error_median"] = statistics.median(errors)
        out[f"{key}_within_5pct"] = sum(e <= 0.05 for e in errors)
    for key in ("time_constant", "speed_per_volt", "coulomb_v"):
        scores = [abs(r["z_scores"][key]) for r in rows]
        out[f"{key}_within_2_sigma"] = sum(z <= 2 for z in scores)
        out[f"{key}_sigma_median"] = statistics.median(r["sigmas"][key] for r in rows)
    out["jackknifed"] = sum(r["uncertainty"] == "jackknife" for r in rows)
    overshoots = [r["auto"]["overshoot_pct"][1] for r in rows]
    gaps = []
    for r in rows:
        predicted, measured = r["auto"]["settling_s"]
        gaps.append(abs(measured / predicted - 1) if predicted and not math.isnan(measured)
                    and not math.isnan(predicted) else math.inf)
    out["overshoot_max_pct"] = max(overshoots)
    out["overshoot_within_5pct"] = sum(o <= 5.0 for o in overshoots)
    out["settling_gap_max"] = max(gaps)
    out["settling_within_10pct"] = sum(g <= 0.10 for g in gaps)
    out["both_step_targets"] = sum(o <= 5.0 and g <= 0.10
                                   for o, g in zip(overshoots, gaps, strict=True))
    for key in ("ratio", "aligned_ratio", "device_ratio", "device_aligned_ratio"):
        done = [r["demo1"][key] for r in rows if key in r["demo1"]]
        out[f"demo1_{key}_compared"] = len(done)
        out[f"demo1_{key}_min"] = min(done) if done else math.nan
        out[f"demo1_{key}_median"] = statistics.median(done) if done else math.nan
        out[f"demo1_{key}_max"] = max(done) if done else math.nan
        out[f"demo1_{key}_at_least_2"] = sum(x >= 2 for x in done)
    for label in ("auto", "baseline", "device"):
        out[f"demo1_{label}_faulted_axes"] = sum(not r["demo1"][f"{label}_completed"]
                                                 for r in rows)
    gaps = [abs(r["demo1"]["auto_predicted_ise_counts2_s"] / r["demo1"]["auto_ise_counts2_s"]
                - 1) for r in rows if r["demo1"]["auto_completed"]]
    out["demo1_prediction_gap_max"] = max(gaps) if gaps else math.nan
    out["baseline_unstable"] = sum(not r["baseline"]["stable"] for r in rows)
    out["baseline_phase_margin_deg_median"] = statistics.median(
        r["baseline"]["phase_margin_deg"] for r in rows)
    out["baseline_step_overshoot_pct_median"] = statistics.median(
        r["baseline"]["step_overshoot_pct"] for r in rows)
    out["baseline_step_overshoot_pct_max"] = max(r["baseline"]["step_overshoot_pct"]
                                                 for r in rows)
    out["auto_phase_margin_deg_min"] = min(r["auto"]["phase_margin_deg"] for r in rows)
    out["auto_gain_margin_db_min"] = min(r["auto"]["gain_margin_db"] for r in rows)
    out["tune_wall_s_median"] = statistics.median(r["tune_wall_s"] for r in rows)
    return out


def text(figures: dict[str, Any]) -> str:
    s = figures["summary"]
    n = s["axes"]
    lines = [f"{n} simulated axes ({figures['machines']} machines, seed {figures['seed']},"
             f" travel {figures['travel_mm']:g} mm), {figures['wall_s']:.0f} s wall",
             "identification error |found/true - 1|: max (median), axes within 5 %"]
    for key, label in (("time_constant", "time constant"), ("speed_per_volt", "speed per volt"),
                       ("coulomb_v", "Coulomb voltage"),
                       ("inertia", "inertia (Kt, R given)"),
                       ("viscous", "viscous friction (Kt, R given)"),
                       ("viscous_of_damping", "  the same, share of Kt^2/R + b"),
                       ("load_torque", "load torque (Kt, R given)")):
        lines.append(f"  {label:32} {s[key + '_error_max'] * 100:7.2f} %"
                     f" ({s[key + '_error_median'] * 100:.2f} %)  {s[key + '_within_5pct']}/{n}")
    lines.append("the printed standard errors (jackknife over the stretches on"
                 f" {s['jackknifed']}/{n} axes): the error within 2 sigma on " + ", ".join(
                     f"{label} {s[key + '_within_2_sigma']}/{n} (sigma median"
                     f" {s[key + '_sigma_median'] * 100:.2f} %)"
                     for key, label in (("time_constant", "tau"), ("speed_per_volt", "g"),
                                        ("coulomb_v", "C"))))
    lines.append(f"step: overshoot <= 5 % on {s['overshoot_within_5pct']}/{n} (max"
                 f" {s['overshoot_max_pct']:.2f} %); settling within 10 % of the prediction on"
                 f" {s['settling_within_10pct']}/{n} (worst gap {s['settling_gap_max'] * 100:.1f}"
                 f" %); both on {s['both_step_targets']}/{n}")
    for key, label in (
            ("ratio", "demo 1 ISE as the device counts it, baseline / auto (measured)"),
            ("aligned_ratio", "demo 1 ISE at the tick's start, baseline / auto (predicted)"),
            ("device_ratio", "demo 1 ISE as the device counts it, baseline / auto with"
             " --objective device (measured)"),
            ("device_aligned_ratio", "demo 1 ISE at the tick's start, baseline / auto with"
             " --objective device (predicted)")):
        lines.append(f"{label}: median {s[f'demo1_{key}_median']:.3g}, range"
                     f" {s[f'demo1_{key}_min']:.3g} .. {s[f'demo1_{key}_max']:.3g};"
                     f" >= 2 on {s[f'demo1_{key}_at_least_2']}/{s[f'demo1_{key}_compared']}")
    lines.append(f"demo 1 runs that faulted (axes): auto {s['demo1_auto_faulted_axes']},"
                 f" baseline {s['demo1_baseline_faulted_axes']}, --objective device"
                 f" {s['demo1_device_faulted_axes']}; the model's prediction of the measured"
                 f" ISE (auto) within {s['demo1_prediction_gap_max'] * 100:.1f} %")
    lines.append(f"auto loops: phase margin >= {s['auto_phase_margin_deg_min']:.1f} deg, gain"
                 f" margin >= {s['auto_gain_margin_db_min']:.1f} dB; baseline loops on the true"
                 f" model: unstable {s['baseline_unstable']}/{n}, phase margin median"
                 f" {s['baseline_phase_margin_deg_median']:.1f} deg, step overshoot median"
                 f" {s['baseline_step_overshoot_pct_median']:.1f} % (max"
                 f" {s['baseline_step_overshoot_pct_max']:.1f} %)")
    lines.append(f"tune --auto per axis {s['tune_wall_s_median']:.1f} s wall (median)")
    lines.append("")
    lines.append(f"{'axis':>6} {'tau':>7} {'g':>7} {'C':>7} {'J':>7} {'b':>7} {'T':>7}"
                 f" {'bw Hz':>6} {'os p/m %':>11} {'settle p/m ms':>14} {'ZN kp ki kd':>22}"
                 f" {'ISE auto':>9} {'ISE ZN':>9} {'ratio':>6} {'aligned':>8} {'dev.obj':>8}")
    for r in figures["rows"]:
        e = r["errors"]
        a = r["auto"]
        d = r["demo1"]
        zn = r["baseline"]["gains"]
        lines.append(
            f"{r['machine']:>4}{r['axis']:>2} " + " ".join(
                f"{e[k] * 100:+6.2f}%" for k in ("time_constant", "speed_per_volt", "coulomb_v",
                                                 "inertia", "viscous", "load_torque"))
            + f" {a['bandwidth_hz']:6g} {a['overshoot_pct'][0]:5.2f}/{a['overshoot_pct'][1]:<5.2f}"
            f" {a['settling_s'][0] * 1000:6.0f}/{a['settling_s'][1] * 1000:<7.0f}"
            f" {zn['kp']:6.3g} {zn['ki']:6.3g} {zn['kd']:8.3g}"
            f" {d['auto_ise_counts2_s']:9.2f} {d['baseline_ise_counts2_s']:9.2f}"
            f" {d.get('ratio', math.nan):6.2f} {d.get('aligned_ratio', math.nan):8.2f}"
            f" {d.get('device_ratio', math.nan):8.2f}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = argument_parser(__doc__, runs=1)
    parser.add_argument("--machines", type=int, default=17,
                        help="random machines of 3 axes each (default 17: 51 axes)")
    parser.add_argument("--seed", type=int, default=31)
    parser.add_argument("--travel-mm", type=float, default=20.0)
    args = parse_arguments(parser, argv)
    base = load_config(default_machine())
    started = time.perf_counter()
    rows: list[dict[str, Any]] = []
    for index in range(args.machines):
        rows.extend(one_machine(base, index, args.seed, args.travel_mm))
        if not args.json:
            print(f"machine {index + 1}/{args.machines} done", file=sys.stderr)
    figures = {"machines": args.machines, "seed": args.seed, "travel_mm": args.travel_mm,
               "wall_s": time.perf_counter() - started, "rows": rows,
               "summary": summary(rows)}
    return emit(figures, text, as_json=args.json)


if __name__ == "__main__":
    main()
