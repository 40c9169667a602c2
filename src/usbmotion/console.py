"""The serial console of seed 003 over a machine session: cycle start, reset, demo selection,
MDI, jogging and live control while the machine moves.

Commands are ``$`` and a letter, then values: ``$c`` runs the loaded program from where the
machine stands, ``$H`` homes it (grbl's spelling), ``$r`` stops the machine, clears any
alarm and homes it, ``$d N`` loads demo program N, ``$l FILE`` loads a G-code file, ``?``
reports the state, ``$h`` lists the commands, ``$q`` leaves. ``$z [AXES]`` sets the work
origin (G54) where the machine stands for the named axes (all by default), as a sender's
zero button does, and a line of G-code that sets offsets without moving (``G10 L20 P1 X0
Y0``, ``G10 L2 P2 X50``, ``G28.1``) is carried out at the machine's position; both keep the
offsets in the machine's parameter file. Every command answers with at least one line;
unknown input answers one ``error:`` line. A cycle start plans the program from where the
machine is, so two in a row run it twice from wherever the first ended.

The machine moves on a worker thread (:class:`~usbmotion.session.operator.Operator`), so
the console keeps reading while it moves: any other line of G-code is MDI, run at once
(``G0 X10``, ``G1 Y5 F300``, ``G91 G0 Z1``: the modal state lasts from line to line, and
lines written while the machine moves are streamed after what it is doing); ``!`` holds,
``~`` (or ``$c``) resumes a hold or a program pause (M0, M1, M6), Ctrl-X (0x18) or ``$x``
stops (every axis to rest along its deceleration, the rest dropped, the machine homed and
Idle); ``$j X10 Y-2 F600`` jogs by distances, ``$j X+ F600`` jogs continuously until
``$jx``, ``!``, Ctrl-X or the soft limit; the lines typed while a homing asked for here
runs (``$H``, ``$r``) wait for it to end, then run in order, as grbl holds the lines after
its ``$H`` (a stop or ``$r`` drops them, saying how many); ``$o F150`` and ``$o R50`` set
the feed and rapid overrides; ``?`` reports the state, the positions (machine and work),
the line and the overrides while a program runs.
"""

from __future__ import annotations

import re
import threading
import time
from collections import deque
from collections.abc import Callable, Mapping
from functools import partial
from pathlib import Path

from usbmotion.demos import DEMOS, demo_path
from usbmotion.errors import (
    ArgumentError,
    GCodeError,
    MachineStateError,
    PlanningError,
    StopRequestedError,
    UsbMotionError,
)
from usbmotion.motion.gcode import interpret_setting, parse_gcode, read_gcode_text
from usbmotion.motion.offsets import format_point
from usbmotion.session import MachineSession, MachineState, describe
from usbmotion.session.operator import Operator, parse_steps
from usbmotion.session.planning import machine_axes, machine_dialect, program_axes

_GCODE_LETTERS = frozenset("GMFTNXYZUVW")
"""The first letters of a line of G-code (MDI)."""
_SETTING = re.compile(r"\s*G\s*(10|92|28\.1|30\.1)\b", re.IGNORECASE)
"""A line that sets offsets without moving: carried out at the machine's position."""
MDI_WAIT_S = 5.0
"""How long an MDI line waits for room in the planner before it is refused."""

HELP = """\
$c        cycle start: run the loaded program from where the machine stands (or resume)
$c N      run the loaded program from line N (after a stop: the report names the line);
          the lines before it set the modes without moving, then up, over and down into it
G0 X10    MDI: any other G-code line runs at once (modal state kept between lines)
!  ~      feed hold; resume (cycle start) a hold or a pause (M0, M1, M6)
^X  $x    stop: every axis to rest along its deceleration, the rest dropped
$j X10 Y-2 F600   jog by distances (machine coordinates); $j X+ F600 jogs until $jx or ^X
$o F150   feed override 10..200 %; $o R50 rapid override 100, 50 or 25 %
$H        home every axis (grbl's $H; in Alarm, $r); what is typed meanwhile waits for it
$r        reset: stop every axis, clear any alarm, then home
$d N      load demo program N (1 rounded square, 2 star, 3 spiral)
$l FILE   load a G-code file
$z [AXES] zero: the work origin (G54) where the machine stands, for the named axes (default all)
$tls [N]  measure tool N (default: the one in the spindle) on the tool setter; its length
          goes into the tool table, where G43 reads it; at a program's M6 pause, $tls
          measures the new tool, then the program goes on from the next line
G10 ...   set offsets at the machine's position: G10 L20 P1 X0 Y0, G10 L2 P1 Z-5, G28.1
?         status: state, line, positions (machine and work), overrides, faults
$h        this help
$q        quit"""


