"""A float64 version of core1's controller, to measure what the firmware's arithmetic costs.

The servo tick is the same as core1's (PID on the position error with the derivative over
the last millisecond, saturation to the source voltage, conditional integration with the
same clamp, encoder counter and velocity ring), but every product of the controller is a
float64 instead of a 4-digit scientific-notation number. The motor is the device's own
model (``motor_tick``), fed the float output voltage to 4 significant digits, so the
comparison isolates the controller's arithmetic.

Run ``python -m tests.device.float_reference`` for the figures quoted in PROTOCOL.md.
"""

from __future__ import annotations

import math

from usbmotion.device import Device, Gains, MotorParams
from usbmotion.device.motor import MICRO, derive_constants, motor_tick, sci_value
from usbmotion.scimath import SciNumber


def _value(pair: tuple[int, int]) -> float:
    return float(sci_value(pair))


def float_run(
    desired: list[int],
    *,
    tick_us: int = 1000,
    gains: Gains | None = None,
    motor: MotorParams | None = None,
) -> list[int]:
    """Encoder counts after each tick, following ``desired`` (one value per tick)."""
    gains = gains or Gains()
    motor = motor or MotorParams()
    constants = derive_constants(motor, tick_us=tick_us)
    dt_s = tick_us * 1e-6
    window = min(10, max(1, 1000 // tick_us))
    kp = _value(gains.kp)
    ki_dt = _value(gains.ki) * dt_s
    kd_dt = _value(gains.kd) / (window * dt_s)
    supply = _value(motor.source_voltage_v)
    limit = 0 if ki_dt == 0 else max(1, math.trunc(supply / ki_dt))
    theta = omega = 0
    errors = [desired[0]] * window
    error_pos = 0
    integral = 0
    out = []
    for target in desired:
        error = target - theta // MICRO
        change = error - errors[error_pos]
        errors[error_pos] = error
        error_pos = (error_pos + 1) % window
        candidate = 0
        if limit:
            candidate = max(-limit, min(limit, integral + error))
        volts = kp * error + ki_dt * candidate + kd_dt * change
        if volts > supply:
            volts = supply
            if error <= 0:
                integral = candidate
        elif volts < -supply:
            volts = -supply
            if error >= 0:
                integral = candidate
        else:
            integral = candidate
        u = SciNumber.from_float(volts)
        theta, omega = motor_tick(theta, omega, u.coefficient, u.exponent, constants)
        out.append(theta // MICRO)
    return out


def firmware_run(desired: list[int], *, interval_dms: int = 10) -> list[int]:
    """Encoder counts after each tick of the device following ``desired`` from its queue."""
    device = Device()
    device.feed(f"5 {interval_dms}\n3 1\n".encode())
    out = []
    for start in range(0, len(desired), 500):
        chunk = desired[start : start + 500]
        device.feed(f"1 {len(chunk)} {' '.join(map(str, chunk))}\n".encode())
        for _ in chunk:
            device.run(1)
            out.append(device.state.actual)
    return out


def step_figures(
    counts: list[int], target: int, tick_us: int, *, band: int = 2
) -> tuple[float, float]:
    """Settling time (ms, last tick outside ``+-band``) and overshoot (% of the step)."""
    last_outside = max((i for i, c in enumerate(counts) if abs(c - target) > band), default=-1)
    settle_ms = (last_outside + 1) * tick_us / 1000
    overshoot = max(0, max(counts) - target) / target * 100
    return settle_ms, overshoot


def sine(amplitude: int, frequency_hz: float, duration_s: float, tick_us: int) -> list[int]:
    """A sinusoidal trajectory sampled every tick, counts."""
    n = round(duration_s * 1e6 / tick_us)
    return [
        round(amplitude * math.sin(2 * math.pi * frequency_hz * k * tick_us * 1e-6))
        for k in range(1, n + 1)
    ]


def following_error_difference(
    desired: list[int], *, interval_dms: int = 10
) -> tuple[int, float, int, int]:
    """Max and RMS of (firmware - float64) following error (counts), and each one's max."""
    firmware = firmware_run(desired, interval_dms=interval_dms)
    reference = float_run(desired, tick_us=interval_dms * 100)
    diffs = [b - a for a, b in zip(firmware, reference, strict=True)]
    rms = math.sqrt(sum(d * d for d in diffs) / len(diffs))
    worst = max(abs(d) for d in diffs)
    fw_max = max(abs(d - a) for d, a in zip(desired, firmware, strict=True))
    ref_max = max(abs(d - b) for d, b in zip(desired, reference, strict=True))
    return worst, rms, fw_max, ref_max


def open_loop(volts: float, *, interval_dms: int, ticks: int = 300) -> tuple[float, float]:
    """Final speed (counts/s) and 63.2 % rise time (s) of the motor model at ``volts``."""
    constants = derive_constants(MotorParams(sim_update_interval_dms=interval_dms), tick_us=1000)
    volt = SciNumber.from_float(volts)
    theta = omega = 0
    speeds = []
    for _ in range(ticks):
        theta, omega = motor_tick(theta, omega, volt.coefficient, volt.exponent, constants)
        speeds.append(omega / MICRO)
    level = (1 - math.exp(-1)) * speeds[-1]
    k = next(i for i, s in enumerate(speeds) if abs(s) >= abs(level))
    before = speeds[k - 1] if k else 0.0
    return speeds[-1], (k + (level - before) / (speeds[k] - before)) * 1e-3


def main() -> None:
    """Print the open-loop, step and tracking figures quoted in PROTOCOL.md."""
    motor = MotorParams()
    for interval_dms in (10, 1):
        final, rise = open_loop(12.0, interval_dms=interval_dms)
        exact_final = motor.steady_speed_counts_s(12.0)
        exact_tau = motor.time_constant_s()
        print(
            f"open loop 12 V, integration step {interval_dms * 100} us: final speed {final:.1f}"
            f" counts/s (analytic {exact_final:.1f}, {100 * (final / exact_final - 1):+.2f} %),"
            f" time constant {rise * 1e3:.2f} ms (analytic {exact_tau * 1e3:.2f} ms,"
            f" {100 * (rise / exact_tau - 1):+.2f} %)"
        )
    for interval_dms in (10, 1):
        tick_us = interval_dms * 100
        step = [1000] * (400_000 // tick_us)
        firmware = firmware_run(step, interval_dms=interval_dms)
        reference = float_run(step, tick_us=tick_us)
        fw_settle, fw_over = step_figures(firmware, 1000, tick_us)
        ref_settle, ref_over = step_figures(reference, 1000, tick_us)
        worst, rms, _, _ = following_error_difference(step, interval_dms=interval_dms)
        print(
            f"{1e6 / tick_us:.0f} Hz step of 1000 counts: firmware settles to +-2 counts in "
            f"{fw_settle:.1f} ms, overshoot {fw_over:.2f} %; float64 {ref_settle:.1f} ms, "
            f"{ref_over:.2f} %; following-error difference max {worst} counts, RMS {rms:.2f}"
        )
        track = sine(300, 2.0, 1.0, tick_us)
        worst, rms, fw_max, ref_max = following_error_difference(track, interval_dms=interval_dms)
        print(
            f"{1e6 / tick_us:.0f} Hz sine 300 counts 2 Hz: max following error firmware "
            f"{fw_max}, float64 {ref_max} counts; difference max {worst} counts, RMS {rms:.2f}"
        )


if __name__ == "__main__":
    main()
