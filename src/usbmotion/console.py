"""The serial console of seed 003 over a machine: cycle start, reset, demo selection.

Commands are ``$`` and a letter, then values: ``$c`` runs the loaded program, ``$r`` stops
the machine and homes it, ``$d N`` loads demo program N, ``$l FILE`` loads a G-code file,
``?`` reports the state, ``$h`` lists the commands, ``$q`` leaves. Every command answers
with at least one line; unknown input answers one ``error:`` line.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from usbmotion.demos import DEMOS, demo_path
from usbmotion.errors import GCodeError, OutOfRangeError, PlanningError, UsbMotionError
from usbmotion.host.machine import Machine
from usbmotion.job import describe, home_machine, plan_program, run_program
from usbmotion.motion.gcode import GCodeProgram, load_gcode
from usbmotion.motion.planner import Plan

HELP = """\
$c        cycle start: run the loaded program
$r        reset: stop every axis, then home
$d N      load demo program N (1 rounded square, 2 star, 3 spiral)
$l FILE   load a G-code file
?         status: loaded program, homed, positions, faults
$h        this help
$q        quit"""


class Console:
    """Interpret console lines against a connected machine.

    Parameters:
        machine: the connected machine (configured on first use).
        write: where replies go, one line per call.
    """

    def __init__(self, machine: Machine, write: Callable[[str], None]) -> None:
        self.machine = machine
        self.write = write
        self.program: GCodeProgram | None = None
        self.plan: Plan | None = None
        self.homed = False
        self.configured = False
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
            else:
                self.write(f"error: unknown command {text!r}; $h lists the commands")
        except (GCodeError, PlanningError) as error:
            self.write(f"error: {error}")
        except UsbMotionError as error:
            self.write(f"error: {error}")
        return True

    def _configure(self) -> None:
        if not self.configured:
            self.machine.configure()
            self.configured = True

    def _load(self, path: Path) -> None:
        program = load_gcode(path)
        plan = plan_program(program, self.machine.config)
        self.program, self.plan = program, plan
        self.write(f"loaded {path.name}: {len(program.moves)} moves, {plan.duration_s:.2f} s")

    def _load_demo(self, value: str) -> None:
        try:
            number = int(value)
        except ValueError:
            self.write(f"error: $d takes a demo number 1..{len(DEMOS)}, got {value!r}")
            return
        try:
            path = demo_path(number)
        except OutOfRangeError as error:
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
        if self.program is None or self.plan is None:
            self.write("error: no program loaded; $d N loads a demo, $l FILE a file")
            return
        self._configure()
        self.write(f"cycle start: {self.program.file}")
        report, _ = run_program(self.machine, self.program, self.plan, home=not self.homed,
                                configure=False)
        self.homed = report.completed
        self.last_result = "completed" if report.completed else "stopped"
        for line in describe(report).splitlines():
            self.write(line)
        self.write("done" if report.completed else "stopped: $r resets and homes")

    def _reset(self) -> None:
        self._configure()
        self.write("reset: stopping every axis")
        self.machine.stop()
        self.machine.clear_faults()
        seconds = home_machine(self.machine)
        self.homed = True
        positions = "  ".join(f"{k} {v:.3f}" for k, v in self.machine.positions_mm().items())
        self.write(f"homed in {seconds:.2f} s: {positions} mm")

    def _status(self) -> None:
        loaded = Path(self.program.file).name if self.program is not None else "none"
        self.write(f"program: {loaded}; homed: {'yes' if self.homed else 'no'};"
                   f" last run: {self.last_result or 'none'}")
        for name, status in self.machine.status().items():
            scale = self.machine.axis(name).scale
            self.write(
                f"{name}: {scale.to_mm(status.actual_counts):9.3f} mm"
                f"  {'enabled' if status.enabled else 'disabled'}  mode {int(status.mode)}"
                f"  queued {status.queued}  limits {'L' if status.lower_limit else '-'}"
                f"{'U' if status.upper_limit else '-'}  fault {status.fault_name}"
            )
