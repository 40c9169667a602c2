"""Demo 1 on a machine of emulated RP2040s and on one of Python devices, and their reports.

Two ways to run the job:

- in virtual time (:func:`virtual_report`): the host drives devices in a ``SimWorld``, each
  either a Python device or the firmware on an emulated chip
  (``usbmotion.sim.firmware.FirmwareSimDevice``); nothing depends on the wall clock, so the
  two reports must be equal in every field;
- in real time (:func:`realtime_report`): ``usbmotion sim --pty 3`` (with ``--firmware``,
  emulated chips) in one process and ``usbmotion run --machine`` in another, as with real
  devices. Homing then ends wherever the host's reactions put it, and the run's figures move
  by a count or a millisecond from run to run on either kind of device (``python -m
  firmware.jobs`` prints a table of several runs of each); ``--record`` keeps the bytes each
  emulated chip received, with their ticks, for a deterministic replay.

The machine is ``examples/machine-firmware.toml``: the default machine with each carriage
5 mm from its switch and the watchdog on.
"""

from __future__ import annotations

import contextlib
import json
import signal
import subprocess
import sys
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from usbmotion.device import Device, MemoryFlash
from usbmotion.host.config import AxisConfig, MachineConfig, load_config
from usbmotion.motion.dialects import dialect_named
from usbmotion.motion.gcode import read_gcode_text
from usbmotion.sim.firmware import FirmwareSimDevice, PinsMotor, default_uf2
from usbmotion.sim.machine import connect_session, sim_motor_params
from usbmotion.sim.world import SimWorld

from .native import ROOT

DEMO = ROOT / "src" / "usbmotion" / "data" / "demos" / "1-rounded-square.ngc"
MACHINE = ROOT / "examples" / "machine-firmware.toml"
NAMES = ("X AXIS", "Y AXIS", "Z AXIS")
TCP_URLS = {f"socket://127.0.0.1:{7000 + i}": name for i, name in enumerate(NAMES)}

DEVICE_FIGURES = ("max_error_counts", "max_error_time_s", "max_error_line",
                  "final_error_counts", "rms_error_counts", "ticks")
"""The per-axis figures of a report that the devices count (call 35, call 20)."""


def machine_text(urls: dict[str, str]) -> str:
    """examples/machine-firmware.toml with each axis's url replaced (device name -> url)."""
    text = MACHINE.read_text(encoding="utf-8")
    for tcp, name in TCP_URLS.items():
        text = text.replace(f'url = "{tcp}"', f'url = "{urls[name]}"')
    return text


def virtual_config(folder: Path) -> MachineConfig:
    """The machine with ``sim://`` axes (devices in a virtual-time world)."""
    path = folder / "virtual.toml"
    path.write_text(machine_text({name: f"sim://{name[0]}" for name in NAMES}),
                    encoding="utf-8")
    return load_config(path)


@dataclass
class VirtualRun:
    """A job in virtual time: its report, and per emulated axis the lines compared with
    the Python shadow and the ticks run (empty for Python devices)."""

    report: dict[str, Any]
    lines_compared: dict[str, int]
    ticks: dict[str, int]
    wall_s: float


def pins_motor(axis: AxisConfig) -> PinsMotor:
    """The motor outside the chip for ``axis``: the one its ``sim`` table gives the on-chip
    simulated motor (calls 12-17, 32-34 as the host sends them), its switches where the
    travel's are."""
    assert axis.sim is not None and axis.sim_travel_counts is not None
    return PinsMotor.like(sim_motor_params(axis.sim, travel_counts=axis.sim_travel_counts))


def virtual_report(config: MachineConfig, *, firmware: Path | None, pins: bool = False,
                   program: Path = DEMO, dialect: str | None = None,
                   origin: dict[str, float] | None = None) -> VirtualRun:
    """Home the machine and run ``program`` (demo 1; in ``dialect``, from the work
    ``origin`` when given) in virtual time; ``firmware``: on emulated chips running this
    image, else on Python devices (made as the firmware's are: default motor, blank flash,
    the name written by call 18). ``pins``: each chip drives the axis's motor outside it
    through its pins (call 39 1 and a power cycle first; its lines are then not compared
    with the Python shadow's)."""
    assert firmware is not None or not pins
    world = SimWorld()
    emulated: dict[str, FirmwareSimDevice] = {}
    started = time.monotonic()
    try:
        for axis in config.axes:
            assert axis.url is not None and axis.device is not None
            key = axis.url.removeprefix("sim://")
            if firmware is not None:
                emulated[axis.name] = FirmwareSimDevice(
                    firmware, name=axis.device, motor=pins_motor(axis) if pins else None)
                world.add(emulated[axis.name], key=key)
            else:
                device = Device(flash=MemoryFlash())
                codes = " ".join(str(ord(c)) for c in axis.device)
                device.feed(f"18 {len(axis.device)} {codes}\n".encode("ascii"))
                device.take_output()
                world.add(device, key=key)
        text = read_gcode_text(program)
        with connect_session(config, world=world) as session:
            homing_s = session.home()
            if origin:
                session.set_work_origin(origin)
            prepared = session.prepare(program, text=text,
                                       dialect=dialect_named(dialect) if dialect else None)
            report, _ = session.run(prepared, homing_s=homing_s)
            session.shutdown()
        return VirtualRun(report.to_json(),
                          {name: d.lines_compared for name, d in emulated.items()},
                          {name: d.ticks for name, d in emulated.items()},
                          time.monotonic() - started)
    finally:
        for device in emulated.values():
            device.close()


