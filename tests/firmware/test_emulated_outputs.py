"""Coolant and laser outputs on emulated RP2040s: a run of ``examples/laser.toml`` whose
axes are chips running the firmware, in virtual time. The flood output's pin (GP13 of X's
chip) goes high on the tick the move after ``M8`` takes its first setpoint, as on the
Python device; the laser's PWM pin (GP16) shows the program's power while a feed move cuts
and nothing on a rapid."""

from __future__ import annotations

import math
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from usbmotion.host.config import load_config
from usbmotion.session.live import LiveSnapshot
from usbmotion.sim.firmware import FirmwareSimDevice, default_uf2
from usbmotion.sim.machine import connect_session
from usbmotion.sim.world import SimWorld

from .emulated import require_emulator
from .native import ROOT

LASER = ROOT / "examples" / "laser.toml"


@pytest.fixture
def chips() -> Iterator[dict[str, FirmwareSimDevice]]:
    require_emulator()
    firmware = default_uf2()
    made = {axis: FirmwareSimDevice(firmware, name=f"{axis} AXIS") for axis in "XYZ"}
    try:
        yield made
    finally:
        for chip in made.values():
            chip.close()


def _world(chips: dict[str, FirmwareSimDevice]) -> SimWorld:
    world = SimWorld()
    for axis, chip in chips.items():
        world.add(chip, key=axis)
    return world


def test_the_flood_pin_rises_on_the_moves_first_tick(chips: dict[str, FirmwareSimDevice],
                                                     tmp_path: Path) -> None:
    machine = tmp_path / "laser.toml"
    machine.write_text(LASER.read_text())
    with connect_session(load_config(machine), world=_world(chips)) as session:
        session.home()
        session.run(session.prepare("flood.ngc", text="G21 G90\nG0 X10\nM8\nG1 X20 F600\n"))
        run = session.last_run
        assert run is not None
        plan = run.legs.plan
        segment = int(np.searchsorted(plan.line, 4, side="left"))
        row = math.ceil(float(plan.start_time_s[segment]) / run.legs.period_s - 1e-9)
        state = session.machine.axis("X").client.outputs()
        assert state.values[0] == 1000
        assert state.last_change_tick == run.streams.tick_of(row), (
            "the chip applied the M8 on the tick of the G1's first setpoint")
        assert chips["X"].chip.output_levels()[0] == 1000, "GP13 driven high"
        session.shutdown()


def test_the_laser_pin_shows_the_power_while_cutting_and_none_on_rapids(
        chips: dict[str, FirmwareSimDevice], tmp_path: Path) -> None:
    machine = tmp_path / "laser.toml"
    machine.write_text(LASER.read_text())
    program = "G21 G90\nG0 X10\nM3 S600\nG1 X30 F600\nG0 X50\nG1 X60\nM5\n"
    seen: list[tuple[float, float]] = []

    def look(snapshot: LiveSnapshot) -> None:
        x = snapshot.axes["X"].measured_mm
        if 12 < x < 28 or 32 < x < 48:
            seen.append((x, chips["X"].chip.output_levels()[2]))

    with connect_session(load_config(machine), world=_world(chips)) as session:
        session.home()
        session.run(session.prepare("laser.ngc", text=program), on_progress=look)
        session.shutdown()
    cutting = [level for x, level in seen if x < 30]
    rapid = [level for x, level in seen if x > 30]
    assert cutting and rapid, seen
    assert all(level == pytest.approx(600, abs=1) for level in cutting), cutting
    assert all(level == 0 for level in rapid), rapid
