"""A load put on a simulated stepper axis mid-run, and what the machine makes of it.

Shared by ``tests/test_steppers.py`` and ``benchmarks/stepper_lost_steps.py``. The machine
is ``examples/stepper.toml`` (copied into a folder of the caller's, so its parameter file
lands there): X and Y open loop, Z closed loop. The load is call 33 fed to the simulated
device itself, from the run's progress callback, as ``tests/test_spindle.py`` stalls its
spindle: the host knows nothing of it.

Open loop, a load beyond the stepper's pull-out torque stalls the shaft while the device
goes on issuing steps: the run completes (the counter is the steps issued, so no following
error shows), and the next homing finds the switch at another step count than the one the
first homing set. Closed loop, the encoder sees the shaft fall behind on the tick it
happens: below the holding torque the axis catches up; above it, the following error
passes call 29's limit and the device faults, an alarm that stops every axis.
"""

from __future__ import annotations

import shutil
from dataclasses import dataclass
from pathlib import Path

from usbmotion.device import Device
from usbmotion.device.motor import MICRO
from usbmotion.host.config import AxisConfig, MachineConfig
from usbmotion.session import RunReport
from usbmotion.session.live import LiveSnapshot
from usbmotion.sim.machine import SimulatedMachine, connect_session, load_machine_file

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "stepper.toml"

OPEN_PROGRAM = "G21 G90\nG1 X150 F1200\nG1 X60\nM2\n"
"""X (open loop) from its home at 0 out to 150 mm at 20 mm/s and back to 60 mm."""
CLOSED_PROGRAM = "G21 G90\nG1 X120 Y90 Z-60 F1200\nG1 X40 Y30\nM2\n"
"""X, Y and Z (closed loop) together along one line at 20 mm/s (Z at 7.3 mm/s), then back."""


def stepper_machine(folder: Path) -> MachineConfig:
    """``examples/stepper.toml`` copied into ``folder`` and read."""
    path = folder / "stepper.toml"
    shutil.copyfile(EXAMPLE, path)
    return load_machine_file(path)


@dataclass(frozen=True, slots=True)
class LoadedRun:
    """A run with a load on one axis for a while, and the homing after it.

    Fields:
        axis: the loaded axis.
        load_mnm: the load, mNm (its sim table's own load before and after).
        on_s, off_s: program time the load went on and off, s.
        report: the run's report.
        steps_issued: the device's step counter at the end of the run (call 48).
        shaft_microsteps: where the simulated shaft stood then, microsteps from where the
            drive was set (the device's truth, which no host sees).
        rehome_shift: the counter shift the next homing made on the axis (latched switch
            edge against the machine position homing gives it), microsteps; ``None`` when
            the run ended in a fault (no homing was tried).
    """

    axis: str
    load_mnm: float
    on_s: float
    off_s: float
    report: RunReport
    steps_issued: int
    shaft_microsteps: int
    rehome_shift: int | None

    @property
    def slipped_microsteps(self) -> int:
        """Steps issued that the shaft did not make, microsteps (the device's truth)."""
        return self.steps_issued - self.shaft_microsteps


def full_steps(config: AxisConfig, microsteps: int) -> float:
    """Microsteps in full steps of the axis's motor."""
    assert config.stepper is not None
    return microsteps / config.stepper.microsteps


def run_with_load(config: MachineConfig, program: str, *, axis: str, load_mnm: float,
                  on_s: float, for_s: float, rehome: bool = True) -> LoadedRun:
    """Home, run ``program`` with ``load_mnm`` on ``axis`` from ``on_s`` into the program for
    ``for_s`` (as the progress callbacks see the time), then (``rehome``, a run that did not
    fault) home again and take the shift that homing made."""
    settings = config.axis(axis)
    assert settings.sim is not None
    usual = settings.sim.load_torque_mnm
    machine: list[SimulatedMachine] = []
    seen: dict[str, float] = {}

    def device() -> Device:
        found = machine[0].world.device(axis)
        assert isinstance(found, Device)
        return found

    def load(snapshot: LiveSnapshot) -> None:
        if not machine:
            return
        if "on" not in seen and snapshot.done_s >= on_s:
            device().feed(f"33 {round(load_mnm)} 0\n".encode())
            seen["on"] = snapshot.done_s
        elif "on" in seen and "off" not in seen and snapshot.done_s >= seen["on"] + for_s:
            device().feed(f"33 {round(usual)} 0\n".encode())
            seen["off"] = snapshot.done_s

    with connect_session(config) as session:
        assert isinstance(session.machine, SimulatedMachine)
        machine.append(session.machine)
        session.home()
        prepared = session.prepare("loaded.ngc", text=program)
        report, _ = session.run(prepared, on_progress=load)
        if "off" not in seen:
            device().feed(f"33 {round(usual)} 0\n".encode())
        client = session.machine.axis(axis).client
        issued = client.steps().issued
        state = device().state
        shaft = state.shaft_micro_counts // MICRO
        shift: int | None = None
        if rehome and report.completed:
            session.home(axes=[axis])
            shift = session.zeroes[axis].shift_counts
        session.shutdown()
    return LoadedRun(axis, load_mnm, seen.get("on", 0.0), seen.get("off", 0.0), report,
                     issued, shaft, shift)