def _is_mdi(text: str) -> bool:
    """Whether a console line is G-code run as MDI (not one that only sets offsets)."""
    return _SETTING.match(text) is None and text[:1].upper() in _GCODE_LETTERS


class Console:
    """Interpret console lines against a machine session.

    Parameters:
        session: the connected machine session.
        write: where replies go, one line per call.
    """

    def __init__(self, session: MachineSession, write: Callable[[str], None]) -> None:
        self.session = session
        self.write = write
        self.operator = Operator(session, on_message=write)
        self.path: Path | None = None
        self.text = ""
        self.last_result = ""
        self._held: deque[str] = deque()
        """Lines typed while a homing asked for here runs (or lines wait): carried out once
        it has ended, in order, as grbl holds the lines after its ``$H``."""
        self._homings = 0
        """Homings (``$H``, ``$r``) queued or running."""
        self._releasing: threading.Thread | None = None
        """Sends the held lines (until they are all taken)."""
        self._held_lock = threading.Lock()

    def close(self) -> None:
        """Wait for what runs (and for the lines held for a homing), then end the worker."""
        self.wait_idle()
        self.operator.close()

    def wait_idle(self, timeout_s: float | None = None) -> bool:
        """Wait until what the lines handed in started has ended: the worker's actions and
        the lines held for a homing; False when ``timeout_s`` passed first."""
        deadline = None if timeout_s is None else time.monotonic() + timeout_s

        def left() -> float | None:
            return None if deadline is None else max(0.0, deadline - time.monotonic())

        while True:
            if not self.operator.wait_idle(left()):
                return False
            releasing = self._releasing
            if releasing is None:
                if not self.operator.busy:
                    return True
                continue
            releasing.join(left())
            if releasing.is_alive():
                return False

    def handle(self, line: str) -> bool:
        """Carry out one line; returns False when the console should end."""
        text = line.strip()
        if not text:
            return True
        if self._live(text) or self._hold(text):
            return True
        return self._handle(text)

    def _hold(self, text: str) -> bool:
        """Hold ``text`` for after a homing asked for here (True), if one is queued or runs
        or lines wait already: what was typed after ``$H`` runs after it, in order. The
        help, ``$q`` and ``$r`` (which drops what waits) act at once."""
        if text in ("$h", "$?", "$q", "$r"):
            return False
        with self._held_lock:
            if self._homings or self._held or self._releasing is not None:
                self._held.append(text)
                return True
        return False

    def _handle(self, text: str) -> bool:
        command, _, value = text.partition(" ")
        value = value.strip()
        machine: Callable[[], None] | None = None
        if command == "?":
            machine = self._status
        elif command in ("$h", "$?"):
            self.write(HELP)
        elif command == "$q":
            self.write("bye")
            return False
        elif command == "$c" and not value:
            machine = self._cycle_start
        elif command == "$c":
            if not value.isdigit() or int(value) < 1:
                self.write(f"error: $c {value}: a line number, 1 or more ($c 120 runs the"
                           " loaded program from line 120)")
                return True
            machine = partial(self._cycle_start, int(value))
        elif command == "$H" and not value:
            machine = self._homing_then(self._home)
        elif command == "$r" and not value:
            self._drop_held()  # a reset drops what waits, as a stop does
            machine = self._homing_then(self._reset)
        elif command == "$d":
            self._guarded(lambda: self._load_demo(value))
        elif command == "$l":
            self._guarded(lambda: self._load_file(value))
        elif command == "$z":
            machine = partial(self._zero, value)
        elif command == "$j":
            machine = self._jog_action(value)
        elif command == "$tls":
            if value and not value.isdigit():
                self.write(f"error: $tls {value}: a tool number ($tls 3), or nothing for the"
                           " tool in the spindle")
                return True
            if self.session.held:
                self._measure_at_pause(value)
                return True
            machine = partial(self._measure_tool, int(value) if value else None)
        elif _SETTING.match(text):
            machine = partial(self._set_offsets, text)
        elif _is_mdi(text):
            self._mdi(text)
        else:
            self.write(f"error: unknown command {text!r}; $h lists the commands")
        if machine is not None:
            action = machine
            self.operator.do(lambda: self._guarded(action))
        return True

    def _guarded(self, action: Callable[[], None]) -> None:
        """Carry out ``action``, its errors written as one line each."""
        try:
            action()
        except StopRequestedError as error:
            self.write(f"stopped: {error.reason}; every axis at rest")
        except (GCodeError, PlanningError) as error:
            self.write(f"error: {error}")
        except UsbMotionError as error:
            self.write(f"error: {error}")

    def _live(self, text: str) -> bool:
        """The commands that act at once, even while the machine moves: True when ``text``
        was one."""
        operator = self.operator
        if text in ("!", "$jx") or text.startswith("!"):
            if self.session.jogging:
                operator.jog_cancel()
                self.write("jog cancelled")
            elif text == "$jx":
                self.write("error: no jog runs")
            else:
                operator.hold()
                self.write("hold: decelerating to rest along the path; ~ resumes")
            return True
        if text == "~" or (text == "$c" and self.session.hold_requested):
            if self.session.hold_requested:
                operator.resume()
                self.write("resume")
            else:
                self.write("error: nothing to resume (no hold, no pause)")
            return True
        if text in ("\x18", "$x"):
            if not self.stop():
                self.write("stop: nothing moves")
            return True
        if text == "?" and operator.busy:
            self._live_status()
            return True
        if text.startswith("$o"):
            self._override(text[2:].strip())
            return True
        return False

    def _live_status(self) -> None:
        """The machine now, from the session's live model: the state, the line the devices
        execute, the encoders' machine and work positions, the feed they move at, the
        overrides, each axis's following error and the spindle's measured speed."""
        now = self.session.live.read()
        axes = program_axes(self.session.config)
        machine = now.machine_mm()
        work = now.work_mm()
        state = now.state.value
        if now.state is MachineState.HOLD:
            state += "" if now.at_rest else " (decelerating)"
        line = f"line {now.line}" + (f" of {now.lines_total}" if now.lines_total else "")
        error = "  ".join(f"{a} {now.axes[a].following_error_mm:+.3f}" for a in axes)
        self.write(
            f"state: {state}; {line}; machine "
            + "  ".join(f"{a} {machine[a]:.3f}" for a in axes) + " mm; work "
            + "  ".join(f"{a} {work[a]:.3f}" for a in axes)
            + f" mm; feed {now.feed_mm_min:.0f} mm/min; overrides feed {now.feed_override} %,"
            f" rapid {now.rapid_override} %; following error {error} mm"
            + (f"; {now.done_s:.1f} of {now.total_s:.1f} s, {now.eta_s:.1f} s left"
               if now.total_s and not now.at_rest else "")
            + (f"; paused: {now.pause}" if now.pause else "")
            + (f"; spindle {abs(now.spindle.measured_rpm):.0f} rpm"
               + (" counter-clockwise" if now.spindle.commanded_rpm < 0 else "")
               + ("" if now.spindle.at_speed
                  else f" (to {abs(now.spindle.commanded_rpm):.0f} rpm)")
               if now.spindle is not None else "")
            + _outputs_text(now.outputs))

    def _measure_at_pause(self, value: str) -> None:
        """``$tls`` while a program waits at rest: at its M6 pause, the run ends there and
        :meth:`_cycle_start` measures the new tool and runs the program on."""
        session = self.session
        pause = session.paused
        if value or pause is None or pause.code != "M6":
            self.write("error: $tls measures while the machine is idle, or the new tool at"
                       " a program's M6 pause (as $tls alone); it waits at "
                       + (f"an {pause.code} pause" if pause is not None else "a hold")
                       + " now: ~ resumes, $x stops")
            return
        try:
            asked = session.request_tool_measure()
        except UsbMotionError as error:
            self.write(f"error: {error}")
            return
        self.write(f"measuring T{asked.tool} on the tool setter; the program then goes on"
                   f" from line {asked.from_line}")

    def _measure_tool(self, tool: int | None) -> None:
        self.write(self.session.measure_tool(tool).describe())
        self.operator.measured_tool()

    def _override(self, value: str) -> None:
        kind, number = value[:1].upper(), value[1:].strip()
        try:
            percent = int(number)
        except ValueError:
            self.write(f"error: $o takes F10..F200 or R25/R50/R100, got {value!r}")
            return
        try:
            if kind == "F":
                self.session.set_feed_override(percent)
            elif kind == "R":
                self.session.set_rapid_override(percent)
            else:
                self.write(f"error: $o takes F10..F200 or R25/R50/R100, got {value!r}")
                return
        except ArgumentError as error:
            self.write(f"error: {error}")
            return
        self.write(f"override: feed {self.session.feed_override_percent} %, rapid"
                   f" {self.session.rapid_override_percent} %")

    def _mdi(self, text: str) -> None:
        """A G-code line, run at once (streamed after what runs)."""
        operator = self.operator
        deadline = time.monotonic() + MDI_WAIT_S
        while True:
            try:
                taken = operator.submit(text)
            except (GCodeError, PlanningError, MachineStateError) as error:
                session = self.session
                hint = ("; $H homes it" if not session.is_homed
                        and session.state is not MachineState.HOMING else "")
                self.write(f"error: {error}{hint}")
                return
            if taken:
                self.write("ok")
                return
            if time.monotonic() > deadline:
                self.write("error: the planner is full; try again")
                return
            time.sleep(0.01)

    def _jog_action(self, value: str) -> Callable[[], None] | None:
        """The jog ``$j`` asks for, to run on the machine (None: the words are wrong, said)."""
        words = value.upper().split()
        feed = [w for w in words if w.startswith("F")]
        steps = [w for w in words if not w.startswith("F")]
        if len(feed) != 1 or not steps:
            self.write("error: $j takes AXIS DISTANCE pairs (or AXIS+ / AXIS-) and one F"
                       " feed: $j X10 Y-2 F600, $j X+ F600")
            return None
        try:
            feed_mm_min = float(feed[0][1:])
        except ValueError:
            self.write(f"error: $j feed {feed[0]!r} is not a number")
            return None
        continuous = all(len(w) == 2 and w[1] in "+-" for w in steps)
        try:
            if continuous:
                moves = {w[0]: 1.0 if w[1] == "+" else -1.0 for w in steps}
            else:
                moves = parse_steps(steps)
        except ValueError as error:
            self.write(f"error: $j {error}")
            return None

        def go() -> None:

            report = self.session.jog(moves, feed_mm_min=feed_mm_min, continuous=continuous)
            where = "  ".join(f"{k} {v:.3f}" for k, v in self.session.positions_mm().items())
            self.write(("jogged" if report.completed else report.stop_reason) + f": {where} mm")

        return go

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

    def _cycle_start(self, from_line: int | None = None) -> None:
        session = self.session
        if self.path is None:
            self.write("error: no program loaded; $d N loads a demo, $l FILE a file")
            return
        if session.state is MachineState.ALARM:
            self.write("error: the machine is in Alarm; $r resets and homes it")
            return
        prepared = session.prepare(self.path, text=self.text, pauses=session.pause_rule(),
                                   from_line=from_line)
        homing_s = 0.0
        if not session.is_homed:
            self.write("homing first: the machine is not homed")
            homing_s = session.home()
            prepared = session.prepare(self.path, text=self.text, pauses=session.pause_rule(),
                                       from_line=from_line)
        start = "  ".join(f"{a} {v:.3f}" for a, v in zip(prepared.axes, prepared.start_mm,
                                                          strict=True))
        joined = "" if from_line is None else f", joining it at line {from_line}"
        self.write(f"cycle start: {self.path} from {start} mm{joined},"
                   f" {prepared.plan.duration_s:.2f} s")

        report, _ = session.run(prepared, homing_s=homing_s)
        self.last_result = report.stop_reason
        asked = session.measure_asked(report)
        if asked is not None:
            try:
                self._measure_tool(asked.tool)
            except UsbMotionError as error:
                self.write(f"error: measuring T{asked.tool}: {error}")
                self.write(f"the program stopped at its tool change (line {asked.line}):"
                           f" $tls measures the tool, then $c {asked.from_line} runs the"
                           " program on")
                return
            self._go_on_after_change(asked.from_line)
            return
        for line in describe(report).splitlines():
            self.write(line)
        self.write("done" if report.completed else f"stopped ({report.stop_reason}):"
                   " $r resets and homes")

    def _go_on_after_change(self, from_line: int) -> None:
        """The program on from the line after a tool change whose tool was measured."""
        try:
            self._cycle_start(from_line)
        except ArgumentError as error:
            if error.reason != "from_line":
                raise
            self.write(f"done: nothing of the program moves after the tool change ({error})")

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
                       " $H homes it")
            return
        where = session.positions_mm()
        offsets = session.set_work_origin({name: where[name] for name in names})
        self.write(f"G54 origin {format_point(offsets.g5x[0], axes)} mm (machine), saved in"
                   f" {session.config.parameter_path}")

    def _set_offsets(self, text: str) -> None:
        session = self.session
        if not session.is_homed:
            self.write("error: the machine is not homed, so its position means nothing;"
                       " $H homes it")
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

    def _homing_then(self, homing: Callable[[], None]) -> Callable[[], None]:
        """``homing`` for the worker, the lines typed meanwhile held until it ends."""
        with self._held_lock:
            self._homings += 1

        def then() -> None:
            try:
                homing()
            finally:
                with self._held_lock:
                    self._homings -= 1
                    if self._held and not self._homings and self._releasing is None:
                        self._releasing = threading.Thread(
                            target=self._release_held, name="usbmotion-console-held",
                            daemon=True)
                        self._releasing.start()

        return then

    def _release_held(self) -> None:
        """Carry out the held lines in order, each as if typed now (until one is a homing:
        the lines after it wait for its end in turn)."""
        after_action = False
        while True:
            with self._held_lock:
                if not self._held or self._homings:
                    self._releasing = None
                    return
                line = self._held.popleft()
            mdi = _is_mdi(line)
            if mdi and after_action:
                self.operator.wait_idle()  # a line would join a run queued before the action
            self._handle(line)
            after_action = not mdi

    def stop(self) -> bool:
        """Stop as Ctrl-X does: what waits for a homing dropped, then every axis to rest
        along its deceleration; False when nothing moved nor waited."""
        dropped = self._drop_held()
        if not self.operator.busy:
            return dropped > 0
        self.operator.stop()
        self.write("stop: every axis to rest along its deceleration")
        return True

    def _drop_held(self) -> int:
        """A stop drops the lines held for a homing, saying how many; returns how many."""
        with self._held_lock:
            dropped = len(self._held)
            self._held.clear()
        if dropped:
            self.write(f"dropped {dropped} line{'s' if dropped > 1 else ''} held for the homing")
        return dropped

    def _reset(self) -> None:
        self.write("reset: stopping every axis")
        self.session.reset()
        self._homed()

    def _home(self) -> None:
        if self.session.state is MachineState.ALARM:
            self.write("error: the machine is in Alarm; $r resets and homes it")
            return
        self._homed()

    def _homed(self) -> None:
        """Home every axis and say where they are."""
        session = self.session
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
            axis = session.machine.axis(name)
            self.write(
                f"{name}: {axis.scale.to_mm(status.actual_counts):9.3f}"
                f" {'deg' if axis.config.rotary else 'mm'}"
                f"  {'enabled' if status.enabled else 'disabled'}  mode {int(status.mode)}"
                f"  queued {status.queued}  limits {'L' if status.lower_limit else '-'}"
                f"{'U' if status.upper_limit else '-'}  fault {status.fault_name}"
            )
        live = session.read_live()
        if live.outputs or live.probe:
            self.write(("outputs:" + _outputs_text(live.outputs)[1:] if live.outputs
                        else "outputs: none") + ("; probe touching" if live.probe else ""))
        spindle = session.machine.spindle
        if spindle is not None:
            now = spindle.read()
            turn = " counter-clockwise" if now.commanded_rpm < 0 else ""
            self.write(f"spindle: {abs(now.measured_rpm):.0f} rpm{turn} measured,"
                       f" {abs(now.commanded_rpm):.0f} rpm commanded"
                       + ("" if now.at_speed else " (ramping)"))


def _outputs_text(outputs: Mapping[str, int]) -> str:
    """``; flood on, mist off, laser 80 %`` ("" without outputs)."""
    if not outputs:
        return ""
    return "; " + ", ".join(f"laser {value / 10:g} %" if name == "laser"
                            else f"{name} {'on' if value else 'off'}"
                            for name, value in outputs.items())
