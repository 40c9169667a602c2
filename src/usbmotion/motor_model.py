"""The continuous model of a brushed DC gearmotor, in floating point: what a motor can do.

At the output shaft (the one whose revolutions the encoder counts)::

    J dw/dt = Kt i - b w - T_load sign(w),      i = (V - Kt w) / R

(PROTOCOL.md, "The simulated motor"). The device simulates it in the firmware's integer
arithmetic (``usbmotion.device.motor``); these are its closed-form figures, for tools and
for checking a machine file's limits against what its motor reaches.
"""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True, slots=True)
class DcMotorModel:
    """A DC gearmotor's figures in SI units.

    Fields:
        torque_constant_nm_per_a: ``Kt``, equal to the back-EMF constant in V s/rad.
        resistance_ohm: winding resistance ``R``.
        inertia_kg_m2: rotor plus load inertia at the output shaft ``J``.
        viscous_nm_s_per_rad: viscous friction ``b``.
        load_torque_nm: constant torque opposing motion ``T_load``.
        counts_per_revolution: encoder counts per output revolution.
        source_voltage_v: the supply, the most the drive can apply.
    """

    torque_constant_nm_per_a: float
    resistance_ohm: float
    inertia_kg_m2: float
    viscous_nm_s_per_rad: float
    load_torque_nm: float
    counts_per_revolution: int
    source_voltage_v: float

    @property
    def counts_per_rad(self) -> float:
        """Encoder counts per radian of the output shaft."""
        return self.counts_per_revolution / (2.0 * math.pi)

    @property
    def damping_nm_s_per_rad(self) -> float:
        """``Kt^2/R + b``: the back-EMF's damping and the viscous friction's."""
        kt = self.torque_constant_nm_per_a
        return kt * kt / self.resistance_ohm + self.viscous_nm_s_per_rad

    def time_constant_s(self) -> float:
        """Mechanical time constant ``J / (Kt^2/R + b)``, s."""
        return self.inertia_kg_m2 / self.damping_nm_s_per_rad

    def steady_speed_counts_s(self, voltage_v: float) -> float:
        """Speed the motor settles at under a constant voltage, counts/s (0 when the load
        torque holds it)."""
        drive = self.torque_constant_nm_per_a * voltage_v / self.resistance_ohm
        if abs(drive) <= self.load_torque_nm:
            return 0.0
        return ((drive - math.copysign(self.load_torque_nm, drive))
                / self.damping_nm_s_per_rad * self.counts_per_rad)

    def stall_torque_nm(self) -> float:
        """Torque at standstill under the full source voltage, after the load torque, N m."""
        return (self.torque_constant_nm_per_a * self.source_voltage_v / self.resistance_ohm
                - self.load_torque_nm)
