"""A program's following error before anything moves: the program played on simulated
devices whose motors are the identified models of the machine's axes.

Each axis's motor comes from its ``model`` table (``usbmotion tune --auto --write``), or,
for an axis without one, from its ``sim`` table (a simulated axis's own motor). The
simulated devices run the device's own servo tick with the machine file's gains, in
virtual time, and the host streams them the program as it streams real devices: the plan,
the setpoints and the report are those of the real run. The machine is declared homed
where the real homing leaves it (or where the real machine stands), so the first move is
the real run's too.

A model gives a motor only up to a scale: volts and counts tell the time constant, the
speed per volt and the Coulomb voltage, not the torque constant apart from the inertia
(``usbmotion.autotune.model``). Any motor with those three figures moves alike; the one
simulated keeps the file's torque constant and resistance (the device's defaults without a
``sim`` table) where they fit the model, and derives inertia, viscous friction and load
torque from them.
"""

from __future__ import annotations

import dataclasses
import math
import shutil
import tempfile
import time
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

from usbmotion.errors import ConfigError
from usbmotion.host.config import (
    REACH_MARGIN,
    SIM_MOTOR_DEFAULTS,
    SPINDLE_SIM_DEFAULTS,
    AxisConfig,
    MachineConfig,
    MotorModelConfig,
    SimMotorConfig,
    SimStepperConfig,
    SpindleConfig,
)
from usbmotion.motion.dialects import Dialect
from usbmotion.motion.gcode import Pauses
from usbmotion.session import RunReport, Trace
from usbmotion.session.homing import home_position_mm
from usbmotion.sim.machine import connect_session
from usbmotion.sim.world import SimWorld

IDENTIFIED = "identified (its model table)"
"""How a prediction names a motor from the axis's ``model`` table."""
SIMULATED = "its sim table (not identified)"
"""How a prediction names a motor from the axis's ``sim`` table."""
BACK_EMF_SHARE = 0.9
"""Of the largest torque constant a model allows (all its damping the back-EMF's), the
share a simulated motor takes at most, leaving the rest to viscous friction."""


@dataclass(frozen=True, slots=True)
class Prediction:
    """A program played on the identified models.

    Fields:
        report: the run's report, as a real run's (its ``axes`` the predicted peak and RMS
            following error, its ``line_peaks`` each line's predicted peak).
        trace: the predicted run's diagnostics.
        motors: axis -> where its motor came from (:data:`IDENTIFIED`, :data:`SIMULATED`).
        wall_s: how long the prediction took, s.
    """

    report: RunReport
    trace: Trace
    motors: Mapping[str, str]
    wall_s: float

    @property
    def speed_ratio(self) -> float:
        """Program time over the prediction's wall time."""
        return self.report.planned_time_s / self.wall_s if self.wall_s > 0 else math.inf


def model_motor(model: MotorModelConfig, like: SimMotorConfig | None, *,
                update_interval_dms: int) -> SimMotorConfig:
    """A simulated motor that moves as ``model`` says, with ``like``'s torque constant,
    resistance and encoder (the device's defaults when None) where they fit the model.

    With ``k`` radians per count, the model's ``g`` (speed per volt), ``tau`` and ``C``
    fix ``Kt / (R g k)`` as the damping ``Kt^2/R + b``; a torque constant above ``1 / (g
    k)`` would need negative viscous friction, so at most :data:`BACK_EMF_SHARE` of it is
    taken. Then ``J = tau x damping``, ``b = damping - Kt^2/R``, ``T_load = C Kt / R``.
    """
    d = SIM_MOTOR_DEFAULTS
    counts = like.counts_per_revolution if like is not None else int(d["counts_per_revolution"])
    resistance = like.winding_resistance_ohm if like is not None else d["winding_resistance_ohm"]
    kt_nominal = (like.torque_constant_mnm_per_a if like is not None
                  else d["torque_constant_mnm_per_a"]) * 1e-3
    rad_per_count = 2.0 * math.pi / counts
    kt_most = 1.0 / (model.speed_per_volt_counts_s * rad_per_count)
    kt = min(kt_nominal, BACK_EMF_SHARE * kt_most)
    damping = kt / (resistance * model.speed_per_volt_counts_s * rad_per_count)
    viscous = damping - kt * kt / resistance
    return SimMotorConfig(
        update_interval_dms=update_interval_dms,
        source_voltage_v=model.supply_v,
        torque_constant_mnm_per_a=kt * 1e3,
        winding_resistance_ohm=resistance,
        counts_per_revolution=counts,
        inertia_kg_m2=model.time_constant_s * damping,
        viscous_friction_unm_per_rad_s=viscous * 1e6,
        load_torque_mnm=model.coulomb_v * kt / resistance * 1e3,
        start_mm=like.start_mm if like is not None else 0.0,
    )


