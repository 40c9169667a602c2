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
from typing import Any

import pytest

from stepper_loads import EXAMPLE
from usbmotion.device import Device, MemoryFlash
from usbmotion.host.config import MachineConfig
from usbmotion.motion.dialects import dialect_named
from usbmotion.sim.firmware import FirmwareSimDevice, default_uf2
from usbmotion.sim.machine import connect_session, load_machine_file
from usbmotion.sim.world import SimWorld

from .emulated import require_emulator
from .jobs import differences

ROOT = Path(__file__).resolve().parents[2]
PROGRAMS = {
    "demo 1": (ROOT / "src" / "usbmotion" / "data" / "demos" / "1-rounded-square.ngc", None,
               {}),
    "cam corner": (ROOT / "tests" / "programs" / "cam_corner.ngc", "grbl",
                   {"X": 100.0, "Y": 100.0, "Z": -40.0}),
}


def _machine(folder: Path) -> MachineConfig:
    """examples/stepper.toml at 1 kHz, Z with gains for it."""
    text = EXAMPLE.read_text()
    for old, new in (("servo_interval_dms = 1 ", "servo_interval_dms = 10 "),
                     ("gains = { kp = 0.5, ki = 1.0, kd = 0.005 }",
                      "gains = { kp = 0.2, ki = 1.0, kd = 0.001 }")):
        assert text.count(old) == 1, f"examples/stepper.toml no longer says {old!r}"
        text = text.replace(old, new)
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "stepper.toml"
    path.write_text(text)
    return load_machine_file(path)


def _report(folder: Path, program: str, firmware: Path | None) -> tuple[
        dict[str, Any], dict[str, int]]:
    """Home examples/stepper.toml and run ``program`` on emulated chips (``firmware``) or
    Python devices; the report and, per emulated axis, the lines compared."""
    path, dialect, origin = PROGRAMS[program]
    config = _machine(folder)
    world = SimWorld()
    emulated: dict[str, FirmwareSimDevice] = {}
    try:
        for axis in config.axes:
            assert axis.url is not None and axis.device is not None
            key = axis.url.removeprefix("sim://")
            if firmware is not None:
                emulated[axis.name] = FirmwareSimDevice(firmware, name=axis.device)
                world.add(emulated[axis.name], key=key)
            else:
                device = Device(flash=MemoryFlash())
                codes = " ".join(str(ord(c)) for c in axis.device)
                device.feed(f"18 {len(axis.device)} {codes}\n".encode("ascii"))
                device.take_output()
                world.add(device, key=key)
        with connect_session(config, world=world) as session:
            homing_s = session.home()
            if origin:
                session.set_work_origin(origin)
            prepared = session.prepare(path, text=path.read_text(),
                                       dialect=dialect_named(dialect) if dialect else None)
            report, _ = session.run(prepared, homing_s=homing_s)
            session.shutdown()
        return report.to_json(), {name: d.lines_compared for name, d in emulated.items()}
    finally:
        for chip in emulated.values():
            chip.close()


@pytest.mark.parametrize("program", sorted(PROGRAMS))
def test_a_stepper_machine_of_emulated_chips_gives_the_python_report(
        program: str, tmp_path: Path) -> None:
    require_emulator()
    python, _ = _report(tmp_path / "python", program, None)
    assert python["completed"] and not python["faults"], python
    emulated, compared = _report(tmp_path / "chips", program, default_uf2())
    assert differences(python, emulated) == []
    assert all(count > 1000 for count in compared.values()), compared
    peaks = {axis["name"]: axis["max_error_counts"] for axis in emulated["axes"]}
    print(f"{program} on examples/stepper.toml, emulated RP2040s: {emulated['executed_time_s']}"
          f" s, peak following error {peaks} microsteps, the Python devices' report to the"
          " field")
