"""Demo 1 and the CAM corner program on a stepper machine of emulated RP2040s.

``examples/stepper.toml`` (X and Y open-loop steppers, Z a closed-loop one) at a 1 kHz servo
period (a tenth of the example's ticks to emulate; Z with gains for that period),
its axes on three emulated chips in virtual time: the host homes it and runs each program
as on the Python devices, and the two reports are equal in every field, while every line
each chip printed was compared on the way with a Python device given the same bytes. The
figures are printed (``-s``).
"""

from __future__ import annotations

from pathlib import Path

import pytest

from stepper_loads import EXAMPLE
from usbmotion.host.config import MachineConfig
from usbmotion.sim.firmware import default_uf2
from usbmotion.sim.machine import load_machine_file

from .emulated import require_emulator
from .jobs import differences, virtual_report

ROOT = Path(__file__).resolve().parents[2]
PROGRAMS = {
    "demo 1": (ROOT / "src" / "usbmotion" / "data" / "demos" / "1-rounded-square.ngc", None,
               {}),
    "cam corner": (ROOT / "tests" / "programs" / "cam_corner.ngc", "grbl",
                   {"X": 100.0, "Y": 100.0, "Z": -40.0}),
}
ABSOLUTE_Z = {"cam corner"}
"""The programs run with Z's encoder absolute (call 49, its magnet a third of a turn round):
the chips take the angle, say where the turns begin, and home Z on a turn boundary as the
Python devices do."""


def _machine(folder: Path, *, absolute_z: bool = False) -> MachineConfig:
    """examples/stepper.toml at 1 kHz, Z with gains for it, each simulated axis starting
    3 mm inside the travel end it homes to, homing's slow approach quicker (the homing
    emulated in 3 s of machine time, not 25); with ``absolute_z``, Z's encoder absolute."""
    text = EXAMPLE.read_text()
    if absolute_z:
        old = "encoder_counts_per_rev = 4000"
        assert text.count(old) == 1, f"examples/stepper.toml no longer says {old!r}"
        text = text.replace(old, f'{old}\nencoder = "absolute"').replace(
            "start_mm = -40.0,", "start_mm = -40.0, magnet_angle_deg = 120.0,")
    for old, new, count in (("servo_interval_dms = 1 ", "servo_interval_dms = 10 ", 1),
                            ("gains = { kp = 0.5, ki = 1.0, kd = 0.005 }",
                             "gains = { kp = 0.2, ki = 1.0, kd = 0.001 }", 1),
                            ("start_mm = 150.0", "start_mm = 3.0", 1),
                            ("start_mm = 100.0", "start_mm = 3.0", 1),
                            ("start_mm = -40.0", "start_mm = -3.0", 1),
                            ("slow_speed_mm_s = 1.0, backoff_mm = 1.0",
                             "slow_speed_mm_s = 4.0, backoff_mm = 0.5", 3)):
        assert text.count(old) == count, f"examples/stepper.toml no longer says {old!r}"
        text = text.replace(old, new)
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "stepper.toml"
    path.write_text(text)
    return load_machine_file(path)


@pytest.mark.parametrize("program", sorted(PROGRAMS))
def test_a_stepper_machine_of_emulated_chips_gives_the_python_report(
        program: str, tmp_path: Path) -> None:
    require_emulator()
    path, dialect, origin = PROGRAMS[program]
    absolute = program in ABSOLUTE_Z
    python_machine = _machine(tmp_path / "python", absolute_z=absolute)
    assert (python_machine.axis("Z").absolute_encoder is not None) == absolute
    python = virtual_report(python_machine, firmware=None, program=path,
                            dialect=dialect, origin=origin).report
    assert python["completed"] and not python["faults"], python
    run = virtual_report(_machine(tmp_path / "chips", absolute_z=absolute),
                         firmware=default_uf2(), program=path, dialect=dialect, origin=origin)
    emulated = run.report
    assert differences(python, emulated) == []
    assert all(count > 1000 for count in run.lines_compared.values()), run.lines_compared
    peaks = {axis["name"]: axis["max_error_counts"] for axis in emulated["axes"]}
    encoder = ", Z's encoder absolute" if absolute else ""
    print(f"{program} on examples/stepper.toml{encoder}, emulated RP2040s:"
          f" {emulated['executed_time_s']}"
          f" s, peak following error {peaks} microsteps, the Python devices' report to the"
          " field")
