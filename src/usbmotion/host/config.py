"""The machine configuration: one TOML file read into frozen, validated dataclasses.

A file names the machine-wide settings at its top level and one ``[axes.<LETTER>]`` table
per axis, with optional ``gains``, ``velocity_gains``, ``homing``, ``sim`` and ``reach``
sub-tables (see ``examples/machine.toml`` and ``examples/real-machine.toml``). Every key is
checked: an unknown key (named before anything else in its table, with the closest known
key), a value of the wrong type or out of its range, a missing required key, and a
``max_velocity_mm_s`` or ``max_accel_mm_s2`` the axis's motor cannot reach with
:data:`REACH_MARGIN` to spare (from the motor model of a simulated axis, from the ``reach``
that ``usbmotion tune --reach`` measured on a real one) are
:class:`~usbmotion.errors.ConfigError` s naming the file, the dotted key
(``axes.X.max_accel_mm_s2``), the line when it can be found, and what is allowed.
"""

from __future__ import annotations

import difflib
import math
import re
import tomllib
from collections.abc import Callable, Mapping
from dataclasses import dataclass, replace
from importlib import resources
from pathlib import Path
from typing import Any, NoReturn

from usbmotion.errors import ConfigError
from usbmotion.host.device import AxisScale, to_sci
from usbmotion.motor_model import DcMotorModel
from usbmotion.protocol import (
    BY_NUMBER,
    DEVICE_NAME_MAX,
    QUEUE_CAPACITY,
    CallNumber,
    device_name_problem,
)
from usbmotion.protocol.names import Drive
from usbmotion.protocol.table import INT32_MAX, INT32_MIN, max_steps_per_tick

AXIS_LETTERS = ("X", "Y", "Z", "A", "B", "C", "U", "V", "W")
DIALECTS = ("linuxcnc", "grbl", "marlin")
"""The G-code dialects a machine file may name (those of ``usbmotion.motion.dialects``)."""
"""Axis names a machine may use: the RS274/NGC axis letters."""

SIM_SCHEME = "sim://"

_WATCHDOG_SLACK_MS = 250
"""Watchdog headroom over the time a full motion queue lasts (a host may be quiet that long)."""


# --- the dataclasses -------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class PidGains:
    """The PID gains of one axis's position loop (calls 9-11; 3 significant digits each).

    Fields:
        kp: proportional gain, volts per count of following error.
        ki: integral gain, volts per count-second.
        kd: derivative gain, volt-seconds per count.
    """

    kp: float
    ki: float
    kd: float


VELOCITY_GAINS_DEFAULT = PidGains(kp=0.001, ki=0.5, kd=0.0)
SPINDLE_GAINS_DEFAULT = PidGains(kp=0.001, ki=0.1, kd=0.0)
"""A spindle's velocity loop when its table gives none (the default simulated spindle)."""
"""Velocity-mode gains when a file gives none: a PI loop that holds the default simulated
motor within a count per second of its target. The velocity it is fed is measured over one
servo tick (1000 counts/s per count at 1 ms), so a small ``kp`` keeps that quantisation
from chattering the output; ``ki`` acts on the integrated error, a position error."""


@dataclass(frozen=True, slots=True)
class HomingConfig:
    """How one axis finds its reference switch.

    Fields:
        direction: ``-1`` homes onto the lower limit switch (the seed's way), ``+1`` onto
            the upper one.
        speed_mm_s: approach speed toward the switch, mm/s.
        slow_speed_mm_s: back-off and slow re-approach speed, mm/s.
        backoff_mm: distance to back off the switch before the slow re-approach, mm
            (0: take the zero on the first touch).
        position_mm: the machine position of the switch's closing edge: the device latches
            the count of that edge and homing gives it this position. It is outside the
            working travel (below ``travel_mm``'s lowest when homing down), so a program
            that goes to the end of the travel (``G0 X0``) never closes the switch; by
            default ``pull_off_mm`` beyond that end.
        pull_off_mm: how far homing moves the axis off the switch at the end (a planned
            move, > 0); the axis then stands at ``position_mm`` + ``pull_off_mm`` (homing
            down), which must be inside the travel.
        search_mm: the longest the seek for the switch may go before homing fails naming
            the axis and the distance (default 1.5 x the travel).
        declare: no switch: homing declares that the axis stands at ``position_mm`` (a
            rotary axis, a wrapped one always).
    """

    direction: int
    speed_mm_s: float
    slow_speed_mm_s: float
    backoff_mm: float
    position_mm: float
    pull_off_mm: float = 1.0
    search_mm: float = math.inf
    declare: bool = False


SIM_MOTOR_CALLS: tuple[tuple[str, CallNumber], ...] = (
    ("source_voltage_v", CallNumber.SET_SIM_SOURCE_VOLTAGE),
    ("torque_constant_mnm_per_a", CallNumber.SET_SIM_TORQUE_CONSTANT),
    ("winding_resistance_ohm", CallNumber.SET_SIM_WINDING_RESISTANCE),
    ("inertia_kg_m2", CallNumber.SET_SIM_INERTIA),
    ("viscous_friction_unm_per_rad_s", CallNumber.SET_SIM_VISCOUS_FRICTION),
    ("load_torque_mnm", CallNumber.SET_SIM_LOAD_TORQUE),
)
"""Each value of :class:`SimMotorConfig` the device takes as 4 significant digits, with the
call that sets it."""


@dataclass(frozen=True, slots=True)
class SimMotorConfig:
    """The simulated motor behind a simulated axis (calls 12-17, 32, 33 and 34).

    Fields:
        update_interval_dms: motor integration step, tenths of a millisecond (at most the
            servo period).
        source_voltage_v: supply voltage, the ceiling of the PID output, volts.
        torque_constant_mnm_per_a: torque constant, mNm per ampere (equal to the back-EMF
            constant in SI units).
        winding_resistance_ohm: winding resistance, ohms.
        counts_per_revolution: encoder counts per output-shaft revolution (quadrature x4).
        inertia_kg_m2: rotor plus load inertia at the encoder shaft, kg m^2.
        viscous_friction_unm_per_rad_s: viscous friction at the encoder shaft, micro-newton-metres
            per rad/s.
        load_torque_mnm: constant load torque opposing motion, mNm.
        start_mm: where the carriage stands at power-up, in machine millimetres; the
            simulated limit switches close ``switch_margin_mm`` beyond the ends of the
            axis's ``travel_mm``, relative to it.
        probe_side: where a probe touches on this axis (call 40): 0 nowhere, 1 at or below
            ``probe_mm`` (a plate under a Z probe: the file's ``probe_below_mm``), 2 at or
            above it (``probe_above_mm``).
        probe_mm: the probe's surface, machine millimetres.
    """

    update_interval_dms: int
    source_voltage_v: float
    torque_constant_mnm_per_a: float
    winding_resistance_ohm: float
    counts_per_revolution: int
    inertia_kg_m2: float
    viscous_friction_unm_per_rad_s: float
    load_torque_mnm: float
    start_mm: float
    probe_side: int = 0
    probe_mm: float = 0.0
    magnet_angle_deg: float = 0.0

    def model(self) -> DcMotorModel:
        """The motor's continuous model, each value to the 4 significant digits the device's
        call carries (so the figures are those of the motor the device simulates)."""

        def sent(value: float, label: str) -> float:
            coefficient, exponent = to_sci(value, digits=4, parameter=label)
            return float(coefficient) * 10.0 ** exponent if coefficient else 0.0

        return DcMotorModel(
            torque_constant_nm_per_a=sent(self.torque_constant_mnm_per_a,
                                          "torque_constant_mnm_per_a") * 1e-3,
            resistance_ohm=sent(self.winding_resistance_ohm, "winding_resistance_ohm"),
            inertia_kg_m2=sent(self.inertia_kg_m2, "inertia_kg_m2"),
            viscous_nm_s_per_rad=sent(self.viscous_friction_unm_per_rad_s,
                                      "viscous_friction_unm_per_rad_s") * 1e-6,
            load_torque_nm=sent(self.load_torque_mnm, "load_torque_mnm") * 1e-3,
            counts_per_revolution=self.counts_per_revolution,
            source_voltage_v=sent(self.source_voltage_v, "source_voltage_v"),
        )


SIM_MOTOR_DEFAULTS: Mapping[str, float] = {
    "update_interval_dms": 10,
    "source_voltage_v": 12.0,
    "torque_constant_mnm_per_a": 334.6,
    "winding_resistance_ohm": 2.182,
    "counts_per_revolution": 1920,
    "inertia_kg_m2": 1.1e-3,
    "viscous_friction_unm_per_rad_s": 500.0,
    "load_torque_mnm": 50.0,
}
"""The simulated motor of a ``sim`` table's omitted keys: the device's own power-up
defaults (``usbmotion.device.motor.MotorParams``), a 12 V 30:1 gearmotor with a 64 CPR
encoder (1920 counts per output revolution)."""


REACH_MARGIN = 0.1
"""The share of the motor's full-voltage capability an axis's limits leave to the PID.

At the worst point of a planned move, top speed ``v`` while still accelerating at ``a``,
an axis uses ``v / v_top + a / a_0`` of what its motor can do at the full source voltage
(:class:`AxisReach`): that is the share of the supply the motion itself needs (exactly so
without load torque; with it, the share is a little higher). ``max_velocity_mm_s`` and
``max_accel_mm_s2`` may use at most ``1 - REACH_MARGIN`` of it, so the PID keeps a tenth of
the supply to correct errors, and the few percent by which a measured reach, a warm winding
or a sagging supply may be off do not make the limits unreachable."""


@dataclass(frozen=True, slots=True)
class AxisReach:
    """What an axis's motor can do at its full source voltage, in axis units.

    A DC motor's torque falls on a straight line from standstill to its no-load speed as the
    back-EMF grows, so two figures describe it: the acceleration available at speed ``v`` is
    ``accel_mm_s2 * (1 - v / velocity_mm_s)``, from ``(Kt (V - Kt w)/R - b w - T_load) / J``.

    Fields:
        velocity_mm_s: top speed: the no-load speed under the axis's own friction and load
            torque, mm/s.
        accel_mm_s2: acceleration from standstill, mm/s^2.
    """

    velocity_mm_s: float
    accel_mm_s2: float

    def accel_at_mm_s2(self, velocity_mm_s: float) -> float:
        """The acceleration available at ``velocity_mm_s`` (0 from top speed on), mm/s^2."""
        return max(0.0, self.accel_mm_s2 * (1.0 - velocity_mm_s / self.velocity_mm_s))

    @property
    def usable_velocity_mm_s(self) -> float:
        """The fastest ``max_velocity_mm_s`` that keeps :data:`REACH_MARGIN`, mm/s."""
        return (1.0 - REACH_MARGIN) * self.velocity_mm_s

    def usable_accel_mm_s2(self, velocity_mm_s: float) -> float:
        """The largest ``max_accel_mm_s2`` that keeps :data:`REACH_MARGIN` with
        ``max_velocity_mm_s = velocity_mm_s``, mm/s^2."""
        share = 1.0 - REACH_MARGIN - velocity_mm_s / self.velocity_mm_s
        return max(0.0, self.accel_mm_s2 * share)


def simulated_reach(sim: SimMotorConfig, counts_per_mm: float) -> AxisReach:
    """The reach of a simulated motor at its full source voltage, from the motor model.

    Top speed: the model's steady speed under the source voltage, with the load torque and
    viscous friction, ``(Kt V/R - T_load) / (Kt^2/R + b)``. Acceleration from standstill:
    the stall torque after the load torque over the inertia, ``(Kt V/R - T_load) / J``.
    Both through ``counts_per_revolution`` and ``counts_per_mm``; a motor whose load torque
    is at least its stall torque has a reach of 0.
    """
    motor = sim.model()
    speed_counts_s = motor.steady_speed_counts_s(motor.source_voltage_v)
    accel_counts_s2 = max(0.0, motor.stall_torque_nm()) / motor.inertia_kg_m2 * (
        motor.counts_per_rad)
    return AxisReach(speed_counts_s / counts_per_mm, accel_counts_s2 / counts_per_mm)


AXIS_KINDS = ("servo", "stepper")
"""What drives an axis: a DC servo (a brushed motor, its encoder and the device's PID) or a
stepper on a step/direction driver (call 44)."""
STEPPER_LOOPS = ("open", "closed")
"""A stepper axis's loop: ``open`` (the position is the steps issued) or ``closed`` (an
encoder on the shaft, the PID's output leading it by at most one full step)."""
STEPPER_GAINS_DEFAULT = PidGains(kp=0.2, ki=1.0, kd=0.001)
"""A closed-loop stepper's gains when its file gives none: the field's lead over the rotor
(microsteps, saturated at a full step) per microstep of error, per microstep-second, per
microstep/s. On the simulated NEMA 17 of ``examples/stepper.toml``'s Z they rest on the
count and follow at 1 kHz and at 10 kHz (at 10 kHz higher gains follow closer:
docs/setup.md); demo 1 on emulated chips at 1 kHz peaks at 11 microsteps."""
OPEN_LOOP_MARGIN = 0.6
"""The share of a simulated open-loop stepper's torque its limits leave unused (a closed
loop leaves :data:`REACH_MARGIN`). An open-loop rotor rings on the field like a lightly
damped spring at every change of acceleration, and lags further than the steady torque
says: on ``examples/stepper.toml``'s X and Y (1.1e-5 kg m^2), moves at 50 mm/s with no
loss up to 26,500 mm/s^2 (45 % of the torque), steps lost at 30,000 (51 %) and beyond."""
OPEN_LOOP_GAINS = PidGains(kp=0.0, ki=0.0, kd=0.0)
"""An open-loop stepper runs no PID: the device ignores its gains; these are sent."""
ENCODER_KINDS = ("incremental", "absolute")
"""An axis's encoder: ``incremental`` (quadrature, counting from power-up) or ``absolute``
within a turn (an AS5161-style magnetic encoder's PWM angle, call 49)."""


