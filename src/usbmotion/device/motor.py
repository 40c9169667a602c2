"""The simulated servo motor: a brushed DC gearmotor with an incremental encoder.

The model (at the output shaft, the one whose revolutions call 16 counts)::

    J dw/dt = Kt * i - b * w - T_load * sign(w)        i = (V - Kt * w) / R

with the winding inductance neglected (current follows the voltage at once), the back-EMF
constant equal to the torque constant in SI units, viscous friction ``b`` and a Coulomb-like
load torque ``T_load`` that only opposes motion: at standstill the shaft stays still unless
the motor torque exceeds it. In encoder counts (``k = 2*pi / counts_per_revolution`` radians
per count) this is a first-order system in the velocity::

    dw/dt = (w_inf - w) / tau        tau   = J / (Kt**2 / R + b)
                                     w_inf = g_v * V - w_f * sign(w)
                                     g_v   = (Kt / R) / (Kt**2 / R + b) / k     counts/s per V
                                     w_f   = T_load / (Kt**2 / R + b) / k       counts/s

For a voltage held over a step of ``h`` seconds it has the exact solution
``w(h) = w_inf + (w - w_inf) * exp(-h/tau)``, which the step function integrates
(velocity and travel) with the constants ``F = 1 - exp(-h/tau)`` and ``Q = h - tau * F``:
``w' = w - (w - w_inf) * F`` and ``travel = w * h - (w - w_inf) * Q``. The products are
scientific-notation integer maths, as the firmware computes them; position (micro-counts)
and velocity (micro-counts per second) are plain integers that never lose an increment.
A step in which the velocity would change sign ends at rest (friction reverses there);
a hard stop beyond each limit switch stops the shaft dead.
"""

from __future__ import annotations

from dataclasses import dataclass

from usbmotion.errors import DeviceParameterError
from usbmotion.motor_model import DcMotorModel
from usbmotion.protocol.table import BY_NUMBER, INT32_MAX, INT32_MIN, Param
from usbmotion.scimath import (
    SciNumber,
    sci_add,
    sci_compare,
    sci_from_int,
    sci_mul,
    sci_sub,
    sci_to_int,
)

DIGITS = 4
"""Significant digits of the firmware's scientific-notation numbers."""
MICRO = 1_000_000
"""Fixed-point scale of the motor state: micro-counts and micro-counts per second."""
OMEGA_MAX_MICRO = 10**12
"""Speed bound of the model, micro-counts/s (10**6 counts/s): keeps every product in int64."""
_OMEGA_MAX_C, _OMEGA_MAX_E = 1000, 9
_TWO_PI = SciNumber(6283, -3)

SciPair = tuple[int, int]
"""A scientific-notation number as the protocol carries it: ``(coefficient, exponent)``."""


def _check(param: Param, field_name: str, value: object) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise DeviceParameterError(f"{field_name} {value!r} is not an int")
    if not param.minimum <= value <= param.maximum:
        raise DeviceParameterError(
            f"{field_name} {value!r} is out of range {param.minimum}..{param.maximum}"
        )
    return value


def _check_sci(call: int, field_name: str, value: object) -> SciPair:
    if not (isinstance(value, tuple) and len(value) == 2):
        raise DeviceParameterError(
            f"{field_name} {value!r} is not a (coefficient, exponent) pair of ints"
        )
    coefficient_param, exponent_param = BY_NUMBER[call].params
    return (
        _check(coefficient_param, f"{field_name} coefficient", value[0]),
        _check(exponent_param, f"{field_name} exponent", value[1]),
    )


def sci_value(pair: SciPair) -> SciNumber:
    """The protocol pair ``(C, E)`` as a normalised 4-digit number."""
    return SciNumber(pair[0], pair[1], digits=DIGITS)


