"""A 4-axis program (X, Y, Z and a wrapped rotary table A) on four emulated RP2040s in
virtual time gives the Python devices' report in every field: a rotary axis is counts to
the devices, and the host's degrees reach them as exactly as its millimetres."""

from __future__ import annotations

from pathlib import Path

from usbmotion.host.config import load_config
from usbmotion.sim.firmware import default_uf2

from .emulated import require_emulator
from .jobs import differences, virtual_report
from .native import ROOT

MACHINE = ROOT / "examples" / "machine-4axis.toml"
PROGRAM = ROOT / "examples" / "4-axis-wrap.ngc"


def test_a_four_axis_program_on_emulated_chips_gives_the_python_report(tmp_path: Path) -> None:
    require_emulator()
    config = load_config(MACHINE)
    python = virtual_report(config, firmware=None, program=PROGRAM)
    assert python.report["completed"] and not python.report["faults"], python.report
    emulated = virtual_report(config, firmware=default_uf2(), program=PROGRAM)
    assert differences(python.report, emulated.report) == []
    assert set(emulated.lines_compared) == {"X", "Y", "Z", "A"}
    assert emulated.lines_compared["A"] > 100
    assert abs(emulated.report["end_position_mm"]["A"] - 360.0) < 2 / 53.3