@dataclass(frozen=True, slots=True)
class AbsoluteEncoder:
    """An axis's absolute encoder (``encoder = "absolute"``, call 49 kind 1): the device
    knows the shaft's angle within a turn from power-up, and homing names the turn.

    Fields:
        turn_counts: one turn of the encoder in counts of the device's counter (call 16's
            counts per revolution on a servo; microsteps per revolution on a closed-loop
            stepper).
        magnet_counts: a simulated encoder's magnet: the angle it reads with the simulated
            shaft at 0, counts (the ``sim`` table's ``magnet_angle_deg``); 0 on hardware.
    """

    turn_counts: int
    magnet_counts: int = 0

    def angle_counts(self, counts: int, zero: int) -> int:
        """The absolute angle within a turn of the counter value ``counts``, given where
        the turns begin (call 49's ``zero``)."""
        return (counts - zero) % self.turn_counts


@dataclass(frozen=True, slots=True)
class StepperConfig:
    """A stepper axis's motor and driver (calls 44-46, and call 16 for its encoder).

    Fields:
        loop: ``"open"`` or ``"closed"`` (:data:`STEPPER_LOOPS`).
        full_steps_per_rev: the motor's full steps per revolution (200: 1.8 degrees).
        microsteps: microsteps per full step, as set on the driver.
        encoder_counts_per_rev: the closed loop's encoder, counts per revolution
            (quadrature x4); ``None`` open loop.
        step_pulse_ns: the step pulse's high time (and at least as long low), ns.
        dir_setup_ns: the direction set-up time before a step edge, ns.
    """

    loop: str
    full_steps_per_rev: int
    microsteps: int
    encoder_counts_per_rev: int | None
    step_pulse_ns: int
    dir_setup_ns: int

    @property
    def closed(self) -> bool:
        """True for a closed loop."""
        return self.loop == "closed"

    @property
    def drive(self) -> Drive:
        """Call 44's drive."""
        return Drive.STEP_CLOSED if self.closed else Drive.STEP_OPEN

    @property
    def microsteps_per_rev(self) -> int:
        """Microsteps per motor revolution."""
        return self.full_steps_per_rev * self.microsteps

    def steps_per_tick(self, tick_us: int) -> int:
        """The most steps one servo tick of ``tick_us`` issues, as the device counts them
        (:func:`~usbmotion.protocol.table.max_steps_per_tick`)."""
        return max_steps_per_tick(tick_us, self.step_pulse_ns, self.dir_setup_ns)


@dataclass(frozen=True, slots=True)
class SimStepperConfig:
    """The simulated stepper behind a simulated stepper axis (calls 12, 17, 32-34, 40, 47).

    Fields:
        update_interval_dms: integration step, tenths of a millisecond (1 = 100 us: a
            stepper's field turns within a millisecond; at most the servo period).
        holding_torque_mnm: the holding torque at the driver's current, mNm.
        detent_torque_mnm: the unpowered detent torque, mNm.
        corner_rpm: the speed above which the driver's current, and the torque, fall as
            1/speed, rpm.
        inertia_kg_m2: rotor plus load inertia at the motor shaft, kg m^2.
        viscous_friction_unm_per_rad_s: viscous friction at the shaft, uNm per rad/s.
        load_torque_mnm: constant load torque opposing motion, mNm.
        start_mm, probe_side, probe_mm: as :class:`SimMotorConfig`'s.
    """

    update_interval_dms: int
    holding_torque_mnm: int
    detent_torque_mnm: int
    corner_rpm: int
    inertia_kg_m2: float
    viscous_friction_unm_per_rad_s: float
    load_torque_mnm: float
    start_mm: float
    probe_side: int = 0
    probe_mm: float = 0.0
    magnet_angle_deg: float = 0.0

    def torque_nm(self, rpm: float) -> float:
        """The most torque the driver's field gives at ``rpm``, N m: the holding torque up
        to the corner speed, falling as 1/speed above it."""
        speed = abs(rpm)
        held = self.holding_torque_mnm * 1e-3
        return held if speed <= self.corner_rpm else held * self.corner_rpm / speed


SIM_STEPPER_DEFAULTS: Mapping[str, float] = {
    "update_interval_dms": 1,
    "holding_torque_mnm": 590,
    "detent_torque_mnm": 20,
    "corner_rpm": 760,
    "inertia_kg_m2": 8.2e-6,
    "viscous_friction_unm_per_rad_s": 20.0,
    "load_torque_mnm": 10.0,
}
"""The simulated stepper of a stepper axis's ``sim`` table's omitted keys: the device's
power-up stepper (a NEMA 17 rated 2 A, 0.59 N m, on a 24 V driver: call 47), its rotor's
8.2e-6 kg m^2 alone, and a bearing's friction; a file adds its screw and carriage."""


@dataclass(frozen=True, slots=True)
class StepperReach:
    """What a stepper can do, in axis units: the torque its driver's field gives (the holding
    torque up to the corner speed, falling as 1/speed above) less what friction, the load
    and the detent take, over the inertia.

    Fields:
        per_mm_rad: motor radians per mm of travel (``2 pi steps_per_mm / microsteps per
            revolution``).
        holding_nm: the holding torque, N m.
        corner_mm_s: the corner speed in axis mm/s.
        drag_nm: the torque friction and the load take at standstill plus the detent's
            ripple (the worst case), N m.
        viscous_nm_s: viscous friction, N m per rad/s.
        inertia_kg_m2: inertia at the shaft.
    """

    per_mm_rad: float
    holding_nm: float
    corner_mm_s: float
    drag_nm: float
    viscous_nm_s: float
    inertia_kg_m2: float

    def torque_nm(self, velocity_mm_s: float) -> float:
        """The field's torque at ``velocity_mm_s``, N m."""
        speed = abs(velocity_mm_s)
        if speed <= self.corner_mm_s:
            return self.holding_nm
        return self.holding_nm * self.corner_mm_s / speed

    def needed_nm(self, velocity_mm_s: float, accel_mm_s2: float) -> float:
        """The torque a move needs at ``velocity_mm_s`` while accelerating at
        ``accel_mm_s2``, N m (the detent's ripple included)."""
        return (self.inertia_kg_m2 * accel_mm_s2 * self.per_mm_rad + self.drag_nm
                + self.viscous_nm_s * velocity_mm_s * self.per_mm_rad)

    def usable_accel_mm_s2(self, velocity_mm_s: float, *, margin: float) -> float:
        """The largest acceleration at ``velocity_mm_s`` that leaves ``margin`` of the
        field's torque unused, mm/s^2 (0 when none)."""
        spare = (1.0 - margin) * self.torque_nm(velocity_mm_s) - self.needed_nm(
            velocity_mm_s, 0.0)
        return max(0.0, spare / (self.inertia_kg_m2 * self.per_mm_rad))

    def usable_velocity_mm_s(self, *, margin: float) -> float:
        """The fastest speed at which the torque, less ``margin``, still holds the move
        against friction, mm/s (0 when even standstill needs more)."""
        if self.usable_accel_mm_s2(0.0, margin=margin) <= 0.0:
            return 0.0
        low, high = 0.0, self.corner_mm_s
        while self.usable_accel_mm_s2(high, margin=margin) > 0.0:
            low, high = high, 2.0 * high
            if high > 1e9:
                return high
        for _ in range(100):
            middle = (low + high) / 2
            if self.usable_accel_mm_s2(middle, margin=margin) > 0.0:
                low = middle
            else:
                high = middle
        return low


def stepper_reach(sim: SimStepperConfig, stepper: StepperConfig,
                  steps_per_mm: float) -> StepperReach:
    """The reach of a simulated stepper (:class:`StepperReach`) through ``steps_per_mm``."""
    per_mm_rev = steps_per_mm / stepper.microsteps_per_rev
    return StepperReach(
        per_mm_rad=2.0 * math.pi * per_mm_rev,
        holding_nm=sim.holding_torque_mnm * 1e-3,
        corner_mm_s=sim.corner_rpm / 60.0 / per_mm_rev,
        drag_nm=(sim.load_torque_mnm + sim.detent_torque_mnm) * 1e-3,
        viscous_nm_s=sim.viscous_friction_unm_per_rad_s * 1e-6,
        inertia_kg_m2=sim.inertia_kg_m2,
    )


@dataclass(frozen=True, slots=True)
class MotorModelConfig:
    """An axis's motor as ``usbmotion tune --auto`` identified it (the file's ``model``
    table), in the drive's units: what volts and counts tell of a brushed DC motor and its
    load (``usbmotion.autotune.model``). ``usbmotion run --predict`` plays a program on it.

    Fields:
        time_constant_s: the mechanical time constant, s.
        speed_per_volt_counts_s: the steady speed one volt above the Coulomb voltage holds,
            counts/s per V.
        coulomb_v: the voltage the Coulomb (load) torque takes, V.
        supply_v: the drive's ceiling, V.
    """

    time_constant_s: float
    speed_per_volt_counts_s: float
    coulomb_v: float
    supply_v: float


@dataclass(frozen=True, slots=True)
class AxisConfig:
    """One axis: which device drives it, its scale, limits, gains and homing.

    Fields:
        name: the axis letter (``X``, ``Y``, ``Z``, ``A``, ...).
        device: the device name written in the device's flash (call 18), by which
            discovery finds it among the serial ports; ``None`` when ``url`` is given alone.
        url: where the device is, when known: ``sim://X`` (an in-process simulated
            device), ``/dev/ttyACM0``, ``COM3``, ``socket://host:port``; ``None`` to find
            ``device`` by discovery.
        counts_per_mm: device counts per millimetre of axis travel (> 0): encoder counts
            on a servo, microsteps on a stepper (its file's ``steps_per_mm``).
        max_velocity_mm_s: the fastest the axis may move, mm/s.
        max_accel_mm_s2: the largest acceleration of the axis, mm/s^2.
        max_jerk_mm_s3: the largest jerk of jerk-limited profiles, mm/s^3.
        travel_mm: (lowest, highest) machine position of the axis, mm.
        gains: the PID gains of position and curve modes (1 and 3): on the position error.
        velocity_gains: the PID gains of velocity mode (2, used by homing): on the velocity
            error, so ``kp`` is in V per count/s and ``ki`` in V per count.
        following_error_limit_mm: a larger |desired - actual| disables the servo and
            latches a fault on the device, mm (0: no limit).
        homing: how the axis homes.
        reach: what the axis's motor can do at full voltage as ``usbmotion tune --reach``
            measured it (the file's ``reach`` table), or ``None``. ``max_velocity_mm_s``
            and ``max_accel_mm_s2`` were checked against it, and against the motor model
            of a simulated axis, keeping :data:`REACH_MARGIN`.
        sim: the simulated motor, for simulated axes (always set for ``sim://`` axes;
            ``None`` on real hardware unless the file gives a ``sim`` table): a DC motor
            (:class:`SimMotorConfig`) on a servo axis, a stepper
            (:class:`SimStepperConfig`) on a stepper axis.
        wrapped: a rotary axis that turns on without end (``wrapped = true``): no travel, no
            soft limits, homed by declaring its angle.
        model: the motor as ``usbmotion tune --auto --write`` identified it (the file's
            ``model`` table), or ``None``.
        stepper: a stepper axis's motor and driver (``kind = "stepper"``), or ``None`` for
            a servo axis. A stepper's ``velocity_gains`` are its ``gains``: in velocity mode
            (homing) it integrates the velocity into its desired position and runs the same
            position loop.
        absolute_encoder: the axis's absolute encoder (``encoder = "absolute"``), or
            ``None`` for an incremental one.

    A rotary axis (A, B, C) is in degrees: its file writes ``counts_per_degree``,
    ``max_velocity_deg_s``, ``travel_deg`` and so on (:data:`_ROTARY_NAMES`), and every
    ``_mm`` field here holds degrees.
    """

    @property
    def rotary(self) -> bool:
        """True for A, B and C: degrees."""
        return self.name in ROTARY_LETTERS

    name: str
    device: str | None
    url: str | None
    counts_per_mm: float
    max_velocity_mm_s: float
    max_accel_mm_s2: float
    max_jerk_mm_s3: float
    travel_mm: tuple[float, float]
    gains: PidGains
    velocity_gains: PidGains
    following_error_limit_mm: float
    homing: HomingConfig
    reach: AxisReach | None
    sim: SimMotorConfig | SimStepperConfig | None
    wrapped: bool = False
    model: MotorModelConfig | None = None
    stepper: StepperConfig | None = None
    absolute_encoder: AbsoluteEncoder | None = None

    @property
    def kind(self) -> str:
        """``"servo"`` or ``"stepper"`` (:data:`AXIS_KINDS`)."""
        return "servo" if self.stepper is None else "stepper"

    @property
    def drive(self) -> Drive:
        """What the axis's device drives (call 44)."""
        return Drive.DC if self.stepper is None else self.stepper.drive

    @property
    def count_words(self) -> str:
        """What the device counts on this axis: ``counts`` or ``microsteps``."""
        return "counts" if self.stepper is None else "microsteps"

    @property
    def scale(self) -> AxisScale:
        """Millimetres to counts for this axis."""
        return AxisScale(self.counts_per_mm)

    @property
    def is_simulated(self) -> bool:
        """True when the axis is an in-process simulated device (a ``sim://`` URL)."""
        return self.url is not None and self.url.lower().startswith(SIM_SCHEME)

    @property
    def label(self) -> str:
        """How messages name the axis's device: ``X (sim://X)``, ``Y (Y AXIS)``."""
        return f"{self.name} ({self.device or self.url})"

    @property
    def following_error_limit_counts(self) -> int:
        """The following-error limit in counts (0: no limit)."""
        return round(self.following_error_limit_mm * self.counts_per_mm)

    @property
    def switch_margin_mm(self) -> float:
        """How far beyond each end of ``travel_mm`` the limit switches close, mm."""
        end = self.travel_mm[0] if self.homing.direction == -1 else self.travel_mm[1]
        return abs(self.homing.position_mm - end)

    @property
    def sim_travel_counts(self) -> tuple[int, int] | None:
        """The simulated switch positions in counts from power-up (call 34), if simulated.

        Each switch closes ``switch_margin_mm`` beyond its end of ``travel_mm``, measured
        from the carriage's power-up position ``sim.start_mm``.
        """
        if self.sim is None:
            return None
        low, high = self.travel_mm
        margin = self.switch_margin_mm
        return (
            round((low - margin - self.sim.start_mm) * self.counts_per_mm),
            round((high + margin - self.sim.start_mm) * self.counts_per_mm),
        )

    @property
    def sim_probe_counts(self) -> tuple[int, int]:
        """The simulated probe surface as call 40 takes it: (side, motor counts from
        power-up); (0, 0) without one."""
        if self.sim is None or not self.sim.probe_side:
            return 0, 0
        return self.sim.probe_side, round((self.sim.probe_mm - self.sim.start_mm)
                                          * self.counts_per_mm)


