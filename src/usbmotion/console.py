"""The serial console of seed 003 over a machine session: cycle start, reset, demo selection.

Commands are ``$`` and a letter, then values: ``$c`` runs the loaded program from where the
machine stands, ``$r`` stops the machine, clears any alarm and homes it, ``$d N`` loads demo
program N, ``$l FILE`` loads a G-code file, ``?`` reports the state, ``$h`` lists the
commands, ``$q`` leaves. ``$z [AXES]`` sets the work origin (G54) where the machine stands
for the named axes (all by default), as a sender's zero button does, and a line of G-code
that sets offsets without moving (``G10 L20 P1 X0 Y0``, ``G10 L2 P2 X50``, ``G28.1``) is
carried out at the machine's position; both keep the offsets in the machine's parameter
file. Every command answers with at least one line; unknown input answers one ``error:``
line. A cycle start plans the program from where the machine is, so
two in a row run it twice from wherever the first ended.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from usbmotion.demos import DEMOS, demo_path
from usbmotion.errors import (
    ArgumentError,
    GCodeError,
    PlanningError,
    StopRequestedError,
    UsbMotionError,
)
from usbmotion.motion.gcode import interpret_setting, parse_gcode, read_gcode_text
from usbmotion.motion.offsets import format_point
from usbmotion.session import MachineSession, MachineState, describe
from usbmotion.session.planning import machine_axes, machine_dialect, program_axes

HELP = """\
$c        cycle start: run the loaded program from where the machine stands
$r        reset: stop every axis, clear any alarm, then home
$d N      load demo program N (1 rounded square, 2 star, 3 spiral)
$l FILE   load a G-code file
$z [AXES] zero: the work origin (G54) where the machine stands, for the named axes (default all)
G10 ...   set offsets at the machine's position: G10 L20 P1 X0 Y0, G10 L2 P1 Z-5, G28.1
?         status: state, loaded program, homed, positions, faults
$h        this help
$q        quit"""


class Console:
    """Interpret console lines against a machine session.

    Parameters:
        session: the connected machine session.
        write: where replies go, one line per call.
    """

    def __init__(self, session: MachineSession, write: Callable[[str], None]) -> None:
        self.session = session
        self.write = write
        self.path: Path | None = None
        self.text = ""
        self.last_result = ""

    def handle(self, line: str) -> bool:
        """Carry out one line; returns False when the console should end."""
        text = line.strip()
        if not text:
            return True
        command, _, value = text.partition(" ")
        value = value.strip()
        try:
            if command == "?":
                self._status()
            elif command in ("$h", "$?"):
                self.write(HELP)
            elif command == "$q":
                self.write("bye")
                return False
            elif command == "$c" and not value:
                self._cycle_start()
            elif command == "$r" and not value:
                self._reset()
            elif command == "$d":
                self._load_demo(value)
            elif command == "$l":
                self._load_file(value)
            elif command == "$z":
                self._zero(value)
            elif text[:1] in "Gg":
                self._set_offsets(text)
            else:
                self.write(f"error: unknown command {text!r}; $h lists the commands")
        except StopRequestedError as error:
            self.write(f"stopped: {error.reason}; every axis at rest")
        except (GCodeError, PlanningError) as error:
            self.write(f"error: {error}")
        except UsbMotionError as error:
            self.write(f"error: {error}")
        finally:
            self.session.clear_stop_request()
        return True

    def _load(self, path: Path) -> None:
        text = read_gcode_text(path)
        config = self.session.config
        program = parse_gcode(text, file=str(path), machine=machine_axes(config),
                              dialect=machine_dialect(config))
        self.path, self.text = path, text
        self.write(f"loaded {path.name}: {len(program.moves)} moves")

    def _load_demo(self, value: str) -> None:
        try:
            number = int(value)
        except ValueError:
            self.write(f"error: $d takes a demo number 1..{len(DEMOS)}, got {value!r}")
            return
        try:
            path = demo_path(number)
        except ArgumentError as error:
            self.write(f"error: {error}")
            return
        self._load(path)

    def _load_file(self, value: str) -> None:
        if not value:
            self.write("error: $l takes a file name")
            return
        try:
            self._load(Path(value))
        except OSError as error:
            self.write(f"error: cannot read {value!r}: {error.strerror or error}")

    def _cycle_start(self) -> None:
        session = self.session
        if self.path is None:
            self.write("error: no program loaded; $d N loads a demo, $l FILE a file")
            return
        if session.state is MachineState.ALARM:
            self.write("error: the machine is in Alarm; $r resets and homes it")
            return
        prepared = session.prepare(self.path, text=self.text)
        homing_s = 0.0
        if not session.is_homed:
            self.write("homing first: the machine is not homed")
            homing_s = session.home()
            prepared = session.prepare(self.path, text=self.text)
        start = "  ".join(f"{a} {v:.3f}" for a, v in zip(prepared.axes, prepared.start_mm,
                                                          strict=True))
        self.write(f"cycle start: {self.path} from {start} mm, {prepared.plan.duration_s:.2f} s")
        report, _ = session.run(prepared, homing_s=homing_s)
        self.last_result = report.stop_reason
        for line in describe(report).splitlines():
            self.write(line)
        self.write("done" if report.completed else f"stopped ({report.stop_reason}):"
                   " $r resets and homes")

    def _zero(self, value: str) -> None:
        session = self.session
        axes = program_axes(session.config)
        names = value.upper().split() or list(axes)
        bad = [name for name in names if name not in axes]
        if bad:
            self.write(f"error: $z takes axes {', '.join(axes)}; got {' '.join(bad)!r}")
            return
        if not session.is_homed:
            self.write("error: the machine is not homed, so its position means nothing;"
                       " $r homes it")
            return
        where = session.positions_mm()
        offsets = session.set_work_origin({name: where[name] for name in names})
        self.write(f"G54 origin {format_point(offsets.g5x[0], axes)} mm (machine), saved in"
                   f" {session.config.parameter_path}")

    def _set_offsets(self, text: str) -> None:
        session = self.session
        if not session.is_homed:
            self.write("error: the machine is not homed, so its position means nothing;"
                       " $r homes it")
            return
        where = session.positions_mm()
        machine = machine_axes(session.config)
        offsets = interpret_setting(text, start=tuple(where[a] for a in machine.axes),
                                    machine=machine, dialect=machine_dialect(session.config),
                                    tools=session.tool_table(),
                                    offsets=session.work_offsets())
        session.save_work_offsets(offsets)
        system = offsets.coordinate_system
        self.write(f"G{53 + system if system <= 6 else f'59.{system - 6}'} is active; G54"
                   f" origin {format_point(offsets.g5x[0], machine.axes)} mm (machine), saved in"
                   f" {session.config.parameter_path}")

    def _reset(self) -> None:
        session = self.session
        self.write("reset: stopping every axis")
        session.reset()
        seconds = session.home()
        positions = "  ".join(f"{k} {v:.3f}" for k, v in session.positions_mm().items())
        self.write(f"homed in {seconds:.2f} s: {positions} mm")

    def _status(self) -> None:
        session = self.session
        loaded = self.path.name if self.path is not None else "none"
        homed = "yes" if session.is_homed else "no"
        self.write(f"state: {session.state.value}; program: {loaded}; homed: {homed};"
                   f" last run: {self.last_result or 'none'}")
        for name, status in session.machine.status().items():
            scale = session.machine.axis(name).scale
            self.write(
                f"{name}: {scale.to_mm(status.actual_counts):9.3f} mm"
                f"  {'enabled' if status.enabled else 'disabled'}  mode {int(status.mode)}"
                f"  queued {status.queued}  limits {'L' if status.lower_limit else '-'}"
                f"{'U' if status.upper_limit else '-'}  fault {status.fault_name}"
            )
