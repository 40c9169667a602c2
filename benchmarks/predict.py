"""Predicted against measured following error on emulated RP2040s whose motors were perturbed
and then identified (issue 31's prediction before the job).

    python benchmarks/predict.py [--devices emulated|python] [--seed 31] [--spread 0.3]
                                 [--programs demo1,demo2,demo3,cam_corner] [--json]

The machine is ``examples/machine-firmware.toml`` in virtual time. Each axis's motor (the
truth, which the host is never told) is the file's, its inertia, viscous friction, load
torque and torque constant each times a factor drawn uniformly within ``1 +- spread``
(fixed seed), the axis's speed and acceleration limits lowered where the drawn motor could
not keep the file's 10 % margin. With ``--devices emulated`` (the default) each axis is the
firmware on an emulated chip driving that motor outside the chip through its pins (PWM
bridge, quadrature edges, switches: ``usbmotion.sim.firmware.PinsMotor``); with ``python``,
a Python device simulating it.

1. Every axis is identified through its device (``usbmotion.autotune.identify_axis``, 20 mm
   from where it stands after power-up) and its gains placed
   (``usbmotion.autotune.verify.place_loop``); the machine file's copy gets both (its
   ``gains`` and ``model`` tables, as ``usbmotion tune --auto --write`` writes them).
2. The machine is homed; then for each program, from where the machine stands:
   ``usbmotion.sim.predict.predict`` plays it on the identified models (Python devices,
   virtual time), and the machine runs it. Per axis the predicted and measured peak and
   RMS following error are compared: within 10 % or 2 counts (the target); the
   prediction's speed is the program's time over the prediction's wall time (warm: the
   servo kernel compiled), target at least 100 x.

Prints one row per program and axis, then the summary (``--json``: every figure).
"""

from __future__ import annotations

import dataclasses
import math
import statistics
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from _common import argument_parser, emit, parse_arguments
from usbmotion.autotune.identify import identify_axis
from usbmotion.autotune.verify import place_loop
from usbmotion.demos import demo_path
from usbmotion.device import Device, MemoryFlash
from usbmotion.host.config import (
    AxisConfig,
    MachineConfig,
    MotorModelConfig,
    parse_config,
    simulated_reach,
)
from usbmotion.motion.dialects import Dialect
from usbmotion.sim.firmware import FirmwareSimDevice, PinsMotor, default_uf2
from usbmotion.sim.machine import connect_machine, connect_session, sim_motor_params
from usbmotion.sim.predict import predict
from usbmotion.sim.urls import URL_CHECKS
from usbmotion.sim.world import SimWorld

ROOT = Path(__file__).resolve().parents[1]
MACHINE = ROOT / "examples" / "machine-firmware.toml"
PROGRAMS = {
    "demo1": demo_path(1),
    "demo2": demo_path(2),
    "demo3": demo_path(3),
    "cam_corner": ROOT / "tests" / "programs" / "cam_corner.ngc",
}
CAM_ORIGIN = {"X": 100.0, "Y": 100.0, "Z": -40.0}
"""cam_corner.ngc is a grbl job from the stock's top corner (as tests/test_work_offsets.py
runs it): read as grbl, G54 there."""
TRAVEL_MM = 20.0
SHARE = 0.10
"""Predicted within this share of the measured, or :data:`SLACK_COUNTS`."""
SLACK_COUNTS = 2.0
SPEED_TARGET = 100.0


def base_machine(folder: Path) -> MachineConfig:
    """examples/machine-firmware.toml with ``sim://`` axes, written into ``folder``."""
    text = MACHINE.read_text(encoding="utf-8")
    for index, letter in enumerate("XYZ"):
        text = text.replace(f'url = "socket://127.0.0.1:{7000 + index}"',
                            f'url = "sim://{letter}"')
    path = folder / "machine.toml"
    path.write_text(text, encoding="utf-8")
    return parse_config(text, path=path, url_checks=URL_CHECKS)