def _model_axis(axis: AxisConfig, standing_mm: float, servo_interval_dms: int
                ) -> tuple[AxisConfig, str]:
    """``axis`` as a simulated device with the axis's motor, standing at ``standing_mm`` and
    homed by declaring it (its switches at least half the travel beyond its ends)."""
    motor: SimMotorConfig | SimStepperConfig
    if axis.model is not None:
        step = axis.sim.update_interval_dms if axis.sim else min(10, servo_interval_dms)
        like = axis.sim if isinstance(axis.sim, SimMotorConfig) else None
        motor = model_motor(axis.model, like, update_interval_dms=step)
        source = IDENTIFIED
    elif axis.sim is not None:
        motor, source = axis.sim, SIMULATED
    elif axis.stepper is not None:
        raise ConfigError(
            f"axis {axis.name} is a stepper with no sim table to predict with: give"
            f" axes.{axis.name}.sim (its holding_torque_mnm, corner_rpm, inertia_kg_m2 and"
            " friction)", key=f"axes.{axis.name}.sim")
    else:
        raise ConfigError(
            f"axis {axis.name} has no identified model to predict with: identify it first"
            f" (usbmotion tune -a {axis.name} --auto --travel MM --write), which writes"
            f" axes.{axis.name}.model", key=f"axes.{axis.name}.model")
    low, high = axis.travel_mm
    standing = min(max(standing_mm, low), high)
    # The switch of a declared homing lies as far beyond the travel as the homing
    # position is from the end it homes to: the far end's puts both well outside.
    direction = 1 if abs(standing - high) >= abs(standing - low) else -1
    homing = dataclasses.replace(axis.homing, declare=True, position_mm=standing,
                                 direction=direction)
    return dataclasses.replace(
        axis, url=f"sim://{axis.name}", device=axis.device or f"{axis.name} AXIS",
        sim=dataclasses.replace(motor, start_mm=standing), homing=homing, reach=None,
    ), source


def model_machine(config: MachineConfig, *, parameter_file: Path,
                  standing_mm: Mapping[str, float] | None = None
                  ) -> tuple[MachineConfig, dict[str, str]]:
    """The machine of simulated devices on the axes' models (see the module docstring),
    each axis standing at ``standing_mm`` (default: where its homing leaves it), with
    ``parameter_file`` for its offsets; and axis -> where its motor came from.

    Raises:
        ConfigError: an axis has neither a ``model`` nor a ``sim`` table.
    """
    standing = standing_mm or {}
    axes: list[AxisConfig] = []
    motors: dict[str, str] = {}
    for axis in config.axes:
        where = standing.get(axis.name, home_position_mm(axis))
        modelled, motors[axis.name] = _model_axis(axis, where, config.servo_interval_dms)
        axes.append(modelled)
    machine = dataclasses.replace(
        config, axes=tuple(axes), name=f"{config.name} (predicted)", watchdog_ms=0, ports=(),
        parameter_file=parameter_file, joints=(),
        spindle=None if config.spindle is None else model_spindle(config.spindle))
    return machine, motors


def model_spindle(spindle: SpindleConfig) -> SpindleConfig:
    """A simulated spindle for a prediction: its own ``sim`` table when it has one, else
    the default simulated spindle motor wound to reach ``max_rpm`` with a tenth of its
    supply left (the axes wait at each spindle pause as long as the ramp takes)."""
    sim = spindle.sim
    if sim is None:
        defaults = SPINDLE_SIM_DEFAULTS
        volts = defaults["source_voltage_v"]
        no_load_rad_s = spindle.max_rpm / (1 - REACH_MARGIN) / 0.95 * 2 * math.pi / 60
        sim = SimMotorConfig(
            update_interval_dms=int(defaults["update_interval_dms"]),
            source_voltage_v=volts,
            torque_constant_mnm_per_a=round(volts / no_load_rad_s * 1000, 3),
            winding_resistance_ohm=defaults["winding_resistance_ohm"],
            counts_per_revolution=spindle.counts_per_revolution,
            inertia_kg_m2=defaults["inertia_kg_m2"],
            viscous_friction_unm_per_rad_s=defaults["viscous_friction_unm_per_rad_s"],
            load_torque_mnm=defaults["load_torque_mnm"], start_mm=0.0)
    return dataclasses.replace(spindle, url="sim://predicted-spindle", device=None, sim=sim)


def predict(config: MachineConfig, program: Path, text: str, *,
            dialect: Dialect | None = None, from_line: int | None = None,
            standing_mm: Mapping[str, float] | None = None) -> Prediction:
    """Play ``program`` (``text``) on the models of ``config``'s axes (:func:`model_machine`)
    in virtual time: the report a run from ``standing_mm`` (default: homed) would give.
    The machine's parameter file is read, never written.

    Raises:
        ConfigError: an axis without a model; GCodeError, SoftLimitError, PlanningError: as
            ``MachineSession.prepare``.
    """
    started = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="usbmotion-predict-") as folder:
        parameters = Path(folder) / "offsets.var"
        if config.parameter_path.is_file():
            shutil.copyfile(config.parameter_path, parameters)
        machine, motors = model_machine(config, parameter_file=parameters,
                                        standing_mm=standing_mm)
        with connect_session(machine, world=SimWorld()) as session:
            session.home()
            prepared = session.prepare(program, text=text, dialect=dialect,
                                       pauses=Pauses.NONE, from_line=from_line)
            report, trace = session.run(prepared)
            session.shutdown()
    return Prediction(report, trace, motors, time.monotonic() - started)


__all__ = ["IDENTIFIED", "SIMULATED", "Prediction", "model_machine", "model_motor", "predict"]
