"""The simulated stepper and the step/direction drive's arithmetic (calls 44-48).

The motor is a two-phase hybrid stepper on a current-regulating driver set to ``u``
microsteps per full step. At the shaft, in microsteps (``theta``: micro-microsteps from
power-up, ``omega``: micro-microsteps per second)::

    J domega/dt = T_m + T_d - b omega - T_load sign(omega)
    T_m = T_a(omega) sin(2 pi (p - theta) / (4 u))      the driver's field at step count p
    T_a = T_hold                  while |omega| <= omega_c
        = T_hold omega_c / |omega| above (the driver can no longer force its current in)
    T_d = -T_detent sin(2 pi theta / u)                  the detent, one per full step

An electrical cycle is 4 full steps (two phases, each reversed): the field pulls the rotor
toward the step count with a torque that peaks a full step away and reverses beyond two,
so a rotor that falls more than two full steps behind slips to the next cycle and loses
its 4 full steps, as a real one does. Unpowered (the driver's enable off: the servo
disabled with no fault latched) only the detent holds it.

Integer arithmetic throughout, as the firmware computes it: the sine is a table of
:data:`SINE_SIZE` entries scaled by :data:`SINE_ONE` (the firmware's copy is generated
from this one), torques are integer micro-newton-metres, and the products with the
friction and inertia constants are 4-digit scientific-notation numbers. Each servo tick
is integrated in ``steps`` equal sub-steps (call 12's interval) by semi-implicit Euler
(velocity first, then the position with the new velocity); the steps a tick issues reach
the field spread evenly over its sub-steps. A sub-step in which the velocity would
reverse ends at rest (friction reverses there); a hard stop beyond each limit switch
stops the shaft dead.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from usbmotion.protocol.table import max_steps_per_tick
from usbmotion.protocol.table import step_periods as cycles
from usbmotion.scimath import SciNumber, sci_from_int, sci_mul, sci_to_int

DIGITS = 4
MICRO = 1_000_000
"""Fixed-point scale of the shaft: micro-microsteps and micro-microsteps per second."""
SINE_SIZE = 1024
"""Entries of the sine table: one full turn of the angle."""
SINE_ONE = 1 << 14
"""The sine table's 1.0."""
SINE: npt.NDArray[np.int64] = np.array(
    [round(SINE_ONE * math.sin(2.0 * math.pi * i / SINE_SIZE)) for i in range(SINE_SIZE)],
    dtype=np.int64)
"""``round(16384 sin(2 pi i / 1024))``: the same integers in every implementation (the
firmware's table is generated from this one)."""
STEPPER_OMEGA_MAX = 10**13
"""Speed bound of the model, micro-microsteps/s (10**7 microsteps/s)."""
_TWO_PI = SciNumber(6283, -3)


@dataclass(frozen=True, slots=True)
class StepperParams:
    """The simulated stepper and its driver as calls 45-47 set them (power-up values: a
    NEMA 17 stepper rated 2 A, 0.59 N m, on a 24 V driver at 16 microsteps)."""

    full_steps: int = 200
    microsteps: int = 16
    pulse_ns: int = 2000
    setup_ns: int = 1000
    holding_mnm: int = 590
    detent_mnm: int = 20
    corner_rpm: int = 760

    @property
    def microsteps_per_revolution(self) -> int:
        return self.full_steps * self.microsteps


@dataclass(frozen=True, slots=True)
class StepperConstants:
    """What core1 needs of the stepper for one servo period, as plain integers."""

    max_steps: int
    """Steps one tick can issue (call 48's ``max_per_tick``)."""
    cycle: int
    """An electrical cycle (4 full steps), micro-microsteps."""
    full: int
    """A full step, micro-microsteps."""
    holding_unm: int
    detent_unm: int
    corner: int
    """The corner speed, microsteps/s."""
    load_unm: int
    viscous: tuple[int, int]
    """Viscous torque per speed, uNm per micro-microstep/s (scientific notation)."""
    accel: tuple[int, int]
    """Speed change per uNm over one sub-step, micro-microsteps/s (scientific notation)."""


def derive_stepper(stepper: StepperParams, *, tick_us: int, substeps: int,
                   inertia: SciNumber, viscous_unm: SciNumber,
                   load_mnm: SciNumber) -> StepperConstants:
    """The integration constants of the stepper for a servo period of ``tick_us`` in
    ``substeps`` sub-steps, with the shaft's inertia (kg m^2), viscous friction (uNm per
    rad/s) and load torque (mNm) of calls 17, 32 and 33: scientific-notation operations
    only, in this order (the firmware repeats them)."""
    per_rev = SciNumber.from_int(stepper.microsteps_per_revolution)
    micro = SciNumber(1, 6)
    step_s = SciNumber.from_int(tick_us) * SciNumber(1, -6) / SciNumber.from_int(substeps)
    accel = per_rev * micro / _TWO_PI * SciNumber(1, -6) / inertia * step_s
    viscous = viscous_unm * _TWO_PI / per_rev / micro
    return StepperConstants(
        max_steps=max_steps_per_tick(tick_us, stepper.pulse_ns, stepper.setup_ns),
        cycle=4 * stepper.microsteps * MICRO,
        full=stepper.microsteps * MICRO,
        holding_unm=stepper.holding_mnm * 1000,
        detent_unm=stepper.detent_mnm * 1000,
        corner=stepper.corner_rpm * stepper.microsteps_per_revolution // 60,
        load_unm=sci_to_int(*_pair(load_mnm * SciNumber(1, 3))),
        viscous=_pair(viscous),
        accel=_pair(accel),
    )