@dataclass(frozen=True, slots=True)
class MotorParams:
    """Parameters of the simulated gearmotor and axis, with the power-up defaults.

    The defaults describe a Pololu 37D 12 V 30:1 metal gearmotor with its 64 CPR encoder
    (item 4752) driving a small load; PROTOCOL.md ("The simulated motor") gives the source
    of every figure. Scientific-notation fields are ``(coefficient, exponent)`` pairs as
    calls 13-15, 17, 32 and 33 carry them, with the same ranges.

    Raises:
        DeviceParameterError: a field outside the range its protocol call allows, or a
            travel range whose lower end is not below its upper end.
    """

    source_voltage_v: SciPair = (12, 0)
    """Supply voltage and PID output ceiling, V (call 13)."""
    torque_constant_mnm_per_a: SciPair = (3346, -1)
    """Torque constant at the output shaft, mNm/A; the back-EMF constant is equal in SI."""
    winding_resistance_ohm: SciPair = (2182, -3)
    """Winding resistance, ohm (call 15)."""
    counts_per_revolution: int = 1920
    """Encoder counts per output revolution, quadrature x4 (call 16)."""
    inertia_kg_m2: SciPair = (11, -4)
    """Rotor (reflected through the gearbox) plus load inertia at the output shaft (call 17)."""
    viscous_friction_unm_per_rad_s: SciPair = (500, 0)
    """Viscous friction at the output shaft, micro-Nm per rad/s (call 32)."""
    load_torque_mnm: SciPair = (50, 0)
    """Constant (Coulomb-like) torque opposing motion, mNm (call 33)."""
    sim_update_interval_dms: int = 10
    """Longest integration step, tenths of a millisecond (call 12)."""
    travel_lower_counts: int = INT32_MIN
    """Lower limit switch position, counts from power-up (call 34)."""
    travel_upper_counts: int = INT32_MAX
    """Upper limit switch position, counts from power-up (call 34)."""
    overtravel_counts: int = 200
    """Distance from each switch to the hard stop beyond it, counts."""

    def __post_init__(self) -> None:
        _check_sci(13, "source_voltage_v", self.source_voltage_v)
        _check_sci(14, "torque_constant_mnm_per_a", self.torque_constant_mnm_per_a)
        _check_sci(15, "winding_resistance_ohm", self.winding_resistance_ohm)
        _check(BY_NUMBER[16].params[0], "counts_per_revolution", self.counts_per_revolution)
        _check_sci(17, "inertia_kg_m2", self.inertia_kg_m2)
        _check_sci(32, "viscous_friction_unm_per_rad_s", self.viscous_friction_unm_per_rad_s)
        _check_sci(33, "load_torque_mnm", self.load_torque_mnm)
        _check(BY_NUMBER[12].params[0], "sim_update_interval_dms", self.sim_update_interval_dms)
        lower_param, upper_param = BY_NUMBER[34].params
        _check(lower_param, "travel_lower_counts", self.travel_lower_counts)
        _check(upper_param, "travel_upper_counts", self.travel_upper_counts)
        if self.travel_lower_counts >= self.travel_upper_counts:
            raise DeviceParameterError(
                f"travel_lower_counts {self.travel_lower_counts!r} must be below "
                f"travel_upper_counts {self.travel_upper_counts!r}"
            )
        overtravel = Param("overtravel_counts", 0, 1_000_000, "counts")
        _check(overtravel, "overtravel_counts", self.overtravel_counts)

    # --- the continuous model in floating point (for tools and tests) ---------------------

    def model(self) -> DcMotorModel:
        """These parameters as the continuous model's SI figures."""
        return DcMotorModel(
            torque_constant_nm_per_a=float(sci_value(self.torque_constant_mnm_per_a)) * 1e-3,
            resistance_ohm=float(sci_value(self.winding_resistance_ohm)),
            inertia_kg_m2=float(sci_value(self.inertia_kg_m2)),
            viscous_nm_s_per_rad=float(sci_value(self.viscous_friction_unm_per_rad_s)) * 1e-6,
            load_torque_nm=float(sci_value(self.load_torque_mnm)) * 1e-3,
            counts_per_revolution=self.counts_per_revolution,
            source_voltage_v=float(sci_value(self.source_voltage_v)),
        )

    def time_constant_s(self) -> float:
        """Mechanical time constant ``J / (Kt**2/R + b)`` of the continuous model, s."""
        return self.model().time_constant_s()

    def steady_speed_counts_s(self, voltage_v: float) -> float:
        """Speed the continuous model settles at under a constant voltage, counts/s."""
        return self.model().steady_speed_counts_s(voltage_v)

    def stall_torque_nm(self) -> float:
        """Torque at standstill under the full source voltage, after the load torque, N m."""
        return self.model().stall_torque_nm()