JOINT_UNITS = ("deg", "mm")
"""The units a joint is in: degrees (a rotary joint) or millimetres (a linear one)."""


@dataclass(frozen=True, slots=True)
class JointConfig:
    """A robot joint (the file's ``[joints.<name>]``): a named position in degrees or mm on
    one axis's device, for :mod:`usbmotion.robot`.

    Fields:
        name: the joint's name (``shoulder``).
        axis: the axis whose device drives it.
        unit: ``"deg"`` or ``"mm"``.
        counts_per_unit: encoder counts per degree (or mm) of the joint (> 0); joint 0 is
            the axis's machine zero.
        max_velocity, max_accel, max_jerk: the joint's limits, unit/s, unit/s^2, unit/s^3
            (by default the axis's, converted).
        range: (lowest, highest) joint value: the axis's travel, converted.
    """

    name: str
    axis: str
    unit: str
    counts_per_unit: float
    max_velocity: float
    max_accel: float
    max_jerk: float
    range: tuple[float, float]


@dataclass(frozen=True, slots=True)
class SpindleConfig:
    """The spindle: a USB Motion Device run in velocity mode (``[spindle]``).

    Fields:
        device, url: the device, as an axis names its own (a name in its flash, a port or
            ``sim://NAME``).
        counts_per_revolution: encoder counts per spindle revolution (quadrature x4).
        max_rpm: the fastest ``S`` a program may ask (a faster one is refused, naming it).
        accel_rpm_s: how fast the speed ramps, rpm per second, up and down (``M5`` and a
            stop decelerate along it).
        at_speed_tolerance: the share of the commanded speed within which the measured
            speed counts as at speed (LinuxCNC's spindle-at-speed); a program's feed moves
            after an ``M3``/``M4``/``S`` wait for it.
        stall_tolerance: once at speed, a measured speed further than this share from the
            commanded one is a stall: an alarm that stops every axis along its path.
        spin_up_timeout_s: the longest a program waits for the spindle to reach speed
            beyond its ramp; then the same alarm.
        velocity_gains: the device's PID in velocity mode (V per count/s, V per count,
            V s per count/s).
        sim: the simulated motor of a ``sim://`` spindle (``[spindle.sim]``; no switches).
    """

    device: str | None
    url: str | None
    counts_per_revolution: int
    max_rpm: float
    accel_rpm_s: float
    at_speed_tolerance: float
    stall_tolerance: float
    spin_up_timeout_s: float
    velocity_gains: PidGains
    sim: SimMotorConfig | None

    @property
    def is_simulated(self) -> bool:
        """True when the spindle is an in-process simulated device (a ``sim://`` URL)."""
        return self.url is not None and self.url.lower().startswith(SIM_SCHEME)

    @property
    def label(self) -> str:
        """How messages name the spindle's device: ``spindle (sim://S)``."""
        return f"spindle ({self.device or self.url})"

    def counts_per_s(self, rpm: float) -> int:
        """A speed in rpm as the device's velocity setpoint, counts per second."""
        return round(rpm * self.counts_per_revolution / 60.0)

    def rpm(self, counts_per_s: float) -> float:
        """A device velocity, counts per second, in rpm."""
        return counts_per_s * 60.0 / self.counts_per_revolution


SPINDLE_SIM_DEFAULTS: Mapping[str, float] = {
    "update_interval_dms": 10,
    "source_voltage_v": 48.0,
    "torque_constant_mnm_per_a": 30.0,
    "winding_resistance_ohm": 0.5,
    "counts_per_revolution": 400,
    "inertia_kg_m2": 5e-5,
    "viscous_friction_unm_per_rad_s": 20.0,
    "load_torque_mnm": 5.0,
}
"""The simulated spindle motor of a ``[spindle.sim]`` table's omitted keys: a 48 V DC
spindle motor (30 mNm/A: about 15,000 rpm without load) with a 100-line encoder (400 counts
per revolution)."""


@dataclass(frozen=True, slots=True)
class OutputPin:
    """Where an output of the machine is: the device of axis ``axis``, its output
    ``output`` (call 42: 0 and 1 digital, 2 and 3 PWM)."""

    axis: str
    output: int


@dataclass(frozen=True, slots=True)
class OutputsConfig:
    """The machine's outputs (``[outputs]``): flood and mist coolant (``M8``, ``M7``,
    ``M9``) on digital outputs, a laser (``M3``/``M4``/``M5`` with ``S`` as its power) on a
    PWM output, each changed on the device tick its move starts on.

    Fields:
        pins: output name (``flood``, ``mist``, ``laser``) -> :class:`OutputPin`.
        laser_max_s: the ``S`` of the laser's full power (grbl's ``$30``).
    """

    pins: Mapping[str, OutputPin]
    laser_max_s: float = 1000.0


@dataclass(frozen=True, slots=True)
class ToolSetterConfig:
    """A fixed tool-length setter (``[tool_setter]``): a probe button at a known place that
    each tool is lowered onto, its contact height against the reference tool's giving the
    tool's length.

    Fields:
        position_mm: the button's X and Y, machine mm.
        start_z_mm: machine Z the measuring descends to at rapid speed, above the button
            with the longest tool.
        lowest_z_mm: the lowest machine Z probing may reach (no contact by then: an error).
        feed_mm_min: the probing feed.
        reference_z_mm: where the reference tool (length 0: the gauge line of the tool
            table's lengths) touches, machine mm; None: not measured yet (a measurement
            then says the contact to write here).
    """

    position_mm: tuple[float, float]
    start_z_mm: float
    lowest_z_mm: float
    feed_mm_min: float
    reference_z_mm: float | None


@dataclass(frozen=True, slots=True)
class MachineConfig:
    """A machine: several axes, each a device, with settings they share.

    Fields:
        path: the file the configuration was read from.
        name: a label for the machine (default: the file's stem).
        axes: the axes, in the order the file lists them.
        servo_interval_dms: servo period of every device, tenths of a millisecond (call 5).
        motion_scalar: servo ticks per motion-queue value (call 6); the motion period is
            ``servo_interval_dms / 10`` ms times this.
        junction_deviation_mm: the planner's cornering tolerance (grbl/Klipper model), mm.
        arc_tolerance_mm: the largest distance between an arc and its chords, mm.
        homing_order: groups of axes homed together, in order: ``(("Z",), ("X", "Y"))``
            homes Z first, then X and Y together. Every axis is in exactly one group.
        watchdog_ms: a device that hears nothing for this long while enabled disables its
            servo and latches a fault (call 28; 0: off). It must outlast a full motion queue.
        reply_timeout_s: how long the host waits for a device's answer, seconds.
        ports: extra ports or URLs discovery searches for device names, besides the
            computer's serial ports (``socket://host:port`` of a ``usbmotion sim --tcp``).
        dialect: how the machine's G-code programs are read: ``"linuxcnc"`` (the
            default), ``"grbl"`` or ``"marlin"`` (:data:`DIALECTS`).
        tool_table: the tool table in LinuxCNC's ``tool.tbl`` format (lengths in mm),
            relative paths from the machine file's folder; ``None``: no table, every tool
            of zero length. A named file that does not exist also means zero lengths.
        parameter_file: where work offsets and G28/G30 positions persist across runs, in
            LinuxCNC's ``.var`` format and numbers; by default the machine file's name
            with ``.var`` (``machine.toml`` -> ``machine.var``), next to it.
        joints: the robot joints the file names (``[joints.<name>]``), in file order.
        spindle: the spindle device (``[spindle]``), or ``None``: ``M3``-``M5`` and ``S``
            are then listed as ignored words.
        outputs: the coolant and laser outputs (``[outputs]``), or ``None``: ``M7``-``M9``
            (and, without a spindle, ``M3``-``M5``, ``S``) are listed as ignored words.
        tool_setter: the tool-length setter (``[tool_setter]``), or ``None``.
    """

    path: Path
    name: str
    axes: tuple[AxisConfig, ...]
    servo_interval_dms: int
    motion_scalar: int
    junction_deviation_mm: float
    arc_tolerance_mm: float
    homing_order: tuple[tuple[str, ...], ...]
    watchdog_ms: int
    reply_timeout_s: float
    ports: tuple[str, ...]
    dialect: str = "linuxcnc"
    tool_table: Path | None = None
    parameter_file: Path | None = None
    joints: tuple[JointConfig, ...] = ()
    spindle: SpindleConfig | None = None
    outputs: OutputsConfig | None = None
    tool_setter: ToolSetterConfig | None = None

    @property
    def parameter_path(self) -> Path:
        """The parameter file: ``parameter_file``, or the machine file's name with ``.var``."""
        return self.parameter_file or self.path.with_suffix(".var")

    @property
    def axis_names(self) -> tuple[str, ...]:
        """The axis letters, in file order."""
        return tuple(axis.name for axis in self.axes)

    def axis(self, name: str) -> AxisConfig:
        """The axis with this letter.

        Raises:
            KeyError: no such axis (the message lists the axes there are).
        """
        for axis in self.axes:
            if axis.name == name:
                return axis
        raise KeyError(f"no axis {name!r}; this machine has {', '.join(self.axis_names)}")

    @property
    def servo_period_s(self) -> float:
        """Servo period, seconds."""
        return self.servo_interval_dms * 1e-4

    @property
    def motion_period_s(self) -> float:
        """Seconds between motion-queue values: servo period times the scalar."""
        return self.servo_period_s * self.motion_scalar

    @property
    def is_simulated(self) -> bool:
        """True when every axis is an in-process simulated device."""
        return all(axis.is_simulated for axis in self.axes)


# --- loading ---------------------------------------------------------------------------------


UrlChecks = Mapping[str, Callable[[str], str | None]]
"""URL scheme (``sim``) -> why a URL of that scheme is wrong, or ``None``: the checks of
the links this host cannot read itself (:data:`usbmotion.sim.urls.URL_CHECKS`)."""


def builtin_machine_file() -> Path:
    """The built-in simulated 3-axis machine's file: part of the package
    (``usbmotion/data/machine.toml``, the same as ``examples/machine.toml``), never written."""
    return Path(str(resources.files("usbmotion") / "data" / "machine.toml"))


def load_config(path: str | Path, *, url_checks: UrlChecks | None = None) -> MachineConfig:
    """Read and validate a machine configuration file.

    Parameters:
        path: the file.
        url_checks: checks of the axes' URLs by scheme; a URL of a scheme with no check is
            only required to be a non-empty string (its port says more when opened).

    Raises:
        ConfigError: the file cannot be read, is not valid TOML, or holds an unknown key,
            a bad value or lacks a required one (the message names the file, the dotted
            key, the line and what is allowed).
    """
    file = Path(path)
    try:
        text = file.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as error:
        raise ConfigError(f"{file}: cannot read the machine configuration: {error}",
                          path=str(file)) from error
    return parse_config(text, path=file, url_checks=url_checks)