def _pair(number: SciNumber) -> tuple[int, int]:
    return number.coefficient, number.exponent


def trunc_div(numerator: int, denominator: int) -> int:
    """``numerator / denominator`` truncated toward zero (C semantics; ``denominator > 0``)."""
    if numerator >= 0:
        return numerator // denominator
    return -((-numerator) // denominator)


def travel(omega: int, num: int, den: int) -> int:
    """``omega * num / den`` truncated toward zero, for ``|omega| <= STEPPER_OMEGA_MAX``,
    ``0 < num <= 10**6`` and ``10**6 <= den <= 10**10`` (the travel of a sub-step), without
    an int64 overflow: ``10**13 * 10**6`` does not fit an int64, so the kernel could not form
    the product. With ``|omega| = q den + r``: ``q num + (r num) // den``, exactly."""
    magnitude = omega if omega >= 0 else -omega
    whole = magnitude // den
    moved = whole * num + (magnitude - whole * den) * num // den
    return moved if omega >= 0 else -moved


SPEED_CHANGE_CAP = 10**15
"""A speed change taken as this (with its sign) when it is larger: any change beyond
``2 * STEPPER_OMEGA_MAX`` takes the speed past the bound, or through 0 (a reversal, which
stops it), so the result is the same as with the exact change; ``10**15`` is such a change
and stays within an int64 where the exact one (up to ``10**34`` with call 17's smallest
inertia) does not."""


def speed_change(coefficient: int, exponent: int) -> int:
    """``sci_to_int(coefficient, exponent)`` of a normalised speed change, capped at
    :data:`SPEED_CHANGE_CAP` in magnitude (micro-microsteps/s)."""
    if exponent > 11:   # at least 1000e12
        return -SPEED_CHANGE_CAP if coefficient < 0 else SPEED_CHANGE_CAP
    return sci_to_int(coefficient, exponent)


def sine_at(angle: int, period: int) -> int:
    """``SINE_ONE * sin(2 pi angle / period)`` from the table (``period > 0``; the angle
    taken modulo the period, never negative)."""
    return int(SINE[(angle % period) * SINE_SIZE // period])


def encoder_microsteps(shaft: int, counts_per_revolution: int, per_revolution: int) -> int:
    """An encoder of ``counts_per_revolution`` on a shaft standing at ``shaft`` whole
    microsteps (of ``per_revolution`` a turn): its count (floored) in microsteps
    (floored)."""
    count = (shaft * counts_per_revolution) // per_revolution
    return (count * per_revolution) // counts_per_revolution


def stepper_step(
    theta: int,
    omega: int,
    field: int,
    powered: int,
    cycle: int,
    full: int,
    holding: int,
    detent: int,
    corner: int,
    load: int,
    viscous_c: int,
    viscous_e: int,
    accel_c: int,
    accel_e: int,
    step_num_us: int,
    step_den: int,
    stop_low: int,
    stop_high: int,
) -> tuple[int, int]:
    """One integration sub-step of the stepper.

    Parameters:
        theta, omega: the shaft, micro-microsteps and micro-microsteps/s.
        field: the driver's step count over this sub-step, micro-microsteps.
        powered: 1 while the driver is enabled (the field pulls), 0 unpowered.
        cycle, full: an electrical cycle and a full step, micro-microsteps.
        holding, detent, load: torques, uNm; corner: microsteps/s.
        viscous_c, viscous_e: uNm per micro-microstep/s.
        accel_c, accel_e: micro-microsteps/s per uNm over the sub-step.
        step_num_us, step_den: the sub-step lasts ``step_num_us / step_den`` microseconds.
        stop_low, stop_high: hard stops, micro-microsteps.

    Returns the new ``(theta, omega)``.
    """
    pull = 0
    if powered == 1:
        speed = (omega if omega >= 0 else -omega) // MICRO
        available = holding if speed <= corner else holding * corner // speed
        pull = trunc_div(available * sine_at(field - theta, cycle), SINE_ONE)
    torque = pull - trunc_div(detent * sine_at(theta, full), SINE_ONE)
    if omega == 0:
        if -load <= torque <= load:
            return theta, 0
        net = torque - load if torque > 0 else torque + load
    else:
        o_c, o_e = sci_from_int(omega, DIGITS)
        v_c, v_e = sci_mul(o_c, o_e, viscous_c, viscous_e, DIGITS)
        net = torque - sci_to_int(v_c, v_e) - (load if omega > 0 else -load)
    n_c, n_e = sci_from_int(net, DIGITS)
    a_c, a_e = sci_mul(n_c, n_e, accel_c, accel_e, DIGITS)
    new_omega = omega + speed_change(a_c, a_e)
    if (omega > 0 and new_omega < 0) or (omega < 0 and new_omega > 0):
        new_omega = 0
    if new_omega > STEPPER_OMEGA_MAX:
        new_omega = STEPPER_OMEGA_MAX
    elif new_omega < -STEPPER_OMEGA_MAX:
        new_omega = -STEPPER_OMEGA_MAX
    theta += travel(new_omega, step_num_us, step_den * MICRO)
    if theta < stop_low:
        return stop_low, 0
    if theta > stop_high:
        return stop_high, 0
    return theta, new_omega


__all__ = ["MICRO", "SINE", "SINE_ONE", "SINE_SIZE", "StepperConstants", "StepperParams",
           "cycles", "derive_stepper", "encoder_microsteps", "max_steps_per_tick",
           "sine_at", "speed_change", "stepper_step", "travel", "trunc_div"]
