"""Simulated machines: the devices of a machine file's ``sim://`` axes in a virtual-time
world, behind URLs the host opens like any port.

The host knows only ports (``usbmotion.host.machine.Machine``). This is where a machine
file's simulated axes become devices: each gets a :class:`~usbmotion.device.Device` with the
file's motor and travel, named as the file says, in one world (so every axis ticks on the
same clock), registered under an alias that ``sim://KEY?world=ALIAS`` URLs reach.
:class:`SimulatedMachine` is a ``Machine`` connected that way; :func:`connect_session` a
machine session on one.
"""

from __future__ import annotations

import dataclasses
import itertools
from collections.abc import Sequence
from pathlib import Path
from urllib.parse import quote

from usbmotion.device import Device, MemoryFlash
from usbmotion.device.motor import MotorParams
from usbmotion.errors import ConfigError
from usbmotion.host.config import (
    AxisConfig,
    MachineConfig,
    SimMotorConfig,
    SimStepperConfig,
    load_config,
)
from usbmotion.host.device import to_sci
from usbmotion.host.discovery import PROBE_TIMEOUT_S
from usbmotion.host.machine import Axis, Machine
from usbmotion.host.spindle import Spindle
from usbmotion.protocol import encode_device_name
from usbmotion.protocol.table import INT32_MAX, INT32_MIN
from usbmotion.session import MachineSession
from usbmotion.sim.registry import drop_world, set_world
from usbmotion.sim.urls import URL_CHECKS, machine_url_problem, parse_sim_url
from usbmotion.sim.world import SimWorld

_aliases = itertools.count(1)


def load_machine_file(path: str | Path) -> MachineConfig:
    """A machine file read as :func:`usbmotion.host.config.load_config` reads it, its
    ``sim://`` URLs checked too.

    Raises:
        ConfigError: as ``load_config``; a bad ``sim://`` URL names the axis's key and line.
    """
    return load_config(path, url_checks=URL_CHECKS)


def sim_motor_params(sim: SimMotorConfig, *, travel_counts: tuple[int, int]) -> MotorParams:
    """The device's ``MotorParams`` for a simulated axis: each value to the 4 significant
    digits its call carries, the switches at ``travel_counts``."""

    def pair(value: float, label: str) -> tuple[int, int]:
        coefficient, exponent = to_sci(value, digits=4, parameter=label)
        return (coefficient, exponent if coefficient else 0)

    return MotorParams(
        source_voltage_v=pair(sim.source_voltage_v, "source_voltage_v"),
        torque_constant_mnm_per_a=pair(sim.torque_constant_mnm_per_a,
                                       "torque_constant_mnm_per_a"),
        winding_resistance_ohm=pair(sim.winding_resistance_ohm, "winding_resistance_ohm"),
        counts_per_revolution=sim.counts_per_revolution,
        inertia_kg_m2=pair(sim.inertia_kg_m2, "inertia_kg_m2"),
        viscous_friction_unm_per_rad_s=pair(sim.viscous_friction_unm_per_rad_s,
                                            "viscous_friction_unm_per_rad_s"),
        load_torque_mnm=pair(sim.load_torque_mnm, "load_torque_mnm"),
        sim_update_interval_dms=sim.update_interval_dms,
        travel_lower_counts=travel_counts[0],
        travel_upper_counts=travel_counts[1],
    )


def _add_simulated(world: SimWorld, key: str, axis: AxisConfig) -> None:
    """Put the simulated device of ``axis`` into ``world`` under ``key`` (if not there yet)."""
    if key in world.keys:
        return
    assert axis.sim is not None
    travel = axis.sim_travel_counts
    assert travel is not None
    if isinstance(axis.sim, SimStepperConfig):
        # The device powers up driving a DC motor; connecting sets the drive, the stepper
        # and its motor (Machine.configure), which starts the shaft afresh at 0.
        motor = MotorParams(sim_update_interval_dms=axis.sim.update_interval_dms,
                            travel_lower_counts=travel[0], travel_upper_counts=travel[1])
    else:
        motor = sim_motor_params(axis.sim, travel_counts=travel)
    device = Device(flash=MemoryFlash(), motor=motor)
    name = axis.device or key
    device.feed(encode_device_name(name))
    device.take_output()
    world.add(device, key=key)