def perturbed(config: MachineConfig, rng: np.random.Generator, spread: float
              ) -> tuple[MachineConfig, dict[str, AxisConfig]]:
    """The machine the host knows (its limits within the drawn motors' reach) and each
    axis with its drawn motor as its ``sim`` table (the truth)."""
    known: list[AxisConfig] = []
    truth: dict[str, AxisConfig] = {}
    for axis in config.axes:
        sim = axis.sim
        assert sim is not None
        f = rng.uniform(1 - spread, 1 + spread, size=4)
        def times(value: float, factor: float) -> float:
            return float(f"{value * factor:.4g}")

        drawn = dataclasses.replace(
            sim, inertia_kg_m2=times(sim.inertia_kg_m2, f[0]),
            viscous_friction_unm_per_rad_s=times(sim.viscous_friction_unm_per_rad_s, f[1]),
            load_torque_mnm=times(sim.load_torque_mnm, f[2]),
            torque_constant_mnm_per_a=times(sim.torque_constant_mnm_per_a, f[3]))
        reach = simulated_reach(drawn, axis.counts_per_mm)
        velocity = min(axis.max_velocity_mm_s, math.floor(reach.usable_velocity_mm_s))
        accel = min(axis.max_accel_mm_s2, math.floor(reach.usable_accel_mm_s2(velocity)))
        limited = dataclasses.replace(axis, max_velocity_mm_s=float(velocity),
                                      max_accel_mm_s2=float(accel), max_jerk_mm_s3=20.0 * accel)
        known.append(limited)
        truth[axis.name] = dataclasses.replace(limited, sim=drawn)
    return dataclasses.replace(config, axes=tuple(known)), truth


def world_of(truth: dict[str, AxisConfig], devices: str) -> tuple[SimWorld, list[Any]]:
    """A world with each axis's device on its true motor; the emulated chips to close."""
    world = SimWorld()
    chips: list[Any] = []
    for name, axis in truth.items():
        assert axis.sim is not None and axis.sim_travel_counts is not None and axis.device
        params = sim_motor_params(axis.sim, travel_counts=axis.sim_travel_counts)
        if devices == "emulated":
            chip = FirmwareSimDevice(default_uf2(), name=axis.device, motor=PinsMotor.like(params))
            chips.append(chip)
            world.add(chip, key=name)
        else:
            device = Device(flash=MemoryFlash(), motor=params)
            codes = " ".join(str(ord(c)) for c in axis.device)
            device.feed(f"18 {len(axis.device)} {codes}\n".encode("ascii"))
            device.take_output()
            world.add(device, key=name)
    return world, chips


def identified(config: MachineConfig, world: SimWorld) -> tuple[MachineConfig, dict[str, Any]]:
    """Every axis identified and its loop placed: the machine with the new gains and models."""
    axes: list[AxisConfig] = []
    figures: dict[str, Any] = {}
    with connect_machine(config, world=world) as machine:
        machine.configure()
        for axis in config.axes:
            direction = 1.0 if axis.homing.direction < 0 else -1.0
            found = identify_axis(machine, axis.name, travel_mm=direction * TRAVEL_MM)
            chosen = place_loop(found, axis)
            model = found.fit.model
            axes.append(dataclasses.replace(axis, gains=chosen.gains, model=MotorModelConfig(
                model.time_constant_s, model.speed_per_volt_counts_s, max(0.0, model.coulomb_v),
                model.supply_v)))
            figures[axis.name] = {"gains": dataclasses.asdict(chosen.gains),
                                  "model": dataclasses.asdict(axes[-1].model or model)}
        machine.stop()
    return dataclasses.replace(config, axes=tuple(axes)), figures


def within(predicted: float, measured: float) -> bool:
    return abs(predicted - measured) <= max(SHARE * abs(measured), SLACK_COUNTS)


