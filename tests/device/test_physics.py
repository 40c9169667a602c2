"""The simulated motor against its analytic solution, and the closed loop's step response."""

from __future__ import annotations

import math

import pytest
from tests.device.helpers import send

from usbmotion.device import Device, MotorParams
from usbmotion.device.motor import MICRO, derive_constants, motor_tick

from .float_reference import (
    firmware_run,
    float_run,
    following_error_difference,
    sine,
    step_figures,
)

# The default motor in SI units, written out independently of the code under test.
KT = 334.6e-3  # N m / A (= V s / rad)
R = 2.182  # ohm
J = 1.1e-3  # kg m^2
B = 500e-6  # N m s / rad
LOAD = 50e-3  # N m
COUNTS_PER_RAD = 1920 / (2 * math.pi)


def _analytic(volts: float) -> tuple[float, float]:
    """Final speed (counts/s) and time constant (s) of the first-order model."""
    damping = KT * KT / R + B
    final_rad_s = (KT * volts / R - math.copysign(LOAD, volts)) / damping
    return final_rad_s * COUNTS_PER_RAD, J / damping


def _spin_up(volts: float, ticks: int, *, interval_dms: int) -> list[float]:
    """Shaft speed (counts/s) after each 1 ms tick at a constant voltage, from rest."""
    motor = MotorParams(sim_update_interval_dms=interval_dms)
    constants = derive_constants(motor, tick_us=1000)
    u_c, u_e = round(volts * 100), -2
    theta = omega = 0
    speeds = []
    for _ in range(ticks):
        theta, omega = motor_tick(theta, omega, u_c, u_e, constants)
        speeds.append(omega / MICRO)
    return speeds


@pytest.mark.parametrize("volts", [12.0, 6.0, -9.0])
@pytest.mark.parametrize("interval_dms", [10, 1])
def test_open_loop_speed_follows_the_first_order_solution(
    volts: float, interval_dms: int
) -> None:
    final, tau = _analytic(volts)
    speeds = _spin_up(volts, 300, interval_dms=interval_dms)
    assert speeds[-1] == pytest.approx(final, rel=0.02)
    for k, speed in enumerate(speeds, start=1):
        expected = final * (1 - math.exp(-k * 1e-3 / tau))
        assert abs(speed - expected) <= 0.02 * abs(final), k
    # time constant: when the speed crosses 1 - 1/e of its final value (interpolated)
    level = (1 - math.exp(-1)) * speeds[-1]
    k = next(i for i, s in enumerate(speeds) if abs(s) >= abs(level))
    before = speeds[k - 1] if k else 0.0
    crossing_ms = k + (level - before) / (speeds[k] - before)
    assert crossing_ms * 1e-3 == pytest.approx(tau, rel=0.02)


def test_the_default_motor_is_the_datasheet_gearmotor() -> None:
    motor = MotorParams()
    final, tau = _analytic(12.0)
    # Pololu 37D 30:1: 330 RPM no load at 12 V (the model's no-load speed includes the
    # friction that draws the datasheet's 0.2 A no-load current).
    assert final / 1920 * 60 == pytest.approx(330, rel=0.01)
    assert motor.steady_speed_counts_s(12.0) == pytest.approx(final, rel=1e-9)
    assert motor.time_constant_s() == pytest.approx(tau, rel=1e-9)
    assert pytest.approx(5.5, rel=0.01) == 12.0 / R, "stall current"


def test_below_the_breakaway_voltage_the_shaft_stays_still() -> None:
    breakaway = LOAD * R / KT
    assert _spin_up(0.9 * breakaway, 50, interval_dms=10)[-1] == 0
    assert _spin_up(1.2 * breakaway, 50, interval_dms=10)[-1] > 0


def test_coasting_stops_on_friction() -> None:
    motor = MotorParams()
    constants = derive_constants(motor, tick_us=1000)
    theta, omega = motor_tick(0, 5_000 * MICRO, 0, 0, constants)
    for _ in range(2000):
        theta, omega = motor_tick(theta, omega, 0, 0, constants)
    assert omega == 0
    assert theta > 0


def test_hard_stop_beyond_the_switch() -> None:
    motor = MotorParams(travel_lower_counts=-100, travel_upper_counts=100, overtravel_counts=50)
    constants = derive_constants(motor, tick_us=1000)
    theta = omega = 0
    for _ in range(500):
        theta, omega = motor_tick(theta, omega, 1200, -2, constants)
    assert theta // MICRO == 150
    assert omega == 0


@pytest.mark.parametrize("interval_dms", [10, 1])
def test_a_1000_count_step_settles_within_150_ms(interval_dms: int) -> None:
    tick_us = interval_dms * 100
    counts = firmware_run([1000] * (300_000 // tick_us), interval_dms=interval_dms)
    settle_ms, overshoot = step_figures(counts, 1000, tick_us)
    assert settle_ms <= 150
    assert overshoot <= 10
    assert counts[-1] == 1000


def test_the_scientific_pid_tracks_like_a_float64_pid() -> None:
    worst, rms, firmware_max, float_max = following_error_difference([1000] * 300)
    assert worst <= 2
    assert rms <= 1
    track = sine(300, 2.0, 1.0, 1000)
    worst, rms, firmware_max, float_max = following_error_difference(track)
    assert worst <= 3
    assert rms <= 1
    assert abs(firmware_max - float_max) <= 3
    assert firmware_max < 40


def test_float_reference_agrees_on_the_step_shape() -> None:
    counts = float_run([1000] * 300)
    settle_ms, overshoot = step_figures(counts, 1000, 1000)
    assert settle_ms <= 150
    assert overshoot <= 10


def test_zero_viscous_friction_is_allowed_and_frees_the_motor() -> None:
    """Call 32 takes 0 (no viscous friction): the voltage alone then drives the shaft faster."""
    device = Device()
    damped = device.motor_constants.drive
    assert send(device, "32 0 0", "32 -1 0") == ["SIM_VISCOUS_FRICTION 0 0"]
    free = device.motor_constants.drive
    assert free[1] == damped[1] and free[0] > damped[0]
    assert send(device, "32 -5 0") == ["ERR 32 coefficient -5 is out of range 0..9999"]
    send(device, "3 1", "0 500")
    device.run(300)
    assert (device.state.fault, abs(device.state.actual - 500) <= 2) == (0, True)