def parse_config(text: str, *, path: str | Path = "<string>",
                 url_checks: UrlChecks | None = None) -> MachineConfig:
    """Validate a machine configuration given as TOML text.

    Parameters:
        text: the TOML document.
        path: the file it came from, for messages and ``MachineConfig.path``.
        url_checks: as :func:`load_config`.

    Raises:
        ConfigError: as :func:`load_config`.
    """
    source = _Source(Path(path), text, url_checks=url_checks or {})
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as error:
        detail = str(error)
        match = re.search(r"at line (\d+), column (\d+)", detail)
        line = int(match.group(1)) if match else max(1, len(text.splitlines()))
        raise ConfigError(
            f"{source.path}:{line}: TOML syntax error: {detail}", path=str(source.path),
            line=line,
        ) from None
    return _machine(_Reader(source, data, ()))


# --- reading with messages that locate the problem -----------------------------------------


_REQUIRED: Any = object()
_HEADER = re.compile(r"^\s*\[\[?\s*([^\[\]]+?)\s*\]\]?\s*(#.*)?$")
_BARE_OR_QUOTED = r"""(?:[A-Za-z0-9_-]+|"[^"]*"|'[^']*')"""
_KEY_LINE = re.compile(rf"^\s*({_BARE_OR_QUOTED}(?:\s*\.\s*{_BARE_OR_QUOTED})*)\s*=")


def _key_path(dotted: str) -> tuple[str, ...]:
    return tuple(part.strip().strip("\"'") for part in dotted.split("."))


class _Source:
    """The text of a configuration file, for finding the line a key is written on."""

    def __init__(self, path: Path, text: str, *, url_checks: UrlChecks) -> None:
        self.path = path
        self.url_checks = url_checks
        self._entries: list[tuple[int, tuple[str, ...], bool]] = []
        table: tuple[str, ...] = ()
        for number, line in enumerate(text.splitlines(), start=1):
            header = _HEADER.match(line)
            if header is not None:
                table = _key_path(header.group(1))
                self._entries.append((number, table, True))
                continue
            key = _KEY_LINE.match(line)
            if key is not None:
                self._entries.append((number, table + _key_path(key.group(1)), False))

    def line_of(self, key: tuple[str, ...]) -> int | None:
        """The line that writes ``key``: the key itself, its table's header, or the inline
        table or dotted key that holds it; ``None`` when none can be found."""
        exact = [n for n, k, _ in self._entries if k == key]
        if exact:
            return exact[0]
        holders = [(len(k), n) for n, k, _ in self._entries if k == key[: len(k)] and k]
        if holders:
            return max(holders)[1]
        inside = [n for n, k, _ in self._entries if k[: len(key)] == key]
        return inside[0] if inside else None

    def fail(self, key: tuple[str, ...], problem: str) -> NoReturn:
        dotted = ".".join(key) if key else "(top level)"
        line = self.line_of(key) if key else None
        where = f"{self.path}:{line}" if line is not None else f"{self.path}"
        raise ConfigError(f"{where}: {dotted}: {problem}", path=str(self.path), key=dotted,
                          line=line)


def _show(value: object) -> str:
    return f"{value!r} ({type(value).__name__})" if not isinstance(value, str) else repr(value)


class _Reader:
    """One table of the file: typed getters that record which keys were read.

    ``names`` renames keys: the schema asks for ``counts_per_mm``, a rotary axis's file
    writes ``counts_per_degree`` (:data:`_ROTARY_NAMES`); messages name the file's key and
    say ``deg`` for ``mm``."""

    def __init__(self, source: _Source, data: Mapping[str, Any], prefix: tuple[str, ...],
                 names: Mapping[str, str] | None = None) -> None:
        self.source = source
        self.data = data
        self.prefix = prefix
        self.names: Mapping[str, str] = names or {}
        self._read: set[str] = set()
        self._known: tuple[str, ...] = ()

    def _file(self, name: str) -> str:
        return self.names.get(name, name)

    def say(self, text: str) -> str:
        """``text`` as this table's file says it (renamed keys, degrees for mm)."""
        if not self.names:
            return text
        for ours, theirs in self.names.items():
            text = re.sub(rf"\b{ours}\b", theirs, text)
        return re.sub(r"\bmm\b", "deg", text)

    def key(self, name: str) -> tuple[str, ...]:
        return (*self.prefix, self._file(name))

    def fail(self, name: str | None, problem: str) -> NoReturn:
        self.source.fail(self.key(name) if name is not None else self.prefix, self.say(problem))

    def has(self, name: str) -> bool:
        return self._file(name) in self.data

    def _get(self, name: str, default: Any, allowed: str) -> Any:
        name = self._file(name)
        self._read.add(name)
        if name in self.data:
            return self.data[name]
        if default is _REQUIRED:
            self.source.fail((*self.prefix, name),
                             self.say(f"missing required key {name!r}; allowed: {allowed}"))
        return default

    def number(self, name: str, *, default: Any = _REQUIRED, minimum: float | None = None,
               maximum: float | None = None, above: float | None = None, unit: str) -> float:
        """A float (an integer is accepted) within the given bounds."""
        bounds = []
        if above is not None:
            bounds.append(f"> {above:g}")
        if minimum is not None:
            bounds.append(f">= {minimum:g}")
        if maximum is not None:
            bounds.append(f"<= {maximum:g}")
        allowed = f"a number {' and '.join(bounds)} ({unit})" if bounds else f"a number ({unit})"
        value = self._get(name, default, allowed)
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            self.fail(name, f"{_show(value)} is not a number; allowed: {allowed}")
        number = float(value)
        out_of_range = (
            not math.isfinite(number)
            or (above is not None and number <= above)
            or (minimum is not None and number < minimum)
            or (maximum is not None and number > maximum)
        )
        if out_of_range:
            self.fail(name, f"{value!r} is out of range; allowed: {allowed}")
        return number

    def integer(self, name: str, *, default: Any = _REQUIRED, minimum: int, maximum: int,
                unit: str) -> int:
        """An integer within ``minimum..maximum``."""
        allowed = f"an integer {minimum}..{maximum} ({unit})"
        value = self._get(name, default, allowed)
        if isinstance(value, bool) or not isinstance(value, int):
            self.fail(name, f"{_show(value)} is not an integer; allowed: {allowed}")
        if not minimum <= value <= maximum:
            self.fail(name, f"{value!r} is out of range; allowed: {allowed}")
        return value

    def string(self, name: str, *, default: Any = _REQUIRED, allowed: str) -> Any:
        """A string (or ``default`` when absent)."""
        value = self._get(name, default, allowed)
        if value is not default and not isinstance(value, str):
            self.fail(name, f"{_show(value)} is not a string; allowed: {allowed}")
        return value

    def table(self, name: str, *, required: bool = False, allowed: str) -> _Reader | None:
        """A sub-table, or ``None`` when it is absent and optional."""
        value = self._get(name, _REQUIRED if required else None, allowed)
        if value is None:
            return None
        if not isinstance(value, dict):
            self.fail(name, f"{_show(value)} is not a table; allowed: {allowed}")
        return _Reader(self.source, value, self.key(name), self.names)

    def raw(self, name: str, *, default: Any = _REQUIRED, allowed: str) -> Any:
        """A value of any type, for the caller to check."""
        return self._get(name, default, allowed)

    def expect(self, known: tuple[str, ...]) -> None:
        """Reject, before any value is read, the first key (in file order) not in ``known``.

        So a misspelt required key is named as unknown, with the closest known key, rather
        than reported as the correct key missing.
        """
        known = tuple(self._file(name) for name in known)
        self._known = known
        for name in self.data:
            if name not in known:
                self.source.fail((*self.prefix, name), _unknown_key(name, known))

    def finish(self) -> None:
        """Reject every key that was not read: a key :meth:`expect` let through that the
        schema then never read is a fault of this module, never silently ignored."""
        for name in self.data:
            if name not in self._read:
                where = (*self.prefix, name)
                if name in self._known:
                    self.source.fail(where, f"key {name!r} is allowed here but was not read"
                                     " (a fault of usbmotion's configuration reader; please"
                                     " report it)")
                self.source.fail(where, _unknown_key(name, self._known or tuple(self._read)))


def _unknown_key(name: str, known: tuple[str, ...]) -> str:
    """``unknown key 'max_acel_mm_s2'; did you mean 'max_accel_mm_s2'? allowed keys here: ...``"""
    by_folded = {key.lower(): key for key in known}
    close = difflib.get_close_matches(name.lower(), list(by_folded), n=1)
    hint = f"; did you mean {by_folded[close[0]]!r}?" if close else ";"
    return f"unknown key {name!r}{hint} allowed keys here: {', '.join(sorted(known))}"


# --- the schema ------------------------------------------------------------------------------


_MACHINE_KEYS = (
    "name", "servo_interval_dms", "motion_scalar", "junction_deviation_mm", "arc_tolerance_mm",
    "watchdog_ms", "reply_timeout_s", "ports", "homing_order", "axes", "dialect",
    "tool_table", "parameter_file", "joints", "spindle", "outputs", "tool_setter",
)
_SPINDLE_KEYS = ("device", "url", "counts_per_revolution", "max_rpm", "accel_rpm_s",
                 "at_speed_tolerance", "stall_tolerance", "spin_up_timeout_s", "velocity_gains",
                 "sim")
_SPINDLE_SIM_KEYS = ("update_interval_dms", "source_voltage_v", "torque_constant_mnm_per_a",
                     "winding_resistance_ohm", "inertia_kg_m2",
                     "viscous_friction_unm_per_rad_s", "load_torque_mnm")
_JOINT_KEYS = ("axis", "unit", "counts_per_unit", "max_velocity", "max_accel", "max_jerk")
_AXIS_KEYS = (
    "device", "url", "counts_per_mm", "max_velocity_mm_s", "max_accel_mm_s2", "max_jerk_mm_s3",
    "travel_mm", "gains", "velocity_gains", "following_error_limit_mm", "homing", "sim", "reach",
    "model", "kind", "encoder", "encoder_counts_per_rev",
)
_STEPPER_ONLY_KEYS = ("steps_per_mm", "microsteps", "full_steps_per_rev", "loop",
                      "step_pulse_ns", "dir_setup_ns")
_STEPPER_AXIS_KEYS = (
    "device", "url", "kind", "max_velocity_mm_s", "max_accel_mm_s2", "max_jerk_mm_s3",
    "travel_mm", "gains", "following_error_limit_mm", "homing", "sim", "encoder",
    "encoder_counts_per_rev", *_STEPPER_ONLY_KEYS,
)
_SERVO_ONLY_KEYS = ("counts_per_mm", "velocity_gains", "reach", "model")
_SIM_STEPPER_KEYS = (
    "update_interval_dms", "holding_torque_mnm", "detent_torque_mnm", "corner_rpm",
    "inertia_kg_m2", "viscous_friction_unm_per_rad_s", "load_torque_mnm", "start_mm",
    "probe_below_mm", "probe_above_mm", "magnet_angle_deg",
)
_GAINS_KEYS = ("kp", "ki", "kd")
_HOMING_KEYS = ("direction", "speed_mm_s", "slow_speed_mm_s", "backoff_mm", "position_mm",
                "pull_off_mm", "search_mm")
_SIM_KEYS = (
    "update_interval_dms", "source_voltage_v", "torque_constant_mnm_per_a",
    "winding_resistance_ohm", "counts_per_revolution", "inertia_kg_m2",
    "viscous_friction_unm_per_rad_s", "load_torque_mnm", "start_mm", "probe_below_mm",
    "probe_above_mm", "magnet_angle_deg",
)
_REACH_KEYS = ("velocity_mm_s", "accel_mm_s2")
_MODEL_KEYS = ("time_constant_s", "speed_per_volt_counts_s", "coulomb_v", "supply_v")
ROTARY_LETTERS = "ABC"
"""The rotary axes: their file's keys are in degrees."""
_ROTARY_NAMES = {
    "counts_per_mm": "counts_per_degree", "max_velocity_mm_s": "max_velocity_deg_s",
    "max_accel_mm_s2": "max_accel_deg_s2", "max_jerk_mm_s3": "max_jerk_deg_s3",
    "steps_per_mm": "steps_per_degree",
    "travel_mm": "travel_deg", "following_error_limit_mm": "following_error_limit_deg",
    "speed_mm_s": "speed_deg_s", "slow_speed_mm_s": "slow_speed_deg_s",
    "backoff_mm": "backoff_deg", "position_mm": "position_deg", "pull_off_mm": "pull_off_deg",
    "search_mm": "search_deg", "start_mm": "start_deg", "velocity_mm_s": "velocity_deg_s",
    "accel_mm_s2": "accel_deg_s2",
}
"""A rotary axis's keys in its file, by the schema's (linear) names."""


