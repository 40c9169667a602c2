"""Prediction before the job against emulated RP2040s: X's motor, outside its chip on the
firmware's pins, is not the one the machine file describes; identified through the chip,
its model predicts demo 1's following error on every axis within 10 % or 2 counts.
(``benchmarks/predict.py`` does the same for every axis and four programs, and measures the
prediction's speed.)"""

from __future__ import annotations

import dataclasses
from pathlib import Path

from usbmotion.autotune.identify import identify_axis
from usbmotion.autotune.verify import place_loop
from usbmotion.demos import demo_path
from usbmotion.host.config import AxisConfig, MachineConfig, MotorModelConfig
from usbmotion.sim.firmware import FirmwareSimDevice, default_uf2
from usbmotion.sim.machine import connect_machine, connect_session
from usbmotion.sim.predict import IDENTIFIED, SIMULATED, predict
from usbmotion.sim.world import SimWorld

from .emulated import require_emulator
from .jobs import pins_motor, virtual_config

DEMO = demo_path(1)


def _with(config: MachineConfig, name: str, **changes: object) -> MachineConfig:
    return dataclasses.replace(config, axes=tuple(
        dataclasses.replace(a, **changes) if a.name == name else a for a in config.axes))


def test_an_identified_model_predicts_emulated_chips_on_their_pins(tmp_path: Path) -> None:
    require_emulator()
    known = virtual_config(tmp_path)
    x = known.axis("X")
    assert x.sim is not None
    drawn = dataclasses.replace(  # the truth, which the host is not told
        x.sim, inertia_kg_m2=x.sim.inertia_kg_m2 * 1.3,
        load_torque_mnm=x.sim.load_torque_mnm * 0.7,
        viscous_friction_unm_per_rad_s=x.sim.viscous_friction_unm_per_rad_s * 1.4,
        torque_constant_mnm_per_a=x.sim.torque_constant_mnm_per_a * 0.85)
    truth: dict[str, AxisConfig] = {a.name: a for a in known.axes}
    truth["X"] = dataclasses.replace(x, sim=drawn)
    world = SimWorld()
    chips = []
    try:
        for name, axis in truth.items():
            assert axis.device is not None
            chips.append(FirmwareSimDevice(default_uf2(), name=axis.device,
                                           motor=pins_motor(axis)))
            world.add(chips[-1], key=name)
        with connect_machine(known, world=world) as machine:
            machine.configure()
            found = identify_axis(machine, "X", travel_mm=20.0)
            machine.stop()
        fit = found.fit.model
        tuned = _with(known, "X", gains=place_loop(found, x).gains, model=MotorModelConfig(
            fit.time_constant_s, fit.speed_per_volt_counts_s, max(0.0, fit.coulomb_v),
            fit.supply_v))
        with connect_session(tuned, world=world) as session:
            # unhomed, from where power-up left each axis (homing is not what is predicted)
            standing = session.positions_mm()
            prepared = session.prepare(DEMO, text=DEMO.read_text(), unhomed=True)
            predict(tuned, DEMO, DEMO.read_text(), standing_mm=standing)  # the kernel compiled
            forecast = predict(tuned, DEMO, DEMO.read_text(), standing_mm=standing)
            report, _ = session.run(prepared)
            session.shutdown()
    finally:
        for chip in chips:
            chip.close()
    assert forecast.motors == {"X": IDENTIFIED, "Y": SIMULATED, "Z": SIMULATED}
    assert report.completed and forecast.report.completed, report.stop_reason
    measured = {a.name: a for a in report.axes}
    for axis in forecast.report.axes:
        got = measured[axis.name]
        assert abs(axis.max_error_counts - got.max_error_counts) <= max(
            0.1 * got.max_error_counts, 2), (axis, got)
        assert abs(axis.rms_error_counts - got.rms_error_counts) <= max(
            0.1 * got.rms_error_counts, 2), (axis, got)