@dataclass(frozen=True, slots=True)
class MotorConstants:
    """What core1 needs of the motor for one servo period, as plain integers.

    Scientific-notation constants are ``(coefficient, exponent)`` normalised to 4 digits.
    Computed by core0 whenever a motor parameter or the servo period changes (the
    exponential uses soft-float there, never in the servo loop).
    """

    steps: int
    """Integration steps per servo tick."""
    drive: SciPair
    """``g_v``: steady speed per volt, micro-counts/s per V."""
    friction_speed: SciPair
    """``w_f``: speed the load torque takes off, micro-counts/s."""
    decay: SciPair
    """``F = 1 - exp(-h/tau)`` for one step."""
    lag_s: SciPair
    """``Q = h - tau * F`` for one step, s."""
    tick_us: int
    """Servo period, us (the step is ``tick_us / steps``)."""
    stop_low_micro: int
    """Lower hard stop, micro-counts."""
    stop_high_micro: int
    """Upper hard stop, micro-counts."""


def _pair(number: SciNumber) -> SciPair:
    return number.coefficient, number.exponent


def derive_constants(motor: MotorParams, *, tick_us: int) -> MotorConstants:
    """Integration constants of ``motor`` for a servo period of ``tick_us`` microseconds.

    Raises:
        DeviceParameterError: ``tick_us`` is not a positive int.
    """
    if isinstance(tick_us, bool) or not isinstance(tick_us, int) or tick_us <= 0:
        raise DeviceParameterError(f"tick_us {tick_us!r} is not a positive int")
    sim_us = motor.sim_update_interval_dms * 100
    steps = -(-tick_us // sim_us)
    kt = sci_value(motor.torque_constant_mnm_per_a) * SciNumber(1, -3)
    resistance = sci_value(motor.winding_resistance_ohm)
    inertia = sci_value(motor.inertia_kg_m2)
    viscous = sci_value(motor.viscous_friction_unm_per_rad_s) * SciNumber(1, -6)
    load = sci_value(motor.load_torque_mnm) * SciNumber(1, -3)
    rad_per_count = _TWO_PI / SciNumber.from_int(motor.counts_per_revolution)
    damping = kt * kt / resistance + viscous
    tau_s = inertia / damping
    drive = kt / resistance / damping / rad_per_count * SciNumber(1, 6)
    friction_speed = load / damping / rad_per_count * SciNumber(1, 6)
    step_s = SciNumber.from_int(tick_us) * SciNumber(1, -6) / SciNumber.from_int(steps)
    decay, lag = decay_and_lag(float(step_s) / float(tau_s), float(tau_s))
    return MotorConstants(
        steps=steps,
        drive=_pair(drive),
        friction_speed=_pair(friction_speed),
        decay=_pair(SciNumber.from_float(decay, digits=DIGITS)),
        lag_s=_pair(SciNumber.from_float(lag, digits=DIGITS)),
        tick_us=tick_us,
        stop_low_micro=(motor.travel_lower_counts - motor.overtravel_counts) * MICRO,
        stop_high_micro=(motor.travel_upper_counts + motor.overtravel_counts + 1) * MICRO - 1,
    )


SERIES_TERMS = 24
"""Terms of the series :func:`decay_and_lag` sums (the last is below 1e-30 of the first)."""


def decay_and_lag(ratio: float, tau_s: float) -> tuple[float, float]:
    """``F = 1 - exp(-ratio)`` and ``Q = tau_s * (ratio - F)``, by one fixed sequence of
    binary64 additions, multiplications and divisions (no library function), so that every
    implementation with IEEE-754 arithmetic (Python's floats, a C firmware's soft float)
    gets the same bits: a library's ``expm1`` is not correctly rounded everywhere, and ``Q``
    cancels almost all of ``ratio`` for a slow motor, which would magnify its last bit.

    ``x`` is ``ratio`` halved until it is at most 0.5 (exact, in binary); ``g = x - (1 -
    exp(-x)) = x^2/2! - x^3/3! + ...`` is summed from its smallest term up; then ``F = x - g``
    and ``Q = tau_s * g`` when no halving was needed, else ``exp(-ratio)`` is ``(1 - (x -
    g))`` squared once per halving, ``F`` one minus that and ``Q = tau_s * (ratio - F)``.
    """
    halvings = 0
    x = ratio
    while x > 0.5:
        x = x / 2.0
        halvings += 1
    terms = [x * x / 2.0]
    for k in range(3, SERIES_TERMS + 2):
        terms.append(terms[-1] * x / float(k))
    g = terms[-1]
    for term in reversed(terms[:-1]):
        g = term - g
    if halvings == 0:
        return x - g, tau_s * g
    survivor = 1.0 - (x - g)
    for _ in range(halvings):
        survivor = survivor * survivor
    decay = 1.0 - survivor
    return decay, tau_s * (ratio - decay)


def motor_step(
    theta_micro: int,
    omega_micro: int,
    drive_c: int,
    drive_e: int,
    friction_c: int,
    friction_e: int,
    decay_c: int,
    decay_e: int,
    lag_c: int,
    lag_e: int,
    step_num_us: int,
    step_den: int,
    stop_low_micro: int,
    stop_high_micro: int,
) -> tuple[int, int]:
    """One integration step of the motor under a constant voltage.

    Parameters:
        theta_micro: shaft position, micro-counts (not wrapped).
        omega_micro: shaft speed, micro-counts/s.
        drive_c, drive_e: ``g_v * V``, the speed the voltage alone would reach, micro-counts/s.
        friction_c, friction_e: ``w_f``, micro-counts/s (not negative).
        decay_c, decay_e: ``F`` of the step.
        lag_c, lag_e: ``Q`` of the step, s.
        step_num_us, step_den: the step lasts ``step_num_us / step_den`` microseconds.
        stop_low_micro, stop_high_micro: hard stops, micro-counts.

    Returns the new ``(theta_micro, omega_micro)``.
    """
    if omega_micro > 0:
        direction = 1
    elif omega_micro < 0:
        direction = -1
    else:
        magnitude = drive_c if drive_c >= 0 else -drive_c
        if sci_compare(magnitude, drive_e, friction_c, friction_e) <= 0:
            return theta_micro, 0
        direction = 1 if drive_c > 0 else -1
    if direction > 0:
        target_c, target_e = sci_sub(drive_c, drive_e, friction_c, friction_e, DIGITS)
    else:
        target_c, target_e = sci_add(drive_c, drive_e, friction_c, friction_e, DIGITS)
    if sci_compare(target_c, target_e, _OMEGA_MAX_C, _OMEGA_MAX_E) > 0:
        target_c, target_e = _OMEGA_MAX_C, _OMEGA_MAX_E
    elif sci_compare(target_c, target_e, -_OMEGA_MAX_C, _OMEGA_MAX_E) < 0:
        target_c, target_e = -_OMEGA_MAX_C, _OMEGA_MAX_E
    gap = omega_micro - sci_to_int(target_c, target_e)
    gap_c, gap_e = sci_from_int(gap, DIGITS)
    change_c, change_e = sci_mul(gap_c, gap_e, decay_c, decay_e, DIGITS)
    new_omega = omega_micro - sci_to_int(change_c, change_e)
    lag_travel_c, lag_travel_e = sci_mul(gap_c, gap_e, lag_c, lag_e, DIGITS)
    travel = _trunc_div(omega_micro * step_num_us, step_den * MICRO) - sci_to_int(
        lag_travel_c, lag_travel_e
    )
    if direction > 0:
        new_omega = max(new_omega, 0)
        travel = max(travel, 0)
    else:
        new_omega = min(new_omega, 0)
        travel = min(travel, 0)
    theta = theta_micro + travel
    if theta < stop_low_micro:
        return stop_low_micro, 0
    if theta > stop_high_micro:
        return stop_high_micro, 0
    return theta, new_omega


def _trunc_div(numerator: int, denominator: int) -> int:
    """``numerator / denominator`` truncated toward zero (C semantics; ``denominator > 0``)."""
    if numerator >= 0:
        return numerator // denominator
    return -((-numerator) // denominator)


def motor_tick(
    theta_micro: int,
    omega_micro: int,
    volt_c: int,
    volt_e: int,
    constants: MotorConstants,
) -> tuple[int, int]:
    """Advance the motor over one servo tick at a constant voltage (a test and tool hook).

    ``volt_c * 10**volt_e`` volts, normalised to 4 digits. Runs the same steps as core1.
    """
    drive_c, drive_e = sci_mul(volt_c, volt_e, *constants.drive, DIGITS)
    for _ in range(constants.steps):
        theta_micro, omega_micro = motor_step(
            theta_micro,
            omega_micro,
            drive_c,
            drive_e,
            *constants.friction_speed,
            *constants.decay,
            *constants.lag_s,
            constants.tick_us,
            constants.steps,
            constants.stop_low_micro,
            constants.stop_high_micro,
        )
    return theta_micro, omega_micro