def _machine(top: _Reader) -> MachineConfig:
    path = top.source.path
    top.expect(_MACHINE_KEYS)
    name = top.string("name", default=path.stem, allowed="a string, a label for the machine")
    servo_interval_dms = top.integer(
        "servo_interval_dms", default=10, minimum=1, maximum=10000,
        unit="servo period in tenths of a millisecond; 10 = 1 ms",
    )
    motion_scalar = top.integer(
        "motion_scalar", default=1, minimum=1, maximum=65535,
        unit="servo ticks per motion-queue value",
    )
    junction_deviation_mm = top.number(
        "junction_deviation_mm", default=0.01, above=0, maximum=10, unit="mm"
    )
    arc_tolerance_mm = top.number("arc_tolerance_mm", default=0.002, above=0, maximum=1,
                                  unit="mm")
    queue_ms = QUEUE_CAPACITY * servo_interval_dms * motion_scalar / 10
    watchdog_ms = top.integer(
        "watchdog_ms", default=max(2000, math.ceil(queue_ms) + _WATCHDOG_SLACK_MS), minimum=0,
        maximum=600_000, unit="milliseconds; 0 turns the watchdog off",
    )
    if 0 < watchdog_ms < queue_ms + _WATCHDOG_SLACK_MS:
        top.fail(
            "watchdog_ms",
            f"{watchdog_ms!r} ms is shorter than a full motion queue lasts"
            f" ({QUEUE_CAPACITY} values x {queue_ms / QUEUE_CAPACITY:g} ms = {queue_ms:g} ms)"
            f" plus {_WATCHDOG_SLACK_MS} ms, so a host waiting on a full queue would trip it;"
            f" allowed: 0 (off) or >= {math.ceil(queue_ms) + _WATCHDOG_SLACK_MS}",
        )
    reply_timeout_s = top.number("reply_timeout_s", default=1.0, above=0, maximum=60,
                                 unit="seconds")
    ports = _string_list(top, "ports", "a list of port paths or URLs to search for devices")
    dialects = ", ".join(repr(name) for name in DIALECTS)
    dialect = top.string("dialect", default="linuxcnc",
                         allowed=f"the G-code dialect of the machine's programs: {dialects}")
    if dialect not in DIALECTS:
        top.fail("dialect", f"{dialect!r} is not a G-code dialect; allowed: {dialects}")
    tool_table = _file(top, "tool_table", "a LinuxCNC tool.tbl file (T1 P1 Z12.5 D6 lines,"
                       " mm), relative to the machine file")
    parameter_file = _file(top, "parameter_file", "a LinuxCNC .var parameter file for the work"
                           " offsets, relative to the machine file")
    axes_table = top.table(
        "axes", required=True,
        allowed=f"a table of axes, [axes.X], [axes.Y], ... (letters {', '.join(AXIS_LETTERS)})",
    )
    assert axes_table is not None
    axes = _axes(axes_table, servo_interval_dms, motion_scalar)
    order = _homing_order(top, axes)
    joints_table = top.table("joints", allowed="a table of robot joints, [joints.<name>]")
    joints = () if joints_table is None else _joints(joints_table, axes)
    spindle_table = top.table("spindle", allowed="a table: the spindle's device in velocity"
                              " mode (device or url, counts_per_revolution, max_rpm, ...)")
    spindle = None if spindle_table is None else _spindle(spindle_table, servo_interval_dms)
    outputs_table = top.table("outputs", allowed="a table: flood, mist, laser (each { axis,"
                              " output }), laser_max_s")
    outputs = None if outputs_table is None else _outputs(outputs_table, axes)
    setter_table = top.table("tool_setter", allowed="a table: position_mm, start_z_mm,"
                             " lowest_z_mm, feed_mm_min, reference_z_mm")
    tool_setter = None if setter_table is None else _tool_setter(setter_table, axes)
    if outputs_table is not None and spindle is not None and "laser" in outputs_table.data:
        outputs_table.fail("laser", "M3, M4, M5 and S drive the spindle of [spindle] or the"
                           " laser, not both; allowed: a laser output or a [spindle]")
    top.finish()
    return MachineConfig(
        path=path, name=name, axes=axes, servo_interval_dms=servo_interval_dms,
        motion_scalar=motion_scalar, junction_deviation_mm=junction_deviation_mm,
        arc_tolerance_mm=arc_tolerance_mm, homing_order=order, watchdog_ms=watchdog_ms,
        reply_timeout_s=reply_timeout_s, ports=ports, dialect=dialect, tool_table=tool_table,
        parameter_file=parameter_file, joints=joints, spindle=spindle, outputs=outputs,
        tool_setter=tool_setter,
    )


def _joints(table: _Reader, axes: tuple[AxisConfig, ...]) -> tuple[JointConfig, ...]:
    by_name = {axis.name: axis for axis in axes}
    letters = ", ".join(by_name)
    joints: list[JointConfig] = []
    used: dict[str, str] = {}
    for name in table.data:
        if not (isinstance(name, str) and name.isidentifier() and len(name) <= 32):
            table.fail(name, f"{name!r} is not a joint name; allowed: a name of letters,"
                       " digits and _ (up to 32), not starting with a digit: shoulder, pan")
        reader = table.table(name, required=True, allowed="a table of joint settings")
        assert reader is not None
        reader.expect(_JOINT_KEYS)
        axis_name = reader.string("axis", allowed=f"the axis that drives it: {letters}")
        if axis_name not in by_name:
            reader.fail("axis", f"{axis_name!r} is not an axis of this machine; allowed:"
                        f" {letters}")
        if axis_name in used:
            reader.fail("axis", f"axis {axis_name} already drives joint {used[axis_name]};"
                        " allowed: one joint an axis")
        used[axis_name] = name
        axis = by_name[axis_name]
        units = ", ".join(repr(u) for u in JOINT_UNITS)
        unit = reader.string("unit", default="deg", allowed=f"{units}")
        if unit not in JOINT_UNITS:
            reader.fail("unit", f"{unit!r} is not a joint unit; allowed: {units}")
        per_unit = reader.number("counts_per_unit", above=0, maximum=1e7,
                                 unit=f"encoder counts per {unit}")
        to_joint = axis.counts_per_mm / per_unit  # joint units per axis mm
        velocity = reader.number("max_velocity", default=axis.max_velocity_mm_s * to_joint,
                                 above=0, maximum=axis.max_velocity_mm_s * to_joint * (1 + 1e-9),
                                 unit=f"{unit}/s, at most the axis's")
        accel = reader.number("max_accel", default=axis.max_accel_mm_s2 * to_joint, above=0,
                              maximum=axis.max_accel_mm_s2 * to_joint * (1 + 1e-9),
                              unit=f"{unit}/s^2, at most the axis's")
        jerk = reader.number("max_jerk", default=20 * accel, above=0, maximum=1e12,
                             unit=f"{unit}/s^3; default 20 x max_accel")
        reader.finish()
        low, high = axis.travel_mm
        joints.append(JointConfig(name, axis_name, unit, per_unit, velocity, accel, jerk,
                                  (low * to_joint, high * to_joint)))
    return tuple(joints)


def _file(reader: _Reader, name: str, allowed: str) -> Path | None:
    """A file named relative to the machine file's folder, or ``None`` when absent."""
    value = reader.raw(name, default=None, allowed=allowed)
    if value is None:
        return None
    if not isinstance(value, str) or not value.strip():
        reader.fail(name, f"{_show(value)} is not a file name; allowed: {allowed}")
    file = Path(value).expanduser()
    if file.is_absolute():
        return file
    return reader.source.path.parent / file


def _string_list(reader: _Reader, name: str, allowed: str) -> tuple[str, ...]:
    value = reader.raw(name, default=[], allowed=allowed)
    if not isinstance(value, list) or not all(isinstance(v, str) and v for v in value):
        reader.fail(name, f"{_show(value)} is not a list of non-empty strings; allowed: {allowed}")
    return tuple(value)


def _axes(table: _Reader, servo_interval_dms: int,
          motion_scalar: int) -> tuple[AxisConfig, ...]:
    letters = ", ".join(AXIS_LETTERS)
    if not table.data:
        table.fail(None, f"no axes; add at least one [axes.<LETTER>] table ({letters})")
    for name in table.data:
        if name not in AXIS_LETTERS:
            hint = f" (did you mean {name.upper()!r}?)" if name.upper() in AXIS_LETTERS else ""
            table.fail(name, f"{name!r} is not an axis name{hint}; allowed: {letters}")
    axes: list[AxisConfig] = []
    for name in table.data:
        reader = table.table(name, required=True, allowed="a table of axis settings")
        assert reader is not None
        axes.append(_axis(name, reader, servo_interval_dms, motion_scalar))
    for key in ("device", "url"):
        seen: dict[str, str] = {}
        for axis in axes:
            value = getattr(axis, key)
            if value is None:
                continue
            if value in seen:
                table.fail(
                    f"{axis.name}", f"{key} {value!r} is also axis {seen[value]}'s;"
                    f" allowed: a {key} used by one axis only",
                )
            seen[value] = axis.name
    return tuple(axes)


def _device_name(reader: _Reader) -> str | None:
    allowed = f"1..{DEVICE_NAME_MAX} printable ASCII characters, the name in the device's flash"
    name = reader.string("device", default=None, allowed=allowed)
    if name is None:
        return None
    assert isinstance(name, str)
    if device_name_problem(name, allow_empty=False) is not None:
        reader.fail("device", f"{name!r} is not a device name; allowed: {allowed}")
    return name


def _url(reader: _Reader) -> str | None:
    allowed = "a port or URL: sim://NAME[?latency_us=N], /dev/ttyACM0, COM3, socket://host:port"
    url = reader.string("url", default=None, allowed=allowed)
    if url is None:
        return None
    assert isinstance(url, str)
    if not url.strip():
        reader.fail("url", f"{url!r} is empty; allowed: {allowed}")
    check = reader.source.url_checks.get(url.split("://", 1)[0].lower()) if "://" in url else None
    problem = check(url) if check is not None else None
    if problem is not None:
        reader.fail("url", f"{problem}; allowed: {allowed}")
    return url


def _one_of(reader: _Reader, key: str, choices: tuple[str, ...], *, default: str,
            what: str, meaning: str) -> str:
    """A key that names one of ``choices`` (``what`` they are, ``meaning`` what each means,
    for the error)."""
    allowed = ", ".join(repr(choice) for choice in choices) + f": {meaning}"
    value = reader.string(key, default=default, allowed=allowed)
    if value not in choices:
        reader.fail(key, f"{value!r} is not {what}; allowed: {allowed}")
    return str(value)


def _kind(reader: _Reader) -> str:
    """The axis's ``kind``, and no key of the other kind in its table."""
    kind = _one_of(reader, "kind", AXIS_KINDS, default="servo", what="a kind of axis",
                   meaning="a DC motor with an encoder and the device's PID, or a stepper on"
                   " a step/direction driver")
    if kind == "stepper":
        for key in _SERVO_ONLY_KEYS:
            if reader.has(key):
                hint = {
                    "counts_per_mm": "a stepper counts microsteps: give steps_per_mm"
                                     " (microsteps per mm, grbl's $100)",
                    "velocity_gains": "a stepper's velocity mode (homing) runs its position"
                                      " loop: it takes gains, none of its own",
                    "reach": "usbmotion tune --reach measures a servo's motor; a stepper's"
                             " limits are checked against its step rate (and its simulated"
                             " torque)",
                    "model": "usbmotion tune --auto identifies a DC motor",
                }[key]
                reader.fail(key, f"{key!r} is a servo axis's key, and this axis is kind ="
                            f" 'stepper': {hint}")
    else:
        for key in _STEPPER_ONLY_KEYS:
            if reader.has(key):
                reader.fail(key, f"{key!r} is a stepper axis's key; allowed: kind ="
                            " 'stepper' with it, or this servo axis without it")
    return str(kind)


def _call_integer(reader: _Reader, key: str, call: CallNumber, index: int, *, default: int,
                  unit: str) -> int:
    """A key that a call's parameter ``index`` carries as it is: the call's range."""
    param = BY_NUMBER[call].params[index]
    return reader.integer(key, default=default, minimum=param.minimum, maximum=param.maximum,
                          unit=unit)