@dataclass
class Served:
    """``usbmotion sim --pty 3`` running: device name -> terminal path; what it said on its
    standard error once stopped (the emulators' lag, if any)."""

    paths: dict[str, str]
    messages: str = ""


@contextlib.contextmanager
def served(flash_dir: Path, *, firmware: Path | None = None,
           record_dir: Path | None = None) -> Iterator[Served]:
    """The three devices served on pseudo-terminals by a ``usbmotion sim`` process."""
    command = [sys.executable, "-m", "usbmotion", "sim", "--pty", "3", "--flash-dir",
               str(flash_dir), *(arg for name in NAMES for arg in ("--name", name))]
    if firmware is not None:
        command += ["--firmware", str(firmware)]
        if record_dir is not None:
            command += ["--record", str(record_dir)]
    server = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                              text=True)
    result = Served({})
    try:
        assert server.stdout is not None
        for _ in NAMES:
            line = server.stdout.readline().rstrip("\n")
            assert " " in line, f"usbmotion sim printed {line!r}: {server.stderr.read()}"
            name, path = line.rsplit(" ", 1)
            result.paths[name] = path
        yield result
    finally:
        server.send_signal(signal.SIGTERM)
        try:
            _, result.messages = server.communicate(timeout=30)
        except subprocess.TimeoutExpired:
            server.kill()
            _, result.messages = server.communicate()


@dataclass
class RealtimeRun:
    """A job in real time: the exit status, the report, the wall time, the server's words."""

    code: int
    report: dict[str, Any]
    wall_s: float
    output: str
    server_messages: str


def realtime_report(folder: Path, *, firmware: Path | None,
                    record_dir: Path | None = None) -> RealtimeRun:
    """Serve the machine (emulated chips running ``firmware``, else Python devices) on
    pseudo-terminals and ``usbmotion run --machine`` demo 1 on it, in real time."""
    label = "firmware" if firmware is not None else "python"
    folder.mkdir(parents=True, exist_ok=True)
    with served(folder / f"flash-{label}", firmware=firmware, record_dir=record_dir) as sim:
        machine = folder / f"{label}.toml"
        machine.write_text(machine_text(sim.paths), encoding="utf-8")
        report_path = folder / f"{label}.json"
        started = time.monotonic()
        done = subprocess.run(
            [sys.executable, "-m", "usbmotion", "run", "--machine", str(machine), str(DEMO),
             "--no-plot", "--report", str(report_path), "-q"],
            capture_output=True, text=True, check=False, timeout=300)
        wall = time.monotonic() - started
    report = json.loads(report_path.read_text()) if report_path.exists() else {}
    return RealtimeRun(done.returncode, report, wall, done.stdout + done.stderr, sim.messages)


def differences(a: dict[str, Any], b: dict[str, Any], path: str = "") -> list[str]:
    """Every field where two reports differ, as ``path: a != b``."""
    out: list[str] = []
    for key in sorted(set(a) | set(b)):
        x, y = a.get(key), b.get(key)
        where = f"{path}.{key}" if path else key
        if isinstance(x, dict) and isinstance(y, dict):
            out += differences(x, y, where)
        elif (isinstance(x, list) and isinstance(y, list) and len(x) == len(y)
              and all(isinstance(v, dict) for v in (*x, *y))):
            for index, (p, q) in enumerate(zip(x, y, strict=True)):
                out += differences(p, q, f"{where}[{index}]")
        elif x != y:
            out.append(f"{where}: {x!r} != {y!r}")
    return out


def _row(label: str, report: dict[str, Any]) -> list[str]:
    cells = [label, f"{report.get('executed_time_s', 0):.3f}"]
    for axis in report.get("axes", []):
        cells.append(f"{axis['max_error_counts']}@{axis['max_error_time_s']:.3f} "
                     f"rms {axis['rms_error_counts']:.3f} fin {axis['final_error_counts']} "
                     f"t {axis['ticks']}")
    end = report.get("end_position_mm", {})
    cells.append(" ".join(f"{end[k]:.4f}" for k in sorted(end)))
    cells.append(str(len(report.get("faults", []))))
    return cells


def main(argv: Sequence[str]) -> None:
    """Print demo 1's figures: virtual time on both, then ``RUNS`` real-time runs of each."""
    import tempfile  # noqa: PLC0415

    runs = int(argv[0]) if argv else 2
    with tempfile.TemporaryDirectory() as name:
        folder = Path(name)
        config = virtual_config(folder)
        rows = [_row("virtual python", virtual_report(config, firmware=None).report)]
        fw = virtual_report(config, firmware=default_uf2())
        rows.append(_row(f"virtual firmware ({sum(fw.lines_compared.values())} lines "
                         f"compared, {fw.wall_s:.0f} s)", fw.report))
        for index in range(runs):
            for firmware in (None, default_uf2()):
                run = realtime_report(folder / f"run{index}", firmware=firmware)
                label = "firmware" if firmware else "python"
                lag = " LAG" if "fell behind" in run.server_messages else ""
                rows.append(_row(f"real time {label} #{index + 1}{lag} (exit {run.code})",
                                 run.report))
    header = ["run", "executed s", "X max@s rms final ticks", "Y", "Z", "end mm", "faults"]
    for row in [header, *rows]:
        print(" | ".join(row))


if __name__ == "__main__":
    main(sys.argv[1:])