def _sim_url(key: str, alias: str, latency_us: int) -> str:
    query = f"world={quote(alias)}"
    if latency_us:
        query += f"&latency_us={latency_us}"
    return f"sim://{quote(key)}?{query}"


def simulate(config: MachineConfig, world: SimWorld, alias: str) -> MachineConfig:
    """The devices of ``config``'s ``sim://`` axes added to ``world`` (if not there yet), and
    the configuration with those axes' URLs pointing at them through ``alias``."""
    axes: list[AxisConfig] = []
    for axis in config.axes:
        if axis.is_simulated:
            assert axis.url is not None
            problem = machine_url_problem(axis.url)
            if problem is not None:
                raise ConfigError(f"{config.path}: axes.{axis.name}.url: {problem}",
                                  path=str(config.path), key=f"axes.{axis.name}.url")
            key, _, latency_us = parse_sim_url(axis.url)
            _add_simulated(world, key, axis)
            axis = dataclasses.replace(axis, url=_sim_url(key, alias, latency_us))
        axes.append(axis)
    spindle = config.spindle
    if spindle is not None and spindle.is_simulated:
        assert spindle.url is not None and spindle.sim is not None
        problem = machine_url_problem(spindle.url)
        if problem is not None:
            raise ConfigError(f"{config.path}: spindle.url: {problem}",
                              path=str(config.path), key="spindle.url")
        key, _, latency_us = parse_sim_url(spindle.url)
        if key not in world.keys:
            device = Device(flash=MemoryFlash(), motor=sim_motor_params(
                spindle.sim, travel_counts=(INT32_MIN, INT32_MAX)))
            device.feed(encode_device_name(spindle.device or key))
            device.take_output()
            world.add(device, key=key)
        spindle = dataclasses.replace(spindle, url=_sim_url(key, alias, latency_us))
    return dataclasses.replace(config, axes=tuple(axes), spindle=spindle)


class SimulatedMachine(Machine):
    """A machine whose ``sim://`` axes are simulated devices of :attr:`world`.

    Build one with :meth:`connect`; closing it also forgets the world's URL alias.
    """

    def __init__(self, config: MachineConfig, axes: Sequence[Axis],
                 spindle: Spindle | None = None) -> None:
        super().__init__(config, axes, spindle)
        self.world = SimWorld()
        """The world the simulated axes live in."""
        self._alias = ""

    @classmethod
    def connect(
        cls,
        config: MachineConfig,
        *,
        search_ports: bool = True,
        ports: Sequence[str] = (),
        probe_timeout_s: float = PROBE_TIMEOUT_S,
        world: SimWorld | None = None,
    ) -> SimulatedMachine:
        """Make the simulated devices (in ``world``, a fresh one by default) and connect.

        Axes named by device name only are also looked for among the world's devices.

        Raises:
            as :meth:`usbmotion.host.machine.Machine.connect`.
        """
        world = world if world is not None else SimWorld()
        alias = f"machine-{next(_aliases)}"
        set_world(alias, world)
        try:
            wired = simulate(config, world, alias)
            candidates = [*ports, *(_sim_url(key, alias, 0) for key in world.keys)]
            machine = super().connect(wired, search_ports=search_ports, ports=candidates,
                                      probe_timeout_s=probe_timeout_s)
        except BaseException:
            drop_world(alias)
            raise
        assert isinstance(machine, SimulatedMachine)
        machine.world = world
        machine._alias = alias
        return machine

    def close(self) -> None:
        """Close every link and forget the world's alias (safe twice)."""
        super().close()
        if self._alias:
            drop_world(self._alias)
            self._alias = ""


def connect_session(config: MachineConfig, *, world: SimWorld | None = None) -> MachineSession:
    """A machine session on a :class:`SimulatedMachine` (taken over as any machine is).

    Raises:
        as :meth:`usbmotion.session.MachineSession.take_over`.
    """
    return MachineSession.take_over(SimulatedMachine.connect(config, world=world))


def connect_machine(config: MachineConfig, *, world: SimWorld | None = None) -> Machine:
    """The machine of ``config``: a :class:`SimulatedMachine` when it has ``sim://`` axes,
    else a plain one on its ports."""
    if any(axis.is_simulated for axis in config.axes):
        return SimulatedMachine.connect(config, world=world)
    return Machine.connect(config)