def _stepper(reader: _Reader, tick_us: int, motion_ticks: int, max_velocity: float,
             steps_per_mm: float) -> StepperConfig:
    """A stepper axis's motor and driver, and its step rate checked against the driver's
    timing."""
    loop = _one_of(reader, "loop", STEPPER_LOOPS, default="open", what="a stepper loop",
                   meaning="the position is the steps issued (open), or an encoder's on the"
                   " shaft (closed)")
    full = _call_integer(reader, "full_steps_per_rev", CallNumber.SET_STEPPER, 0, default=200,
                         unit="the motor's full steps per revolution; 200 = 1.8 degrees")
    microsteps = _call_integer(reader, "microsteps", CallNumber.SET_STEPPER, 1, default=16,
                               unit="microsteps per full step, as set on the driver")
    encoder: int | None = None
    if loop == "closed":
        encoder = reader.integer(
            "encoder_counts_per_rev", minimum=1,
            maximum=BY_NUMBER[CallNumber.SET_SIM_COUNTS_PER_REVOLUTION].params[0].maximum,
            unit="the shaft encoder's counts per revolution (quadrature x4)")
    elif reader.has("encoder_counts_per_rev"):
        reader.fail("encoder_counts_per_rev", "an open-loop stepper reads no encoder (its"
                    " position is the steps issued); allowed: loop = 'closed' with it, or no"
                    " encoder_counts_per_rev")
    pulse = _call_integer(reader, "step_pulse_ns", CallNumber.SET_STEP_TIMING, 0, default=2000,
                          unit="ns the step pulse is high (and at least as long low)")
    setup = _call_integer(reader, "dir_setup_ns", CallNumber.SET_STEP_TIMING, 1, default=1000,
                          unit="ns from a direction change to the next step edge")
    stepper = StepperConfig(loop, full, microsteps, encoder, pulse, setup)
    per_tick = stepper.steps_per_tick(tick_us)
    if per_tick < 1:
        reader.fail("step_pulse_ns", f"{pulse!r} ns high and low after a {setup} ns set-up"
                    f" fits no step in a {tick_us} us servo tick; allowed: a shorter"
                    " step_pulse_ns or dir_setup_ns, or a longer servo_interval_dms")
    per_value = per_tick * motion_ticks
    share = 1.0 - REACH_MARGIN if stepper.closed else 1.0
    fastest = share * per_value / (motion_ticks * tick_us * 1e-6) / steps_per_mm
    if max_velocity > fastest:
        why = (f", less {REACH_MARGIN:.0%} left to the closed loop to catch up"
               if stepper.closed else "")
        reader.fail("max_velocity_mm_s", (
            f"{max_velocity!r} mm/s is {max_velocity * steps_per_mm:.0f} microsteps/s, more"
            f" than the driver's timing lets the device issue: {per_tick} steps a"
            f" {tick_us} us servo tick (a {pulse} ns pulse high and low after a {setup} ns"
            f" set-up, in 8 ns periods) is {per_tick / (tick_us * 1e-6):.0f} steps/s"
            f"{why}; allowed: <= {_down(fastest)} mm/s at steps_per_mm {steps_per_mm:g},"
            " or a shorter step_pulse_ns"))
    return stepper


def _axis(name: str, reader: _Reader, servo_interval_dms: int,
          motion_scalar: int) -> AxisConfig:
    rotary = name in ROTARY_LETTERS
    if rotary:
        reader = _Reader(reader.source, reader.data, reader.prefix, _ROTARY_NAMES)
    kind = _kind(reader)
    is_stepper = kind == "stepper"
    keys = _STEPPER_AXIS_KEYS if is_stepper else _AXIS_KEYS
    reader.expect((*keys, "wrapped") if rotary else keys)
    device = _device_name(reader)
    url = _url(reader)
    if device is None and url is None:
        reader.fail(
            "device", "missing required key 'device' or 'url'; allowed: give the device name"
            " written in its flash (found by discovery) or its port/URL (sim://X, /dev/ttyACM0,"
            " socket://host:port)",
        )
    if is_stepper:
        counts_per_mm = reader.number("steps_per_mm", above=0, maximum=1e7,
                                      unit="microsteps per mm (grbl's $100)")
    else:
        counts_per_mm = reader.number("counts_per_mm", above=0, maximum=1e7,
                                      unit="encoder counts per mm")
    max_velocity = reader.number("max_velocity_mm_s", above=0, maximum=1e5, unit="mm/s")
    max_accel = reader.number("max_accel_mm_s2", above=0, maximum=1e7, unit="mm/s^2")
    max_jerk = reader.number("max_jerk_mm_s3", default=20 * max_accel, above=0, maximum=1e10,
                             unit="mm/s^3; default 20 x max_accel_mm_s2")
    wrapped = False
    if rotary:
        flag = reader.raw("wrapped", default=False, allowed="true or false")
        if not isinstance(flag, bool):
            reader.fail("wrapped", f"{_show(flag)} is not true or false; allowed: true (the"
                        " axis turns on without end, LinuxCNC's WRAPPED_ROTARY) or false")
        wrapped = flag
    if wrapped:
        if reader.has("travel_mm"):
            reader.fail("travel_mm", "a wrapped axis turns on without end: it has no travel"
                        " (and no soft limits); allowed: no travel_mm with wrapped = true")
        turns = INT32_MAX // 4 / counts_per_mm
        travel = (-turns, turns)
    else:
        travel = _travel(reader, counts_per_mm)
    stepper: StepperConfig | None = None
    if is_stepper:
        stepper = _stepper(reader, servo_interval_dms * 100, motion_scalar, max_velocity,
                           counts_per_mm)
        if stepper.closed:
            gains = _gains(reader, "gains", defaults=STEPPER_GAINS_DEFAULT,
                           mode="the closed loop", stepper=True)
        elif reader.has("gains"):
            reader.fail("gains", "an open-loop stepper runs no PID (its position is the"
                        " steps issued); allowed: loop = 'closed' with gains, or no gains")
        else:
            gains = OPEN_LOOP_GAINS
        velocity_gains = gains
    else:
        gains = _gains(reader, "gains", defaults=None, mode="position and curve modes")
        velocity_gains = _gains(reader, "velocity_gains", defaults=VELOCITY_GAINS_DEFAULT,
                                mode="velocity mode")
    fe_limit = reader.number(
        "following_error_limit_mm", default=2.0, minimum=0,
        maximum=min(travel[1] - travel[0], INT32_MAX / counts_per_mm),
        unit="mm; 0 turns the limit off",
    )
    homing = _homing(reader, travel, max_velocity, wrapped=wrapped)
    simulated = url is not None and url.lower().startswith(SIM_SCHEME)
    if stepper is not None:
        stepper_sim = _sim_stepper(reader, travel, counts_per_mm, servo_interval_dms,
                                   simulated=simulated)
        if stepper_sim is not None:
            _check_stepper_torque(reader, stepper_reach(stepper_sim, stepper, counts_per_mm),
                                  max_velocity, max_accel, closed=stepper.closed)
        absolute = _encoder(reader, stepper_sim, stepper=stepper)
        reader.finish()
        return AxisConfig(
            name=name, device=device, url=url, counts_per_mm=counts_per_mm,
            max_velocity_mm_s=max_velocity, max_accel_mm_s2=max_accel,
            max_jerk_mm_s3=max_jerk, travel_mm=travel, gains=gains,
            velocity_gains=velocity_gains, following_error_limit_mm=fe_limit, homing=homing,
            reach=None, sim=stepper_sim, wrapped=wrapped, stepper=stepper,
            absolute_encoder=absolute,
        )
    sim = _sim(reader, travel, counts_per_mm, servo_interval_dms, simulated=simulated)
    reach = _reach(reader)
    model = _model(reader)
    if sim is not None:
        volts = f"{sim.source_voltage_v:g} V"
        table = ".".join(reader.key("sim"))
        motor = table if reader.has("sim") else f"the simulated motor ({table}'s defaults)"
        _check_reach(
            reader, simulated_reach(sim, counts_per_mm), max_velocity, max_accel,
            speed=f"its no-load speed at the full {volts} of {motor}",
            speed_how="(Kt V/R - T_load) / (Kt^2/R + b)",
            accel=f"at the full {volts} of {motor}",
            accel_how="(Kt (V - Kt w)/R - b w - T_load) / J at w = max_velocity_mm_s",
        )
    if reach is not None:
        table = ".".join(reader.key("reach"))
        _check_reach(
            reader, reach, max_velocity, max_accel,
            speed="its top speed measured by usbmotion tune --reach",
            speed_how=f"{table}.velocity_mm_s",
            accel="by the reach that usbmotion tune --reach measured",
            accel_how=f"{table}, on a DC motor's straight torque-speed line",
        )
    absolute = _encoder(reader, sim, stepper=None)
    reader.finish()
    return AxisConfig(
        name=name, device=device, url=url, counts_per_mm=counts_per_mm,
        max_velocity_mm_s=max_velocity, max_accel_mm_s2=max_accel, max_jerk_mm_s3=max_jerk,
        travel_mm=travel, gains=gains, velocity_gains=velocity_gains,
        following_error_limit_mm=fe_limit, homing=homing, reach=reach, sim=sim,
        wrapped=wrapped, model=model, absolute_encoder=absolute,
    )


def _encoder(reader: _Reader, sim: SimMotorConfig | SimStepperConfig | None, *,
             stepper: StepperConfig | None) -> AbsoluteEncoder | None:
    """The axis's ``encoder``: ``None`` for an incremental one, else its turn (a servo's
    ``encoder_counts_per_rev``, or its simulated motor's ``counts_per_revolution``; a
    closed-loop stepper's microsteps per revolution) and the simulated magnet's angle."""
    kind = _one_of(reader, "encoder", ENCODER_KINDS, default="incremental",
                   what="a kind of encoder", meaning="counting from power-up (homing finds"
                   " where the axis is), or the shaft's angle within a turn from power-up"
                   " (homing names the turn)")
    magnet_deg = 0.0 if sim is None else sim.magnet_angle_deg
    if kind == "incremental":
        if magnet_deg != 0.0:
            reader.fail("sim", "magnet_angle_deg is an absolute encoder's; allowed: encoder ="
                        " 'absolute' with it, or no magnet_angle_deg")
        if stepper is None and reader.has("encoder_counts_per_rev"):
            reader.fail("encoder_counts_per_rev", "a servo's incremental encoder is scaled by"
                        " counts_per_mm alone; allowed: encoder = 'absolute' with it (its"
                        " turn), or no encoder_counts_per_rev")
        return None
    if stepper is not None:
        if not stepper.closed:
            reader.fail("encoder", "an open-loop stepper reads no encoder (its position is the"
                        " steps issued); allowed: loop = 'closed' with an absolute encoder,"
                        " or encoder = 'incremental'")
        turn = stepper.microsteps_per_rev
    else:
        simulated_turn = sim.counts_per_revolution if isinstance(sim, SimMotorConfig) else None
        maximum = BY_NUMBER[CallNumber.SET_SIM_COUNTS_PER_REVOLUTION].params[0].maximum
        turn = reader.integer(
            "encoder_counts_per_rev",
            default=_REQUIRED if simulated_turn is None else simulated_turn, minimum=2,
            maximum=maximum, unit="counts of the counter per turn of the absolute encoder;"
            " default the simulated motor's counts_per_revolution")
        if simulated_turn is not None and turn != simulated_turn:
            reader.fail("encoder_counts_per_rev", f"{turn!r} counts a turn, and the simulated"
                        f" motor counts {simulated_turn} (its counts_per_revolution); allowed:"
                        " the same number, or no encoder_counts_per_rev")
    magnet = round(magnet_deg / 360.0 * turn) % turn
    return AbsoluteEncoder(turn_counts=turn, magnet_counts=magnet)


def _reach(reader: _Reader) -> AxisReach | None:
    table = reader.table(
        "reach", allowed="a table: velocity_mm_s, accel_mm_s2 (as usbmotion tune --reach prints)"
    )
    if table is None:
        return None
    table.expect(_REACH_KEYS)
    velocity = table.number("velocity_mm_s", above=0, maximum=1e5,
                            unit="mm/s, the top speed usbmotion tune --reach measured")
    accel = table.number("accel_mm_s2", above=0, maximum=1e8,
                         unit="mm/s^2, the acceleration from standstill it measured")
    table.finish()
    return AxisReach(velocity, accel)


def _model(reader: _Reader) -> MotorModelConfig | None:
    table = reader.table(
        "model", allowed="a table: time_constant_s, speed_per_volt_counts_s, coulomb_v,"
        " supply_v (as usbmotion tune --auto --write writes it)")
    if table is None:
        return None
    table.expect(_MODEL_KEYS)
    tau = table.number("time_constant_s", above=0, maximum=100.0,
                       unit="s, the mechanical time constant")
    speed = table.number("speed_per_volt_counts_s", above=0, maximum=1e9,
                         unit="counts/s per V, the steady speed one volt holds")
    supply = table.number("supply_v", above=0, maximum=1000.0, unit="V, the drive's ceiling")
    coulomb = table.number("coulomb_v", minimum=0, unit="V, the voltage the Coulomb torque"
                           " takes, below supply_v")
    if coulomb >= supply:
        table.fail("coulomb_v", f"{coulomb!r} V is not below supply_v ({supply!r} V): the"
                   " motor could not move; allowed: 0 <= coulomb_v < supply_v")
    table.finish()
    return MotorModelConfig(tau, speed, coulomb, supply)


def round_down(value: float, *, digits: int = 4) -> float:
    """``value`` rounded down to ``digits`` significant digits (0 for 0, negatives, NaN):
    a bound to copy into a machine file that stays within what it bounds."""
    if not (math.isfinite(value) and value > 0):
        return 0.0
    quantum = 10.0 ** (math.floor(math.log10(value)) - digits + 1)
    return float(f"{math.floor(value / quantum) * quantum:.{digits}g}")


def _down(value: float) -> str:
    return f"{round_down(value):g}"