def run(devices: str, seed: int, spread: float, programs: list[str], folder: Path
        ) -> dict[str, Any]:
    rng = np.random.default_rng(seed)
    known, truth = perturbed(base_machine(folder), rng, spread)
    world, chips = world_of(truth, devices)
    rows: list[dict[str, Any]] = []
    try:
        started = time.perf_counter()
        tuned, tuning = identified(known, world)
        identify_s = time.perf_counter() - started
        with connect_session(tuned, world=world) as session:
            session.home()
            for label in programs:
                path = PROGRAMS[label]
                text = path.read_text(encoding="utf-8")
                dialect = Dialect.GRBL if label == "cam_corner" else None
                session.set_work_origin(CAM_ORIGIN if label == "cam_corner"
                                        else dict.fromkeys("XYZ", 0.0))
                standing = session.positions_mm()
                # the first warms the servo kernel (compiled once per process)
                predict(tuned, path, text, dialect=dialect, standing_mm=standing)
                forecast = predict(tuned, path, text, dialect=dialect, standing_mm=standing)
                prepared = session.prepare(path, text=text, dialect=dialect)
                report, _ = session.run(prepared)
                measured = {a.name: a for a in report.axes}
                for axis in forecast.report.axes:
                    got = measured[axis.name]
                    rows.append({
                        "program": label, "axis": axis.name,
                        "completed": report.completed and forecast.report.completed,
                        "peak_predicted": axis.max_error_counts,
                        "peak_measured": got.max_error_counts,
                        "rms_predicted": axis.rms_error_counts,
                        "rms_measured": got.rms_error_counts,
                        "peak_ok": within(axis.max_error_counts, got.max_error_counts),
                        "rms_ok": within(axis.rms_error_counts, got.rms_error_counts),
                        "program_s": forecast.report.planned_time_s,
                        "predict_wall_s": forecast.wall_s,
                        "speed": forecast.speed_ratio,
                    })
            session.shutdown()
    finally:
        for chip in chips:
            chip.close()
    truth_figures = {name: dataclasses.asdict(axis.sim) for name, axis in truth.items()
                     if axis.sim is not None}
    speeds = sorted({(r["program"], r["speed"]) for r in rows})
    return {
        "devices": devices, "seed": seed, "spread": spread, "identify_wall_s": identify_s,
        "truth": truth_figures, "tuning": tuning, "rows": rows,
        "summary": {
            "compared": len(rows),
            "peak_within": sum(r["peak_ok"] for r in rows),
            "rms_within": sum(r["rms_ok"] for r in rows),
            "all_completed": all(r["completed"] for r in rows),
            "speed_min": min(s for _, s in speeds),
            "speed_median": statistics.median(s for _, s in speeds),
            "speed_target": SPEED_TARGET,
        },
    }


def text_of(figures: dict[str, Any]) -> str:
    lines = [f"{'program':<11}{'axis':<5}{'peak pred':>10}{'meas':>6}{'rms pred':>10}"
             f"{'meas':>7}  within   speed"]
    for r in figures["rows"]:
        ok = ("peak " if r["peak_ok"] else "PEAK-") + ("rms" if r["rms_ok"] else "RMS-")
        lines.append(f"{r['program']:<11}{r['axis']:<5}{r['peak_predicted']:>10d}"
                     f"{r['peak_measured']:>6d}{r['rms_predicted']:>10.2f}"
                     f"{r['rms_measured']:>7.2f}  {ok:<9}{r['speed']:>5.0f}x")
    s = figures["summary"]
    lines.append(f"{figures['devices']} devices, seed {figures['seed']}, spread"
                 f" +-{figures['spread']:g}; identification {figures['identify_wall_s']:.1f} s")
    lines.append(f"peak within 10 % or 2 counts: {s['peak_within']}/{s['compared']};"
                 f" RMS: {s['rms_within']}/{s['compared']}; every run completed:"
                 f" {s['all_completed']}")
    lines.append(f"prediction speed (program time / wall, warm): median {s['speed_median']:.0f} x,"
                 f" least {s['speed_min']:.0f} x (target {s['speed_target']:g} x)")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argument_parser(__doc__, runs=1)
    parser.add_argument("--devices", choices=("emulated", "python"), default="emulated")
    parser.add_argument("--seed", type=int, default=31)
    parser.add_argument("--spread", type=float, default=0.3)
    parser.add_argument("--programs", default=",".join(PROGRAMS))
    args = parse_arguments(parser, argv)
    chosen = [p.strip() for p in args.programs.split(",") if p.strip()]
    unknown = [p for p in chosen if p not in PROGRAMS]
    if unknown:
        parser.error(f"--programs: {', '.join(unknown)} unknown; allowed: {', '.join(PROGRAMS)}")
    import tempfile  # noqa: PLC0415

    with tempfile.TemporaryDirectory() as folder:
        figures = run(args.devices, args.seed, args.spread, chosen, Path(folder))
    emit(figures, text_of, as_json=args.json)
    s = figures["summary"]
    good = (s["peak_within"] == s["rms_within"] == s["compared"] and s["all_completed"])
    return 0 if good else 1


if __name__ == "__main__":
    sys.exit(main())
