"""PinsMotor, the motor outside an emulated chip, as the host describes it (no emulator)."""

from __future__ import annotations

import re

import pytest

from usbmotion.device.motor import MotorParams
from usbmotion.errors import ArgumentError
from usbmotion.sim.firmware import PinsMotor, emulator_dir


def test_the_default_is_the_on_chip_motor_at_power_up() -> None:
    assert PinsMotor.like(MotorParams()) == PinsMotor()


def test_like_copies_an_on_chip_motor_and_its_travel() -> None:
    params = MotorParams(inertia_kg_m2=(15, -4), load_torque_mnm=(80, 0),
                         travel_lower_counts=-1200, travel_upper_counts=46_800)
    motor = PinsMotor.like(params, bounces=3)
    assert motor.inertia_kg_m2 == pytest.approx(1.5e-3)
    assert motor.load_nm == pytest.approx(0.08)
    assert (motor.lower_counts, motor.upper_counts, motor.bounces) == (-1200, 46_800, 3)


def test_the_options_are_the_harness_motor_keys() -> None:
    source = (emulator_dir() / "lib" / "pins.js").read_text(encoding="utf-8")
    defaults = re.search(r"DEFAULT_MOTOR = \{(.*?)\};", source, re.S)
    extra = re.search(r"\.\.\.Object\.keys\(DEFAULT_MOTOR\),\s*(.*?)\]\);", source, re.S)
    assert defaults is not None and extra is not None
    known = set(re.findall(r"(\w+):", defaults.group(1))) | set(re.findall(r"'(\w+)'",
                                                                           extra.group(1)))
    options = PinsMotor(lower_counts=-10, upper_counts=10).options()
    assert set(options) <= known
    assert {"lower", "upper"} <= set(options)
    assert "lower" not in PinsMotor().options()


@pytest.mark.parametrize("field, value", [("supply_v", 0.0), ("resistance_ohm", -1.0),
                                          ("load_nm", -0.1), ("bounces", -1)])
def test_a_bad_value_is_refused_by_name(field: str, value: float) -> None:
    with pytest.raises(ArgumentError, match=field):
        PinsMotor(**{field: value})


def test_switches_out_of_order_are_refused() -> None:
    with pytest.raises(ArgumentError, match="lower_counts 10 must be below upper_counts 10"):
        PinsMotor(lower_counts=10, upper_counts=10)


def test_the_probe_surface_is_given_as_call_40_gives_it() -> None:
    options = PinsMotor(probe_side=1, probe_counts=-800).options()
    assert (options["probeSide"], options["probePosition"]) == (1, -800)
    assert "probeSide" not in PinsMotor().options()
    with pytest.raises(ArgumentError, match="probe_side 3 must be 0"):
        PinsMotor(probe_side=3)