def _check_reach(reader: _Reader, reach: AxisReach, max_velocity: float, max_accel: float, *,
                 speed: str, speed_how: str, accel: str, accel_how: str) -> None:
    """Refuse a ``max_velocity_mm_s`` or ``max_accel_mm_s2`` beyond ``reach`` less the margin.

    ``speed`` and ``accel`` say where each figure comes from, ``speed_how`` and ``accel_how``
    how it was found.
    """
    kept = f"{REACH_MARGIN:.0%} of the supply"
    top = reach.velocity_mm_s
    if top <= 0:
        reader.fail("max_velocity_mm_s", f"{max_velocity!r} mm/s cannot be reached: {speed}"
                    f" is 0 ({speed_how}: the load torque is at least the stall torque"
                    " Kt V/R); allowed: a motor that turns (a smaller load_torque_mnm or a"
                    " larger source_voltage_v)")
    usable = reach.usable_velocity_mm_s
    if max_velocity > usable:
        problem = ("is faster than the motor can go" if max_velocity > top
                   else f"leaves the PID less than {kept} to correct errors")
        reader.fail(
            "max_velocity_mm_s",
            f"{max_velocity!r} mm/s {problem}: {speed} is {top:.4g} mm/s ({speed_how});"
            f" allowed: <= {_down(usable)} mm/s ({1 - REACH_MARGIN:.0%} of it, so the PID"
            f" keeps {kept} to correct errors)",
        )
    available = reach.accel_at_mm_s2(max_velocity)
    usable = reach.usable_accel_mm_s2(max_velocity)
    if max_accel > usable:
        problem = ("is more than the motor can give" if max_accel > available
                   else f"leaves the PID less than {kept} to correct errors")
        reader.fail(
            "max_accel_mm_s2",
            f"{max_accel!r} mm/s^2 {problem} at max_velocity_mm_s {max_velocity:g} mm/s:"
            f" the motor gives {available:.4g} mm/s^2 {accel} ({accel_how}; {reach.accel_mm_s2:.4g}"
            f" mm/s^2 from standstill, 0 at the top speed {top:.4g} mm/s);"
            f" allowed: <= {_down(usable)} mm/s^2 (keeping {kept} for the"
            f" PID: {reach.accel_mm_s2:.4g} x ({1 - REACH_MARGIN:g} - {max_velocity:g}"
            f" / {top:.4g})), or a lower max_velocity_mm_s",
        )


def _travel(reader: _Reader, counts_per_mm: float) -> tuple[float, float]:
    allowed = "[lowest, highest] machine position in mm, lowest < highest, within int32 counts"
    value = reader.raw("travel_mm", allowed=allowed)
    if (
        not isinstance(value, list) or len(value) != 2
        or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value)
    ):
        reader.fail("travel_mm", f"{_show(value)} is not a pair of numbers; allowed: {allowed}")
    low, high = float(value[0]), float(value[1])
    reach = max(abs(low), abs(high), high - low) * counts_per_mm
    if not (math.isfinite(low) and math.isfinite(high) and low < high) or reach > INT32_MAX // 2:
        reader.fail("travel_mm", f"{value!r} is out of range; allowed: {allowed}")
    return (low, high)


def _sci(reader: _Reader, name: str, value: float, *, call: CallNumber, digits: int) -> None:
    """Check that ``value`` can be sent to the device as call ``call``'s ``C E`` pair."""
    coefficient, exponent = to_sci(value, digits=digits, parameter=name)
    if coefficient == 0:
        exponent = 0
    problem = BY_NUMBER[call].problem((coefficient, exponent))
    if problem is not None:
        spec = BY_NUMBER[call]
        low = max(1, spec.params[0].minimum) * 10.0 ** spec.params[1].minimum
        high = spec.params[0].maximum * 10.0 ** spec.params[1].maximum
        reader.fail(
            name, f"{value!r} cannot be sent to the device (call {call}: {problem[1]});"
            f" allowed: {'0 or ' if spec.params[0].minimum <= 0 else ''}{low:g}..{high:g}",
        )


def _gains(reader: _Reader, name: str, *, defaults: PidGains | None, mode: str,
           stepper: bool = False) -> PidGains:
    table = reader.table(name, required=defaults is None,
                         allowed=f"a table with kp, ki, kd (PID gains of {mode}, numbers >= 0)")
    table = table if table is not None else _Reader(reader.source, {}, reader.key(name))
    table.expect(_GAINS_KEYS)
    values: dict[str, float] = {}
    velocity = defaults is not None and not stepper
    if stepper:
        units = ("microsteps of lead per microstep of error",
                 "microsteps of lead per microstep-second", "microstep-seconds per microstep")
    elif velocity:
        units = ("V per count/s", "V per count", "V-seconds per count/s")
    else:
        units = ("V per count", "V per count-second", "V-seconds per count")
    for key, call, unit in (
        ("kp", CallNumber.SET_PROPORTIONAL_GAIN, units[0]),
        ("ki", CallNumber.SET_INTEGRAL_GAIN, units[1]),
        ("kd", CallNumber.SET_DERIVATIVE_GAIN, units[2]),
    ):
        default = _REQUIRED if defaults is None else getattr(defaults, key)
        values[key] = table.number(key, default=default, minimum=0, unit=unit)
        _sci(table, key, values[key], call=call, digits=3)
    table.finish()
    return PidGains(**values)


def _homing(reader: _Reader, travel: tuple[float, float], max_velocity: float, *,
            wrapped: bool = False) -> HomingConfig:
    table = reader.table("homing", allowed="a table: direction, speed_mm_s, slow_speed_mm_s,"
                         " backoff_mm, position_mm, pull_off_mm, search_mm, declare")
    table = table if table is not None else _Reader(reader.source, {}, reader.key("homing"),
                                                    reader.names)
    table.expect((*_HOMING_KEYS, "declare"))
    declare = table.raw("declare", default=wrapped, allowed="true or false")
    if not isinstance(declare, bool):
        table.fail("declare", f"{_show(declare)} is not true or false; allowed: true (homing"
                   " declares where the axis stands to be position_mm, with no switch) or"
                   " false (homing seeks the limit switch)")
    if wrapped and not declare:
        table.fail("declare", "a wrapped axis has no end switches to home on; allowed: true")
    if declare:
        position = table.number("position_mm", default=0.0, minimum=travel[0],
                                maximum=travel[1], unit="mm, within the travel: where the"
                                " axis is declared to stand")
        table.finish()
        return HomingConfig(-1, max_velocity, max_velocity, 0.0, position, 1.0, math.inf,
                            declare=True)
    allowed = "-1 (home onto the lower limit switch) or 1 (the upper one)"
    direction = table.raw("direction", default=-1, allowed=allowed)
    if isinstance(direction, bool) or direction not in (-1, 1):
        table.fail("direction", f"{_show(direction)} is not a homing direction; allowed: {allowed}")
    speed = table.number("speed_mm_s", default=min(max_velocity / 4, 20.0), above=0,
                         maximum=max_velocity, unit="mm/s, at most max_velocity_mm_s")
    slow = table.number("slow_speed_mm_s", default=speed / 10, above=0, maximum=speed,
                        unit="mm/s, at most speed_mm_s")
    length = travel[1] - travel[0]
    backoff = table.number("backoff_mm", default=min(2.0, length / 4), minimum=0,
                           maximum=length / 2, unit="mm, at most half the travel")
    pull_off = table.number("pull_off_mm", default=min(1.0, length / 4), above=0,
                            maximum=length / 2, unit="mm, at most half the travel")
    search = table.number("search_mm", default=1.5 * length, above=0, maximum=10 * length,
                          unit="mm, at most 10 x the travel; default 1.5 x")
    end = travel[0] if direction == -1 else travel[1]
    which = "lowest" if direction == -1 else "highest"
    beyond = "below" if direction == -1 else "above"
    position = table.number(
        "position_mm", default=end + direction * pull_off,
        minimum=end - length if direction == -1 else end,
        maximum=end if direction == -1 else end + length,
        unit=f"mm, {beyond} travel_mm's {which} end, by at most the travel's length",
    )
    if position == end:
        table.fail("position_mm", (
            f"{position!r} puts the switch at the end of the working travel, where a move to"
            f" {end:g} (G0 to the end, a CAM retract) closes it and faults the axis; allowed:"
            f" {beyond} {end:g}, e.g. {end + direction * pull_off:g} (pull_off_mm beyond it)"))
    home = position - direction * pull_off
    if (home < travel[0] - 1e-9) if direction == -1 else (home > travel[1] + 1e-9):
        table.fail("position_mm", (
            f"homing leaves the axis at {home:g} mm (the switch's position_mm {position:g}"
            f" pulled off by pull_off_mm {pull_off:g}), outside travel_mm [{travel[0]:g},"
            f" {travel[1]:g}], where no program may start; allowed: a position_mm within"
            f" pull_off_mm of the travel's {which} end ({end + direction * pull_off:g}"
            f" {'..' if direction == -1 else 'down to '}{end:g} excluded), or a longer"
            " pull_off_mm"))
    table.finish()
    return HomingConfig(int(direction), speed, slow, backoff, position, pull_off, search)


_SIM_UNITS = {"source_voltage_v": "volts", "torque_constant_mnm_per_a": "mNm per ampere",
              "winding_resistance_ohm": "ohms", "inertia_kg_m2": "kg m^2",
              "viscous_friction_unm_per_rad_s": "uNm per rad/s",
              "load_torque_mnm": "mNm, 0 for none"}


def _sim_motor(reader: _Reader, servo_interval_dms: int, *, simulated: bool,
               keys: tuple[str, ...], defaults: Mapping[str, float], what: str
               ) -> tuple[_Reader, int, dict[str, float]] | None:
    """A ``sim`` table's motor (an axis's or the spindle's): the table (for its other keys),
    its update interval and the values of :data:`SIM_MOTOR_CALLS`, each checked to the 4
    digits its call carries; None when there is none and the device is not simulated."""
    table = reader.table("sim", allowed=f"a table describing {what}")
    if table is None:
        if not simulated:
            return None
        table = _Reader(reader.source, {}, reader.key("sim"))
    table.expect(keys)
    interval = table.integer(
        "update_interval_dms",
        default=min(int(defaults["update_interval_dms"]), servo_interval_dms), minimum=1,
        maximum=servo_interval_dms, unit="tenths of a millisecond, at most servo_interval_dms",
    )
    values: dict[str, float] = {}
    for key, call in SIM_MOTOR_CALLS:
        if key == "load_torque_mnm":
            values[key] = table.number(key, default=defaults[key], minimum=0,
                                       unit=_SIM_UNITS[key])
        else:
            values[key] = table.number(key, default=defaults[key], above=0,
                                       unit=_SIM_UNITS[key])
        _sci(table, key, values[key], call=call, digits=4)
    return table, interval, values


def _sim(reader: _Reader, travel: tuple[float, float], counts_per_mm: float,
         servo_interval_dms: int, *, simulated: bool) -> SimMotorConfig | None:
    motor = _sim_motor(reader, servo_interval_dms, simulated=simulated, keys=_SIM_KEYS,
                       defaults=SIM_MOTOR_DEFAULTS, what="the simulated motor")
    if motor is None:
        return None
    table, interval, values = motor
    d = SIM_MOTOR_DEFAULTS
    counts_per_rev = table.integer(
        "counts_per_revolution", default=int(d["counts_per_revolution"]), minimum=1,
        maximum=BY_NUMBER[CallNumber.SET_SIM_COUNTS_PER_REVOLUTION].params[0].maximum,
        unit="encoder counts per revolution",
    )
    start, probe_side, probe_mm = _sim_place(table, travel, counts_per_mm)
    magnet = _sim_magnet(table)
    table.finish()
    return SimMotorConfig(
        update_interval_dms=interval, counts_per_revolution=counts_per_rev, start_mm=start,
        probe_side=probe_side, probe_mm=probe_mm, magnet_angle_deg=magnet, **values,
    )


def _sim_magnet(table: _Reader) -> float:
    """A simulated absolute encoder's ``magnet_angle_deg``: the angle it reads with the
    simulated shaft at 0 (where the magnet happens to sit on the shaft)."""
    return table.number("magnet_angle_deg", default=0.0, minimum=0.0, above=None,
                        maximum=359.999,
                        unit="degrees of the encoder's turn the simulated absolute encoder"
                             " reads with the shaft at 0 (encoder = 'absolute')")


def _sim_place(table: _Reader, travel: tuple[float, float],
               counts_per_mm: float) -> tuple[float, int, float]:
    """A simulated axis's ``start_mm`` and probe surface: (start, probe side, probe mm)."""
    start = table.number("start_mm", default=(travel[0] + travel[1]) / 2, minimum=travel[0],
                         maximum=travel[1], unit="mm, within travel_mm; default mid-travel")
    for end in travel:
        if not INT32_MIN <= round((end - start) * counts_per_mm) <= INT32_MAX:
            table.fail("start_mm", f"{start!r} puts a switch outside int32 counts")
    probe_side, probe_mm = 0, 0.0
    for side, key in ((1, "probe_below_mm"), (2, "probe_above_mm")):
        if table.has(key):
            if probe_side:
                table.fail(key, "the probe touches one surface: give probe_below_mm (a plate"
                           " under it) or probe_above_mm, not both")
            probe_side = side
            probe_mm = table.number(key, minimum=travel[0], maximum=travel[1],
                                    unit="mm, the probe's surface within travel_mm")
    return start, probe_side, probe_mm


def _sim_stepper(reader: _Reader, travel: tuple[float, float], counts_per_mm: float,
                 servo_interval_dms: int, *, simulated: bool) -> SimStepperConfig | None:
    """A stepper axis's ``sim`` table: the simulated stepper (calls 47, 12, 17, 32, 33)."""
    table = reader.table("sim", allowed="a table describing the simulated stepper")
    if table is None:
        if not simulated:
            return None
        table = _Reader(reader.source, {}, reader.key("sim"), reader.names)
    table.expect(_SIM_STEPPER_KEYS)
    d = SIM_STEPPER_DEFAULTS
    interval = table.integer(
        "update_interval_dms", default=min(int(d["update_interval_dms"]), servo_interval_dms),
        minimum=1, maximum=servo_interval_dms,
        unit="tenths of a millisecond, at most servo_interval_dms; 1 (100 us) suits a stepper")
    holding = _call_integer(table, "holding_torque_mnm", CallNumber.SET_SIM_STEPPER, 0,
                            default=int(d["holding_torque_mnm"]),
                            unit="mNm at the driver's current")
    detent = table.integer("detent_torque_mnm", default=min(holding, int(d["detent_torque_mnm"])),
                           minimum=BY_NUMBER[CallNumber.SET_SIM_STEPPER].params[1].minimum,
                           maximum=holding, unit="mNm unpowered, at most holding_torque_mnm")
    corner = _call_integer(table, "corner_rpm", CallNumber.SET_SIM_STEPPER, 2,
                           default=int(d["corner_rpm"]),
                           unit="rpm above which the torque falls as 1/speed")
    values: dict[str, float] = {}
    for key, call in SIM_MOTOR_CALLS:
        if key not in d:
            continue
        if key == "load_torque_mnm":
            values[key] = table.number(key, default=d[key], minimum=0, unit=_SIM_UNITS[key])
        else:
            values[key] = table.number(key, default=d[key], above=0, unit=_SIM_UNITS[key])
        _sci(table, key, values[key], call=call, digits=4)
    start, probe_side, probe_mm = _sim_place(table, travel, counts_per_mm)
    magnet = _sim_magnet(table)
    table.finish()
    return SimStepperConfig(
        update_interval_dms=interval, holding_torque_mnm=holding, detent_torque_mnm=detent,
        corner_rpm=corner, start_mm=start, probe_side=probe_side, probe_mm=probe_mm,
        magnet_angle_deg=magnet, **values)


def _check_stepper_torque(reader: _Reader, reach: StepperReach, max_velocity: float,
                          max_accel: float, *, closed: bool) -> None:
    """Refuse a ``max_velocity_mm_s`` or ``max_accel_mm_s2`` whose move needs more than
    ``1 - REACH_MARGIN`` (closed loop) or ``1 - OPEN_LOOP_MARGIN`` (open loop) of the
    simulated stepper's torque at that speed (the detent's ripple counted against it):
    beyond its pull-out torque an open-loop stepper loses steps, a closed-loop one falls
    behind."""
    table = ".".join(reader.key("sim"))
    motor = table if reader.has("sim") else f"the simulated stepper ({table}'s defaults)"
    margin = REACH_MARGIN if closed else OPEN_LOOP_MARGIN
    kept = f"{margin:.0%} of its torque"
    fate = "falls behind" if closed else "loses steps"
    torque_how = (f"{reach.holding_nm * 1e3:.4g} mNm up to {reach.corner_mm_s:.4g} mm/s,"
                  " falling as 1/speed above")
    usable_velocity = reach.usable_velocity_mm_s(margin=margin)
    if max_velocity > usable_velocity:
        reader.fail("max_velocity_mm_s", (
            f"{max_velocity!r} mm/s needs more than {1 - margin:.0%} of the torque of"
            f" {motor} at that speed ({torque_how}; friction, the load and the detent take"
            f" {reach.needed_nm(max_velocity, 0.0) * 1e3:.4g} mNm of the"
            f" {reach.torque_nm(max_velocity) * 1e3:.4g} mNm there): beyond it the stepper"
            f" {fate}; allowed: <= {_down(usable_velocity)} mm/s"))
    usable = reach.usable_accel_mm_s2(max_velocity, margin=margin)
    if max_accel > usable:
        reader.fail("max_accel_mm_s2", (
            f"{max_accel!r} mm/s^2 at max_velocity_mm_s {max_velocity:g} mm/s needs"
            f" {reach.needed_nm(max_velocity, max_accel) * 1e3:.4g} mNm (J a + friction, load"
            f" and detent), more than {1 - margin:.0%} of the"
            f" {reach.torque_nm(max_velocity) * 1e3:.4g} mNm {motor} gives at that speed"
            f" ({torque_how}): beyond it the stepper {fate}; allowed: <= {_down(usable)}"
            f" mm/s^2 (keeping {kept}), or a lower max_velocity_mm_s"))


def _tool_setter(reader: _Reader, axes: tuple[AxisConfig, ...]) -> ToolSetterConfig:
    reader.expect(("position_mm", "start_z_mm", "lowest_z_mm", "feed_mm_min",
                   "reference_z_mm"))
    by_name = {axis.name: axis for axis in axes}
    missing = [name for name in "XYZ" if name not in by_name]
    if missing:
        reader.fail(None, f"a tool setter needs axes X, Y and Z; the machine has no"
                    f" {', '.join(missing)}")
    allowed = "[X, Y]: the setter's button, machine mm within X's and Y's travel_mm"
    position = reader.raw("position_mm", allowed=allowed)
    if (not isinstance(position, list) or len(position) != 2
            or not all(isinstance(v, (int, float)) and not isinstance(v, bool)
                       for v in position)):
        reader.fail("position_mm", f"{_show(position)} is not two numbers; allowed: {allowed}")
    for value, name in zip(position, "XY", strict=True):
        low, high = by_name[name].travel_mm
        if not low <= float(value) <= high:
            reader.fail("position_mm", f"{name} {value!r} is outside axis {name}'s travel_mm"
                        f" [{low:g}, {high:g}]; allowed: {allowed}")
    low, high = by_name["Z"].travel_mm
    travel = f"machine mm within Z's travel_mm [{low:g}, {high:g}]"
    start = reader.number("start_z_mm", minimum=low, maximum=high, unit=travel)
    lowest = reader.number("lowest_z_mm", minimum=low, maximum=start,
                           unit=f"{travel}, below start_z_mm")
    feed = reader.number("feed_mm_min", default=100.0, above=0,
                         maximum=by_name["Z"].max_velocity_mm_s * 60, unit="mm/min")
    reference = (reader.number("reference_z_mm", minimum=low, maximum=high, unit=travel)
                 if reader.has("reference_z_mm") else None)
    reader.finish()
    return ToolSetterConfig(position_mm=(float(position[0]), float(position[1])),
                            start_z_mm=start, lowest_z_mm=lowest, feed_mm_min=feed,
                            reference_z_mm=reference)


def _outputs(reader: _Reader, axes: tuple[AxisConfig, ...]) -> OutputsConfig:
    reader.expect(("flood", "mist", "laser", "laser_max_s"))
    letters = [axis.name for axis in axes]
    pins: dict[str, OutputPin] = {}
    used: dict[tuple[str, int], str] = {}
    for name, kinds, allowed in (("flood", (0, 1), "0 or 1 (a digital output)"),
                                 ("mist", (0, 1), "0 or 1 (a digital output)"),
                                 ("laser", (2, 3), "2 or 3 (a PWM output)")):
        table = reader.table(name, allowed=f"a table: axis (whose device has the output),"
                             f" output {allowed}")
        if table is None:
            continue
        table.expect(("axis", "output"))
        axis = table.string("axis", allowed=f"an axis of the machine: {', '.join(letters)}")
        if axis not in letters:
            table.fail("axis", f"{axis!r} is not an axis of the machine; allowed:"
                       f" {', '.join(letters)}")
        output = table.integer("output", minimum=0, maximum=3,
                               unit="the device's output: 0, 1 digital; 2, 3 PWM")
        if output not in kinds:
            table.fail("output", f"{output} cannot carry {name}; allowed: {allowed}")
        if (axis, output) in used:
            table.fail("output", f"axis {axis}'s output {output} already carries"
                       f" {used[axis, output]}")
        used[axis, output] = name
        table.finish()
        pins[name] = OutputPin(axis, output)
    laser_max_s = reader.number("laser_max_s", default=1000.0, above=0, maximum=1e6,
                                unit="the S of the laser's full power (grbl's $30)")
    reader.finish()
    return OutputsConfig(pins=pins, laser_max_s=laser_max_s)


def _spindle(reader: _Reader, servo_interval_dms: int) -> SpindleConfig:
    reader.expect(_SPINDLE_KEYS)
    device = _device_name(reader)
    url = _url(reader)
    if device is None and url is None:
        reader.fail("device", "missing required key 'device' or 'url'; allowed: the spindle"
                    " device's name in its flash, or its port/URL (sim://S, /dev/ttyACM3)")
    simulated = url is not None and url.lower().startswith(SIM_SCHEME)
    sim = _spindle_sim(reader, servo_interval_dms, simulated=simulated)
    counts = reader.integer(
        "counts_per_revolution",
        default=sim.counts_per_revolution if sim is not None else _REQUIRED, minimum=1,
        maximum=BY_NUMBER[CallNumber.SET_SIM_COUNTS_PER_REVOLUTION].params[0].maximum,
        unit="encoder counts per spindle revolution (quadrature x4)")
    if sim is not None:
        sim = replace(sim, counts_per_revolution=counts)
    top_rpm = INT32_MAX * 60.0 / counts
    max_rpm = reader.number("max_rpm", above=0, maximum=min(top_rpm, 1e6), unit="rpm")
    accel = reader.number("accel_rpm_s", default=max_rpm, above=0, maximum=1e7,
                          unit="rpm per second; default max_rpm (a second from rest)")
    at_speed = reader.number("at_speed_tolerance", default=0.02, above=0, maximum=0.5,
                             unit="a share of the commanded speed: 0.02 = 2 %")
    stall = reader.number("stall_tolerance", default=max(0.15, 2 * at_speed), above=at_speed,
                          maximum=1.0, unit="a share of the commanded speed, beyond"
                          " at_speed_tolerance")
    timeout = reader.number("spin_up_timeout_s", default=5.0, above=0, maximum=600,
                            unit="seconds beyond the ramp's own time")
    gains = _gains(reader, "velocity_gains", defaults=SPINDLE_GAINS_DEFAULT,
                   mode="velocity mode")
    if sim is not None:
        top = simulated_reach(sim, float(counts)).velocity_mm_s * 60.0
        if max_rpm > (1 - REACH_MARGIN) * top:
            reader.fail("max_rpm", f"{max_rpm:g} rpm is more than the simulated motor reaches"
                        f" with a tenth of its supply left to the PID: at most"
                        f" {_down((1 - REACH_MARGIN) * top)} rpm (no-load {top:.0f} rpm at"
                        f" {sim.source_voltage_v:g} V)")
    reader.finish()
    return SpindleConfig(
        device=device, url=url, counts_per_revolution=counts, max_rpm=max_rpm,
        accel_rpm_s=accel, at_speed_tolerance=at_speed, stall_tolerance=stall,
        spin_up_timeout_s=timeout, velocity_gains=gains, sim=sim)


def _spindle_sim(reader: _Reader, servo_interval_dms: int, *,
                 simulated: bool) -> SimMotorConfig | None:
    d = SPINDLE_SIM_DEFAULTS
    motor = _sim_motor(reader, servo_interval_dms, simulated=simulated, keys=_SPINDLE_SIM_KEYS,
                       defaults=d, what="the simulated spindle motor")
    if motor is None:
        return None
    table, interval, values = motor
    table.finish()
    return SimMotorConfig(
        update_interval_dms=interval, counts_per_revolution=int(d["counts_per_revolution"]),
        start_mm=0.0, source_voltage_v=values["source_voltage_v"],
        torque_constant_mnm_per_a=values["torque_constant_mnm_per_a"],
        winding_resistance_ohm=values["winding_resistance_ohm"],
        inertia_kg_m2=values["inertia_kg_m2"],
        viscous_friction_unm_per_rad_s=values["viscous_friction_unm_per_rad_s"],
        load_torque_mnm=values["load_torque_mnm"])


def _homing_order(top: _Reader, axes: tuple[AxisConfig, ...]) -> tuple[tuple[str, ...], ...]:
    names = [axis.name for axis in axes]
    allowed = (
        'a list of axis names or lists of names homed together, e.g. ["Z", ["X", "Y"]],'
        f" naming each axis ({', '.join(names)}) once"
    )
    if "Z" in names and len(names) > 1:
        default: list[Any] = ["Z", [n for n in names if n != "Z"]]
    else:
        default = [names]
    value = top.raw("homing_order", default=default, allowed=allowed)
    if not isinstance(value, list) or not value:
        top.fail("homing_order", f"{_show(value)} is not a list; allowed: {allowed}")
    groups: list[tuple[str, ...]] = []
    for item in value:
        group = [item] if isinstance(item, str) else item
        if not isinstance(group, list) or not group or not all(isinstance(g, str) for g in group):
            top.fail("homing_order", f"{_show(item)} is not an axis name or a list of them;"
                     f" allowed: {allowed}")
        groups.append(tuple(group))
    listed = [name for group in groups for name in group]
    for name in listed:
        if name not in names:
            top.fail("homing_order", f"{name!r} is not an axis of this machine; allowed: {allowed}")
        if listed.count(name) > 1:
            top.fail("homing_order", f"{name!r} is listed twice; allowed: {allowed}")
    missing = [name for name in names if name not in listed]
    if missing:
        top.fail("homing_order", f"{', '.join(missing)} never homed; allowed: {allowed}")
    return tuple(groups)
