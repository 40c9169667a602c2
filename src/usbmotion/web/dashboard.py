"""What the dashboard's page can ask of one machine session, free of any web framework.

A :class:`Dashboard` wraps the session's :class:`~usbmotion.session.operator.Operator`: the
worker thread alone talks to the devices (homing, runs, jogs, MDI, reading parameters), the
calls here check their input, queue the work and return; what they started is seen in the
live model (:meth:`Dashboard.state`) and in the messages. A call that cannot be taken raises
:class:`RefusedError` with the HTTP status it answers (400 bad input, 404 nothing there, 409 not
now, 413 too large, 422 a prediction that cannot be made) and a message that names the value
and what is allowed.

The open program is kept with its plan from where the machine stands: its toolpath (the
planned vertices, machine coordinates) is what the page draws, and its ``revision`` changes
whenever it is planned again (opened, a run's start, a work offset changed).

A prediction (``usbmotion run --predict``'s) plays the open program on the identified
models of the axes before anything moves. The simulator that makes it is not this
package's to import: whoever builds the dashboard hands it a :class:`Predictor`. The last
prediction is kept, and a run of the same program text from the same line carries it into
its report, predicted beside measured.
"""

from __future__ import annotations

import math
import threading
import time
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path, PurePosixPath, PureWindowsPath
from typing import Any, Protocol, TypeVar

from usbmotion.autotune.identify import Identification, identify_axis
from usbmotion.autotune.machine_file import write_tuning_file
from usbmotion.autotune.verify import (
    Placement,
    check_on_axis,
    place_loop,
    predicted_versus_measured,
)
from usbmotion.demos import DEMOS, demo_path
from usbmotion.errors import (
    ArgumentError,
    ConfigError,
    GCodeError,
    MachineStateError,
    OutOfRangeError,
    PlanningError,
    UsbMotionError,
)
from usbmotion.host.config import UrlChecks, builtin_machine_file, load_config
from usbmotion.host.parameters import PARAMETERS, Storage, machine_file_problem, parameter
from usbmotion.motion.gcode import parse_gcode
from usbmotion.motion.moves import ROTARY_AXES
from usbmotion.motion.planner import SegmentKind
from usbmotion.session.jog import check_jog
from usbmotion.session.live import LiveReader, LiveSnapshot
from usbmotion.session.operator import IdleReader, Operator
from usbmotion.session.planning import Prepared, machine_axes, machine_dialect, program_axes
from usbmotion.session.report import RunReport
from usbmotion.session.report_text import describe, lines_over
from usbmotion.session.state import MachineState
from usbmotion.session.tool_setter import ToolMeasurement
from usbmotion.tuning import StepResponse, step_response

UPLOAD_LIMIT_BYTES = 8 * 1024 * 1024
"""The largest program an upload may carry."""
PROGRAM_SUFFIXES = (".ngc", ".nc", ".gcode", ".gc", ".g", ".tap", ".cnc", ".txt")
"""The file names a G-code program may have (an upload or a file of the programs folder)."""
MESSAGES_KEPT = 200
"""How many messages a client that connects late still gets."""
MDI_WAIT_S = 5.0
"""How long an MDI line waits for room in the planner before it is refused."""
CALL_TIMEOUT_S = 30.0
"""How long a call waits for the worker to do what it asked (planning, reading devices)."""
MAX_SYSTEM = 9
"""G54 (1) .. G59.3 (9)."""

T = TypeVar("T")


class RefusedError(Exception):
    """A call the dashboard did not take: ``status`` is the HTTP status it answers."""

    def __init__(self, status: int, message: str) -> None:
        super().__init__(message)
        self.status = status
        self.message = message


def _bad(message: str) -> RefusedError:
    return RefusedError(400, message)


def _not_now(message: str) -> RefusedError:
    return RefusedError(409, message)


def _finite(value: float) -> float | None:
    """``value``, or None for NaN or an infinity (JSON has neither)."""
    return value if math.isfinite(value) else None


@dataclass(slots=True)
class Message:
    """One line for the operator: what a call or the worker said."""

    sequence: int
    level: str
    """``info`` or ``error``."""
    text: str


@dataclass(slots=True)
class OpenProgram:
    """The program the page has open, and its plan from where the machine stands."""

    name: str
    text: str
    revision: int
    toolpath: dict[str, Any] | None = None
    duration_s: float = 0.0
    warnings: tuple[str, ...] = ()
    problem: str = ""
    """Why it cannot run from where the machine stands ("" when it can)."""
    lines: list[str] = field(default_factory=list)
    end_line: int = 0
    """The line the program ends on (M2, M30, '%'): its lines to run."""


@dataclass(frozen=True, slots=True)
class Predicted:
    """A program played on the axes' identified models before anything moves.

    Fields:
        report: the predicted run's report (its ``axes`` each axis's predicted peak and
            RMS following error, its ``line_peaks`` each program line's predicted peak).
        motors: axis -> where its motor came from (its model table, or its sim table).
        wall_s: how long the prediction took, s.
    """

    report: RunReport
    motors: Mapping[str, str]
    wall_s: float


class Predictor(Protocol):
    """What makes a prediction: ``usbmotion.sim.predict.predict`` bound to the machine.

    Raises:
        ConfigError: an axis has no model to predict with; GCodeError, PlanningError
            (SoftLimitError): as the program's planning.
    """

    def __call__(self, name: str, text: str, *, from_line: int | None,
                 standing_mm: Mapping[str, float] | None) -> Predicted:
        """Play program ``name`` (``text``) from ``from_line`` (None: the whole program)
        with the machine standing at ``standing_mm`` (None: where homing leaves it)."""
        ...


@dataclass(frozen=True, slots=True)
class KeptPrediction:
    """The last prediction of the open program, and what it was made of."""

    name: str
    text: str
    from_line: int | None
    standing_mm: Mapping[str, float] | None
    """Where the machine stood (None: not homed, so from where homing leaves it)."""
    predicted: Predicted


def system_name(system: int) -> str:
    """``1`` -> ``G54`` .. ``6`` -> ``G59``, ``7`` -> ``G59.1`` .. ``9`` -> ``G59.3``."""
    return f"G{53 + system}" if system <= 6 else f"G59.{system - 6}"


def program_name_problem(name: str) -> str | None:
    """Why ``name`` cannot name an uploaded or opened program, or None."""
    if not name:
        return "give the program's file name (name=FILE.ngc)"
    if any(part in name for part in ("/", "\\")) or name in (".", "..") or (
            PurePosixPath(name).name != name or PureWindowsPath(name).name != name):
        return f"program name {name!r} has a path in it: give the file name alone"
    if any(ord(char) < 32 for char in name):
        return f"program name {name!r} has control characters in it"
    if not name.lower().endswith(PROGRAM_SUFFIXES):
        return (f"program name {name!r} is not a G-code file: allowed names end in"
                f" {', '.join(PROGRAM_SUFFIXES)}")
    return None


def _toolpath(prepared: Prepared) -> dict[str, Any]:
    plan = prepared.plan
    return {
        "axes": plan.axes,
        "points": [[round(float(v), 4) for v in row] for row in plan.vertices_mm],
        "line": [int(line) for line in plan.line],
        "rapid": [bool(kind == SegmentKind.RAPID) for kind in plan.kind],
    }


class Dashboard:
    """The page's view of one machine session (see the module docstring).

    Parameters:
        operator: the session's operator (its worker runs the motion).
        programs: a folder whose G-code files the page may open (None: uploads only).
        machine_name: what the page calls the machine.
        url_checks: the machine file's URL checks (a changed parameter is checked as the
            file is).
        predictor: what plays a program on the axes' models (None: the dashboard cannot
            predict, ``POST /api/predict`` is refused).
    """

    def __init__(self, operator: Operator, *, programs: Path | None = None,
                 machine_name: str = "", url_checks: UrlChecks | None = None,
                 predictor: Predictor | None = None) -> None:
        self.operator = operator
        self.session = operator.session
        self.config = self.session.config
        self.axes = program_axes(self.config)
        self.wrapped = "".join(a.name for a in self.config.axes if a.wrapped)
        self.programs = programs
        self.url_checks = url_checks
        """The machine file's URL checks (a changed parameter is checked as the file is)."""
        self.machine_name = machine_name or self.config.name
        self.predictor = predictor
        self.program: OpenProgram | None = None
        self.prediction: KeptPrediction | None = None
        """The last prediction made (of the program then open)."""
        self._predicting = threading.Lock()
        self._run_prediction: tuple[RunReport, KeptPrediction] | None = None
        """The last run's report and the prediction of what it ran, when there was one."""
        self._revision = 0
        self._lock = threading.Lock()
        self._messages: deque[Message] = deque(maxlen=MESSAGES_KEPT)
        self._message_sequence = 0
        operator.on_message = self._worker_message
        self._reading = IdleReader(operator, name="usbmotion-web-read", on_error=lambda error:
                                   self.message(f"the machine cannot be read: {error}",
                                                level="error"))

    # --- the machine at rest ----------------------------------------------------------------

    def start(self) -> None:
        """Read the machine while it is idle (:class:`IdleReader`)."""
        self._reading.start()

    def close(self) -> None:
        """Stop reading the machine (the operator is the caller's to close)."""
        self._reading.close()

    # --- messages ---------------------------------------------------------------------------

    def message(self, text: str, *, level: str = "info") -> None:
        """A line for every page (and for a page that connects later)."""
        with self._lock:
            self._message_sequence += 1
            self._messages.append(Message(self._message_sequence, level, text))

    def _worker_message(self, text: str) -> None:
        failed = text.startswith("error") or (
            text.startswith("stopped") and "jog cancelled" not in text)
        self.message(text, level="error" if failed else "info")

    def messages(self, after: int = 0) -> list[Message]:
        """The messages kept whose sequence number is after ``after``."""
        with self._lock:
            return [m for m in self._messages if m.sequence > after]

    @property
    def message_sequence(self) -> int:
        """The sequence number of the last message."""
        return self._message_sequence

    # --- reading ----------------------------------------------------------------------------

    def reader(self) -> LiveReader:
        """A reader of the live model whose peaks are its own (one per client)."""
        return self.session.live.reader()

    def state(self, reader: LiveReader) -> dict[str, Any]:
        """The machine now, as the API's state (``docs/dashboard.md``)."""
        now = self.operator.status()
        snapshot = reader.read()
        return self._state_of(snapshot, hold_pending=now.hold_pending)

    def _state_of(self, now: LiveSnapshot, *, hold_pending: bool) -> dict[str, Any]:
        offsets = now.work_offset_mm
        axes: dict[str, Any] = {}
        for name in self.axes:
            axis = now.axes.get(name)
            if axis is None:
                continue
            offset = offsets.get(name, 0.0)
            axes[name] = {
                "machine_mm": axis.measured_mm,
                "work_mm": axis.measured_mm - offset,
                "commanded_mm": axis.commanded_mm,
                "commanded_work_mm": axis.commanded_mm - offset,
                "following_error_mm": axis.following_error_mm,
                "peak_error_mm": axis.peak_error_mm,
                "velocity_mm_s": axis.measured_velocity_mm_s,
                "limit": axis.limit,
                "fault": axis.fault,
                "tick": axis.tick,
                "unit": "deg" if name in ROTARY_AXES else "mm",
                "wrapped": name in self.wrapped,
            }
        program = self.program
        alarm = now.alarm
        return {
            "type": "state",
            "sequence": now.sequence,
            "machine": self.machine_name,
            "state": now.state.value,
            "at_rest": now.at_rest,
            "hold_pending": hold_pending,
            "busy": self.operator.busy,
            "homed": now.homed,
            "axis_order": list(self.axes),
            "axes": axes,
            "program": None if program is None else self._progress(program, now),
            "feed_mm_min": now.feed_mm_min,
            "feed_override": now.feed_override,
            "rapid_override": now.rapid_override,
            "coordinate_system": system_name(now.coordinate_system),
            "work_offset_mm": {name: offsets.get(name, 0.0) for name in self.axes},
            "tool": now.tool,
            "tool_length_mm": now.tool_length_mm,
            "spindle": None if now.spindle is None else {
                "commanded_rpm": now.spindle.commanded_rpm,
                "measured_rpm": now.spindle.measured_rpm,
                "at_speed": now.spindle.at_speed},
            "outputs": dict(now.outputs),
            "probe": now.probe,
            "pause": now.pause,
            "tool_change": self._at_tool_change(),
            "tool_setter": self.config.tool_setter is not None,
            "alarm": alarm,
            "alarm_help": self._alarm_help(now) if alarm or now.state is MachineState.ALARM
            else "",
            "message_sequence": self._message_sequence,
            "sent_s": time.time(),
            "age_s": max(0.0, time.monotonic() - now.updated_s) if now.updated_s else 0.0,
        }

    @staticmethod
    def _progress(program: OpenProgram, now: LiveSnapshot) -> dict[str, Any]:
        """Where the open program stands: the live model's figures while it runs or after
        it ran; before it runs (or while MDI lines run), at its start."""
        if now.program == program.name:
            return {"name": program.name, "revision": program.revision, "line": now.line,
                    "lines_done": now.lines_done, "lines_total": now.lines_total,
                    "done_s": now.done_s, "total_s": now.total_s, "eta_s": now.eta_s}
        return {"name": program.name, "revision": program.revision, "line": 0,
                "lines_done": 0, "lines_total": program.end_line, "done_s": 0.0,
                "total_s": program.duration_s, "eta_s": program.duration_s}

    @staticmethod
    def _alarm_help(now: LiveSnapshot) -> str:
        if any(axis.limit for axis in now.axes.values()):
            return ("a limit switch reads closed: Reset clears the alarm and homes the"
                    " machine, which moves it off the switch")
        return ("Reset stops every axis, clears the alarm and homes the machine; find why it"
                " faulted first (the message log has the axis, the reason and the line)")

    def _at_tool_change(self) -> bool:
        """A program waits at its M6 pause (the new tool can be measured there)."""
        pause = self.session.paused
        return pause is not None and pause.code == "M6" and self.session.held

    def program_view(self) -> dict[str, Any]:
        """The open program (``GET /api/program``).

        Raises:
            RefusedError: no program is open (404).
        """
        program = self.program
        if program is None:
            raise RefusedError(404, "no program is open: open a demo, a file or upload one")
        return {
            "name": program.name,
            "revision": program.revision,
            "lines": program.lines,
            "toolpath": program.toolpath,
            "duration_s": program.duration_s,
            "warnings": list(program.warnings),
            "problem": program.problem,
        }

    def report(self) -> dict[str, Any]:
        """The report of the last program run (``GET /api/report``): the figures ``usbmotion
        run`` prints, as JSON (``docs/dashboard.md``).

        Raises:
            RefusedError: no program has run in this session (404).
        """
        report = self.operator.last_report
        if report is None:
            raise RefusedError(404, "no program has run yet: open one and Run it")
        data = report.to_json()
        kept = self._run_prediction
        if kept is not None and kept[0] is report:
            data["prediction"] = self._prediction_json(kept[1])
        return data

    def catalogue(self) -> dict[str, Any]:
        """What can be opened (``GET /api/programs``)."""
        files: list[str] = []
        if self.programs is not None and self.programs.is_dir():
            files = sorted(p.name for p in self.programs.iterdir()
                           if p.is_file() and program_name_problem(p.name) is None)
        return {
            "folder": None if self.programs is None else str(self.programs),
            "files": files,
            "demos": [{"number": number, "name": name, "title": title}
                      for number, (title, name) in DEMOS.items()],
        }

    # --- the program ------------------------------------------------------------------------

    def upload(self, name: str, body: bytes) -> dict[str, Any]:
        """Open an uploaded program.

        Raises:
            RefusedError: a name that is not a G-code file's or has a path in it (400), a body
                too large (413) or not text (400), G-code that does not parse (400, the
                line named), or the machine is busy (409).
        """
        problem = program_name_problem(name)
        if problem is not None:
            raise _bad(problem)
        if len(body) > UPLOAD_LIMIT_BYTES:
            raise RefusedError(413, f"program {name!r} is {len(body):,} bytes: at most"
                               f" {UPLOAD_LIMIT_BYTES:,} bytes may be uploaded")
        try:
            text = body.decode("utf-8")
        except UnicodeDecodeError as error:
            raise _bad(f"program {name!r} is not text (byte {error.start} is not UTF-8):"
                       " a G-code file is text") from None
        if "\x00" in text:
            raise _bad(f"program {name!r} is not text (it holds NUL bytes): a G-code file"
                       " is text")
        return self._open(name, text)

    def open_file(self, name: str) -> dict[str, Any]:
        """Open a file of the programs folder.

        Raises:
            RefusedError: no folder, a name that is not one of its G-code files (400/404), or
                as :meth:`upload`.
        """
        if self.programs is None:
            raise _bad("no programs folder: start usbmotion web with --programs DIR, or"
                       " upload the program")
        problem = program_name_problem(name)
        if problem is not None:
            raise _bad(problem)
        path = self.programs / name
        if not path.is_file():
            raise RefusedError(404, f"no program {name!r} in {self.programs}")
        size = path.stat().st_size
        if size > UPLOAD_LIMIT_BYTES:  # before reading it
            raise RefusedError(413, f"program {name!r} is {size:,} bytes: at most"
                               f" {UPLOAD_LIMIT_BYTES:,}")
        return self.upload(name, path.read_bytes())

    def open_demo(self, number: object) -> dict[str, Any]:
        """Open demo program ``number``.

        Raises:
            RefusedError: no such demo (400), or as :meth:`upload`.
        """
        if not isinstance(number, int) or isinstance(number, bool) or number not in DEMOS:
            raise _bad(f"demo {number!r}: allowed {', '.join(str(n) for n in DEMOS)}")
        path = demo_path(number)
        return self._open(path.name, path.read_text(encoding="utf-8"))

    def _open(self, name: str, text: str) -> dict[str, Any]:
        if self.operator.busy:
            raise _not_now(f"the machine is busy ({self.session.state.value}): open a"
                           " program when it is Idle")
        try:
            parsed = parse_gcode(text, file=name, machine=machine_axes(self.config),
                                 dialect=machine_dialect(self.config))
        except GCodeError as error:
            raise _bad(str(error)) from None
        with self._lock:
            self._revision += 1
            self.program = OpenProgram(name, text, self._revision, lines=text.splitlines(),
                                       end_line=parsed.end_line)
        self._call(self._plan)
        self.message(f"opened {name}")
        return self.program_view()

    def _plan(self) -> None:
        """Plan the open program from where the machine stands (on the worker)."""
        program = self.program
        if program is None:
            return
        try:
            prepared = self.session.prepare(program.name, text=program.text,
                                            pauses=self.session.pause_rule())
        except PlanningError as error:
            self._planned(program, None, str(error))
            return
        self._planned(program, prepared, "")

    def _planned(self, program: OpenProgram, prepared: Prepared | None, problem: str) -> None:
        with self._lock:
            self._revision += 1
            program.revision = self._revision
            program.problem = problem
            if prepared is not None:
                program.toolpath = _toolpath(prepared)
                program.duration_s = prepared.plan.duration_s
                program.warnings = prepared.warnings

    # --- controls ---------------------------------------------------------------------------

    def run(self, from_line: object = None) -> None:
        """Run the open program from where the machine stands, homing first if needed;
        with ``from_line``, from that line (``usbmotion run --from-line``: the lines before
        it set the modes without moving, then up, over and down into it).

        Raises:
            RefusedError: no program, busy, or in Alarm (409); a start line that is not one
                of the program's lines to run, or with no move after it (400).
        """
        program = self.program
        if program is None:
            raise _not_now("no program is open: open a demo, a file or upload one")
        if from_line is not None:
            last = program.end_line or len(program.lines)
            if (not isinstance(from_line, int) or isinstance(from_line, bool)
                    or not 1 <= from_line <= last):
                raise _bad(f"from_line {from_line!r}: allowed 1..{last} (the lines of"
                           f" {program.name})")
        self._idle_or_refuse("run a program")
        if self.session.state is MachineState.ALARM:
            raise _not_now("the machine is in Alarm: Reset clears it and homes the machine")

        def go() -> None:
            session = self.session
            homing_s = 0.0
            if not session.is_homed:
                self.message("homing first: the machine is not homed")
                homing_s = session.home()
            start = from_line
            while True:
                try:
                    prepared = session.prepare(program.name, text=program.text,
                                               pauses=session.pause_rule(), from_line=start)
                except PlanningError as error:
                    if start is None:
                        self._planned(program, None, str(error))
                    raise
                except ArgumentError as error:
                    if start == from_line or error.reason != "from_line":
                        raise
                    self.message("done: nothing of the program moves after the tool change")
                    return
                joined = ""
                if start is None:
                    self._planned(program, prepared, "")
                else:
                    joined = f" from line {start}"
                self.message(f"cycle start: {program.name}{joined},"
                             f" {prepared.plan.duration_s:.2f} s")
                report, _ = session.run(prepared, homing_s=homing_s)
                asked = session.measure_asked(report)
                if asked is None:
                    break
                try:
                    self.message(session.measure_tool(asked.tool).describe())
                    self.operator.measured_tool()
                except UsbMotionError as error:
                    self.message(f"measuring T{asked.tool}: {error}; the program stopped at"
                                 f" its tool change (line {asked.line}): measure the tool, then"
                                 f" run from line {asked.from_line}", level="error")
                    self.operator.last_report = report
                    return
                start, homing_s = asked.from_line, 0.0
            kept = self.prediction
            if kept is not None and kept.text == program.text and kept.from_line == start:
                self._run_prediction = (report, kept)
            self.operator.last_report = report
            for line in describe(report).splitlines():
                self.message(line, level="info" if report.completed else "error")

        self.operator.do(go)

    # --- prediction -------------------------------------------------------------------------

    def predict(self, tolerance_mm: object = None, from_line: object = None) -> dict[str, Any]:
        """Play the open program on the axes' models before anything moves, from where the
        machine stands (from where homing leaves it when it is not homed): each axis's
        predicted peak and RMS following error, each line's predicted peak, and the lines
        predicted beyond ``tolerance_mm`` (mm, degrees on a rotary axis; None: no
        tolerance). Kept as the open program's last prediction. Blocks for as long as the
        prediction takes (a second or so): call it off the event loop.

        Raises:
            RefusedError: no program open, the machine busy, a prediction already under way
                or no predictor (409); a tolerance or start line not allowed, an axis without
                a model, a program that cannot be planned from there (422).
        """
        program = self.program
        if program is None:
            raise _not_now("no program is open: open a demo, a file or upload one")
        if self.predictor is None:
            raise _not_now("this dashboard cannot predict: it was started without the"
                           " axes' models (usbmotion web predicts)")
        if tolerance_mm is not None and (
                isinstance(tolerance_mm, bool) or not isinstance(tolerance_mm, int | float)
                or not math.isfinite(tolerance_mm) or tolerance_mm <= 0):
            raise RefusedError(422, f"tolerance_mm {tolerance_mm!r}: a positive number of mm"
                                    " (degrees on a rotary axis), or null for none")
        if from_line is not None:
            last = program.end_line or len(program.lines)
            if (not isinstance(from_line, int) or isinstance(from_line, bool)
                    or not 1 <= from_line <= last):
                raise RefusedError(422, f"from_line {from_line!r}: allowed 1..{last} (the"
                                        f" lines of {program.name}), or null for the whole"
                                        " program")
        self._idle_or_refuse("predict")
        if not self._predicting.acquire(blocking=False):
            raise _not_now("a prediction is already being made: wait for its answer")
        try:
            standing = (self._call(self.session.positions_mm) if self.session.is_homed
                        else None)
            try:
                predicted = self.predictor(program.name, program.text, from_line=from_line,
                                           standing_mm=standing)
            except (ConfigError, GCodeError, PlanningError, ArgumentError) as error:
                raise RefusedError(422, str(error)) from None
            except UsbMotionError as error:
                raise RefusedError(500, f"the prediction failed: {error}") from None
        finally:
            self._predicting.release()
        kept = KeptPrediction(program.name, program.text, from_line, standing, predicted)
        self.prediction = kept
        data = self._prediction_json(kept)
        over = ([] if tolerance_mm is None
                else lines_over(predicted.report, float(tolerance_mm), self._scales()))
        data["tolerance_mm"] = tolerance_mm
        data["over_tolerance"] = [{"line": line, "axis": axis, "peak_mm": peak}
                                  for line, axis, peak in over]
        peaks = "  ".join(f"{a.name} {a.max_error_mm:.4f}" for a in predicted.report.axes)
        beyond = "" if tolerance_mm is None else (
            f"; {len(over)} line(s) beyond {tolerance_mm:g}" if over
            else f"; every line within {tolerance_mm:g}")
        self.message(f"predicted {program.name}: peak following error {peaks}{beyond}"
                     f" (in {predicted.wall_s:.2f} s)")
        return data

    def _scales(self) -> dict[str, float]:
        """Counts per mm (per degree) of each axis."""
        return {axis.name: axis.counts_per_mm for axis in self.config.axes}

    def _prediction_json(self, kept: KeptPrediction) -> dict[str, Any]:
        """A prediction as the API gives it (``docs/dashboard.md``)."""
        predicted = kept.predicted
        report = predicted.report
        data = report.to_json()
        wall_s = predicted.wall_s
        return {
            "program": kept.name,
            "from_line": kept.from_line,
            "standing_mm": None if kept.standing_mm is None else dict(kept.standing_mm),
            "motors": dict(predicted.motors),
            "wall_s": wall_s,
            "speed_ratio": report.planned_time_s / wall_s if wall_s > 0 else None,
            "planned_time_s": report.planned_time_s,
            "completed": report.completed,
            "stop_reason": report.stop_reason,
            "axes": data["axes"],
            "line_peaks": data["line_peaks"],
            "counts_per_mm": self._scales(),
        }

    # --- controls, continued ----------------------------------------------------------------

    def hold(self) -> None:
        """Feed hold: to rest along the path (a jog: cancelled)."""
        if self.session.jogging:
            self.operator.jog_cancel()
            self.message("jog cancelled")
            return
        self.operator.hold()
        self.message("hold: decelerating to rest along the path")

    def resume(self) -> None:
        """Resume a hold or a pause.

        Raises:
            RefusedError: nothing to resume (409).
        """
        if not self.session.hold_requested:
            raise _not_now("nothing to resume: no hold, no pause")
        self.operator.resume()
        self.message("resume")

    def stop(self) -> None:
        """Every axis to rest along its deceleration, the rest dropped."""
        if self.operator.busy:
            self.operator.stop()
            self.message("stop: every axis to rest along its deceleration")
        else:
            self.operator.drop_held()
            self.message("stop: nothing moves")

    def reset(self) -> None:
        """Stop what moves, clear the alarm and home the machine."""
        if self.operator.busy:
            self.operator.stop()

        def go() -> None:
            self.message("reset: stopping every axis")
            self.session.reset()
            seconds = self.session.home()
            self.message(f"homed in {seconds:.2f} s")
            self._plan()

        self.operator.do(go)

    def home(self, axes: Sequence[str] | None = None) -> None:
        """Home every axis, or the named ones.

        Raises:
            RefusedError: an axis the machine does not have (400), busy (409).
        """
        names = self._axis_names(axes, "home") if axes is not None else None
        self._idle_or_refuse("home")

        def go() -> None:
            seconds = self.session.home(axes=names)
            which = "every axis" if names is None else " ".join(names)
            self.message(f"homed {which} in {seconds:.2f} s")
            self._plan()

        self.operator.do(go)

    def jog(self, moves: Mapping[str, object], *, feed_mm_min: object,
            continuous: bool = False) -> None:
        """Jog by distances (machine mm) or, ``continuous``, in the signs' directions.

        Raises:
            RefusedError: bad axes, distances or feed (400), busy or not homed (409).
        """
        if not isinstance(moves, Mapping) or not moves:
            raise _bad("jog moves: give {axis: mm}, such as {\"X\": 1.0}")
        parsed: dict[str, float] = {}
        for name, value in moves.items():
            letter = str(name).upper()
            if not isinstance(value, int | float) or isinstance(value, bool):
                raise _bad(f"jog {name}: {value!r} is not a number of mm")
            parsed[letter] = float(value)
        if not isinstance(feed_mm_min, int | float) or isinstance(feed_mm_min, bool):
            raise _bad(f"jog feed_mm_min {feed_mm_min!r}: a positive number (mm/min)")
        feed = float(feed_mm_min)
        try:
            check_jog(parsed, feed, self.axes)
        except ArgumentError as error:
            raise _bad(str(error)) from None
        if continuous:
            if any(v == 0 for v in parsed.values()):
                raise _bad("a continuous jog takes a direction per axis: +1 or -1")
            parsed = {k: math.copysign(1.0, v) for k, v in parsed.items()}
        self._idle_or_refuse("jog")
        if not self.session.is_homed:
            raise _not_now("a jog needs a homed machine (its soft limits): home it first")
        try:
            self.operator.jog(parsed, feed_mm_min=feed, continuous=continuous)
        except MachineStateError as error:
            raise _not_now(str(error)) from None

    def jog_cancel(self) -> None:
        """End a jog along its deceleration."""
        self.operator.jog_cancel()

    def mdi(self, line: object) -> None:
        """A G-code line, run at once after what is queued.

        Raises:
            RefusedError: not a line of text, a line that does not parse or leaves the travel
                (400), the machine in Alarm or not homed, or the planner full (409).
        """
        if not isinstance(line, str) or not line.strip():
            raise _bad("mdi line: give a line of G-code, such as \"G0 X10\"")
        if "\n" in line or "\r" in line:
            raise _bad("mdi line: one line at a time")
        deadline = time.monotonic() + MDI_WAIT_S
        while True:
            try:
                taken = self.operator.submit(line.strip())
            except (GCodeError, PlanningError) as error:
                raise _bad(str(error)) from None
            except MachineStateError as error:
                raise _not_now(str(error)) from None
            if taken:
                self.message(f"> {line.strip()}")
                return
            if time.monotonic() > deadline:
                raise _not_now("the planner is full: try again once the machine has caught up")
            time.sleep(0.01)

    def overrides(self, *, feed: object = None, rapid: object = None) -> None:
        """Set the feed (10..200 %) and rapid (25, 50, 100 %) overrides.

        Raises:
            RefusedError: neither given, or a value not allowed (400).
        """
        if feed is None and rapid is None:
            raise _bad("overrides: give feed (10..200) or rapid (25, 50, 100), in percent")
        for label, value, setter in (("feed", feed, self.session.set_feed_override),
                                     ("rapid", rapid, self.session.set_rapid_override)):
            if value is None:
                continue
            if not isinstance(value, int) or isinstance(value, bool):
                raise _bad(f"{label} override {value!r}: a whole number of percent")
            try:
                setter(value)
            except ArgumentError as error:
                raise _bad(str(error)) from None
        self.message(f"override: feed {self.session.feed_override_percent} %, rapid"
                     f" {self.session.rapid_override_percent} %")

    def zero(self, axes: Sequence[str] | None, *, system: object = 1) -> dict[str, float]:
        """Set the work origin of ``system`` (1 = G54) where the machine stands, for the
        named axes (all when None); returns the new offset of each axis.

        Raises:
            RefusedError: bad axes or system (400), busy or not homed (409).
        """
        names = self._axis_names(axes, "zero") if axes is not None else list(self.axes)
        if not isinstance(system, int) or isinstance(system, bool) or not (
                1 <= system <= MAX_SYSTEM):
            raise _bad(f"system {system!r}: allowed 1 (G54) .. 6 (G59), 7..9 (G59.1..G59.3)")
        self._idle_or_refuse("set a work origin")
        if not self.session.is_homed:
            raise _not_now("the machine is not homed, so its position means nothing: home"
                           " it first")

        def go() -> dict[str, float]:
            where = self.session.positions_mm()
            offsets = self.session.set_work_origin({n: where[n] for n in names},
                                                   system=system)
            self.session.read_live()
            self._plan()
            row = offsets.g5x[system - 1]
            return {n: row["XYZUVW".index(n)] for n in names}

        origin = self._call(go)
        self.message(f"{system_name(system)} origin "
                     + "  ".join(f"{n} {v:.3f}" for n, v in origin.items()) + " mm (machine)")
        return origin

    def measure_tool(self, tool: object = None) -> dict[str, Any]:
        """Measure tool ``tool`` (None: the one in the spindle) on the tool setter, its
        length written to the tool table (:meth:`MachineSession.measure_tool`).

        Raises:
            RefusedError: a bad tool number (400); busy, not homed, no setter, no contact
                (409).
        """
        if tool is not None and (not isinstance(tool, int) or isinstance(tool, bool)
                                 or tool < 1):
            raise _bad(f"tool {tool!r}: allowed a tool number >= 1, or none for the tool in"
                       " the spindle")
        if self._at_tool_change():
            if tool is not None:
                raise _bad(f"tool {tool!r}: at a tool change the new tool is measured (give"
                           " no tool)")
            try:
                asked = self.session.request_tool_measure()
            except (MachineStateError, ConfigError) as error:
                raise _not_now(str(error)) from error
            self.message(f"measuring T{asked.tool} on the tool setter; the program then goes"
                         f" on from line {asked.from_line}")
            return {"tool": asked.tool, "at_tool_change": asked.line,
                    "from_line": asked.from_line}
        self._idle_or_refuse("measure a tool")
        if not self.session.is_homed:
            raise _not_now("the machine is not homed: home it first")
        def go() -> ToolMeasurement:
            done = self.session.measure_tool(tool)
            self.operator.measured_tool()
            return done

        measured = self._call(go)
        self.message(measured.describe())
        return {"tool": measured.tool, "contact_z_mm": measured.contact_z_mm,
                "length_mm": measured.length_mm, "table": measured.table}

    # --- devices ----------------------------------------------------------------------------

    def devices(self) -> dict[str, Any]:
        """Each axis's device and its parameters as it holds them (read at rest).

        Raises:
            RefusedError: the machine is busy (409), or a device did not answer (409).
        """
        self._idle_or_refuse("read the devices' parameters")

        def read() -> list[dict[str, Any]]:
            out = []
            for name in self.config.axis_names:
                axis = self.session.machine.axis(name)
                out.append({
                    "axis": name, "port": axis.url, "label": axis.config.label,
                    "parameters": [{"name": p.name, "value": p.read(axis.client),
                                    "unit": p.unit, "storage": p.storage.value,
                                    "allowed": p.allowed, "meaning": p.meaning}
                                   for p in PARAMETERS],
                })
            return out

        return {"devices": self._call(read)}

    def set_parameter(self, axis: object, name: object, value: object, *,
                      flash: object = False) -> dict[str, Any]:
        """Set one device parameter by name, checked first as ``usbmotion set`` checks it
        (its range, and what the machine file would refuse). ``flash`` asks that it be
        kept across power cycles: only a parameter kept in flash can be.

        Raises:
            RefusedError: an unknown axis or parameter, a value refused (400), busy (409).
        """
        if not isinstance(axis, str) or axis.upper() not in self.config.axis_names:
            raise _bad(f"axis {axis!r}: allowed {', '.join(self.config.axis_names)}")
        letter = axis.upper()
        if not isinstance(name, str):
            raise _bad(f"parameter name {name!r}: a name such as \"kp\"")
        try:
            each = parameter(name)
        except ArgumentError as error:
            raise _bad(str(error)) from None
        if isinstance(value, bool) or not isinstance(value, int | float | str):
            raise _bad(f"{name} value {value!r}: a number, a mode word or a name")
        text = str(value)
        if not isinstance(flash, bool):
            raise _bad(f"flash {flash!r}: true or false")
        if flash and each.storage is not Storage.FLASH:
            raise _bad(f"{name} is kept in RAM: the device cannot keep it in flash (the"
                       " machine file sets it at every start)")
        try:
            each.check(text)
        except (ArgumentError, OutOfRangeError) as error:
            raise _bad(f"axis {letter} {name} {text!r} refused: {error}") from None
        self._idle_or_refuse("set a parameter")

        def write() -> str:
            target = self.session.machine.axis(letter)
            problem = machine_file_problem(self.config, target.config, target.client, each,
                                           text, url_checks=self.url_checks)
            if problem is not None:
                raise ArgumentError(f"axis {letter} {name} {text!r} refused as the machine"
                                    f" file would refuse it: {problem}", reason=name)
            each.write(target.client, text)
            return each.read(target.client)

        now = self._call(write, refused=400)
        kept = "flash" if each.storage is Storage.FLASH else "RAM"
        self.message(f"axis {letter} {name} = {now} {each.unit}".rstrip() + f" ({kept})")
        return {"axis": letter, "name": name, "value": now, "storage": kept}

    def tune(self, axis: object, *, step_mm: object = 1.0) -> dict[str, Any]:
        """A step response of ``axis`` at rest (``usbmotion tune``'s), and a step back to
        where it stood; the first step's record and figures.

        Raises:
            RefusedError: bad axis or step, a step beyond the travel (400), busy or not
                homed (409).
        """
        if not isinstance(axis, str) or axis.upper() not in self.config.axis_names:
            raise _bad(f"axis {axis!r}: allowed {', '.join(self.config.axis_names)}")
        letter = axis.upper()
        if isinstance(step_mm, bool) or not isinstance(step_mm, int | float) or not (
                math.isfinite(step_mm) and 0 < abs(step_mm) <= 50):
            raise _bad(f"step_mm {step_mm!r}: a distance within 0..50 mm, not 0")
        self._idle_or_refuse("tune")
        if not self.session.is_homed:
            raise _not_now("tune steps a homed machine (its travel known): home it first")
        step = float(step_mm)

        def record() -> StepResponse:
            machine = self.session.machine
            response = step_response(machine, letter, step_mm=step)
            step_response(machine, letter, step_mm=-step)
            self.session.read_live()
            return response

        response = self._call(record, refused=400)
        scale = self.config.axis(letter).counts_per_mm
        m = response.metrics

        def finite(value: float) -> float | None:
            return None if math.isnan(value) else round(value, 6)

        self.message(f"tune {letter}: step {step:g} mm, overshoot {m.overshoot_pct:.2f} %,"
                     " settling " + ("never" if math.isnan(m.settling_time_s)
                                     else f"{m.settling_time_s * 1000:.1f} ms"))
        return {
            "axis": letter, "step_mm": step,
            "time_s": [round(float(t), 6) for t in response.times_s],
            "commanded_mm": [float(v) / scale for v in response.desired],
            "measured_mm": [float(v) / scale for v in response.actual],
            "overshoot_percent": finite(m.overshoot_pct),
            "rise_s": finite(m.rise_time_s),
            "settling_s": finite(m.settling_time_s),
            "steady_state_error_mm": m.steady_state_error_counts / scale,
        }

    def tune_auto(self, axis: object, *, travel_mm: object, write: object = False
                  ) -> dict[str, Any]:
        """``usbmotion tune --auto`` on ``axis`` at rest: identified within ``travel_mm`` of
        where it stands (negative: toward lower positions), its gains placed and checked with
        a step and a move, predicted beside measured. With ``write`` the gains and the model
        go into the machine file (the command's ``--write``) and the machine takes them at
        once; without, the axis gets the file's gains back.

        Raises:
            RefusedError: a bad axis, travel or write (400), busy, or the built-in machine's
                file to write (409); the identification refused (400) or failed (409).
        """
        if not isinstance(axis, str) or axis.upper() not in self.config.axis_names:
            raise _bad(f"axis {axis!r}: allowed {', '.join(self.config.axis_names)}")
        letter = axis.upper()
        low, high = self.config.axis(letter).travel_mm
        if isinstance(travel_mm, bool) or not isinstance(travel_mm, int | float) or not (
                math.isfinite(travel_mm) and 0 < abs(travel_mm) <= high - low):
            raise _bad(f"travel_mm {travel_mm!r}: the room the test may use from where the"
                       f" axis stands, mm, not 0, within {high - low:g} (negative: toward"
                       " lower positions)")
        if not isinstance(write, bool):
            raise _bad(f"write {write!r}: true or false")
        if write and self.config.path.resolve() == builtin_machine_file().resolve():
            raise _not_now(f"{self.config.path} is the built-in machine's file, part of the"
                           " package: copy it (examples/machine.toml is the same) and serve"
                           " the copy (usbmotion web --machine FILE) to write it")
        self._idle_or_refuse("tune")
        room = float(travel_mm)

        def identify() -> tuple[Identification, Placement]:
            machine = self.session.machine
            target = machine.axis(letter)
            try:
                found = identify_axis(machine, letter, travel_mm=room)
                chosen = place_loop(found, target.config)
                placed = check_on_axis(machine, letter, found, chosen)
            finally:
                if not write:
                    gains = target.config.gains
                    target.client.set_gains(kp=gains.kp, ki=gains.ki, kd=gains.kd)
                self.session.read_live()
            return found, placed

        found, placed = self._call(identify, refused=400)
        written = ""
        if write:
            path = self.config.path
            try:
                write_tuning_file(path, letter, found, placed, None, url_checks=self.url_checks)
            except ConfigError as error:
                raise _not_now(f"the machine file was not written: {error}") from None
            except OSError as error:
                raise _not_now(f"cannot write {path}: {error.strerror or error}") from None
            try:
                self.operator.reconfigure(load_config(path, url_checks=self.url_checks))
            except (ConfigError, MachineStateError) as error:
                raise _not_now(f"{path} is written, but the machine takes it only when it"
                               f" starts again: {error}") from None
            self.config = self.session.config
            written = str(path)
        model, fit, design = found.fit.model, found.fit, placed.design
        checks: dict[str, Any] = {}
        for check in (placed.step, placed.move):
            if check is not None:
                checks[check.what] = {
                    "distance_counts": check.distance_counts,
                    **{key: {"predicted": _finite(pair[0]), "measured": _finite(pair[1])}
                       for key, pair in predicted_versus_measured(check).items()}}
        gains = design.gains
        self.message(f"tune {letter} automatically: kp {gains.kp:g} ki {gains.ki:g} kd"
                     f" {gains.kd:g}, phase margin {design.margins.phase_margin_deg:.1f} deg"
                     + (f"; written to {written}" if written else "; not written"))
        return {
            "axis": letter, "travel_mm": room,
            "model": {
                "time_constant_s": model.time_constant_s,
                "time_constant_sigma_s": fit.time_constant_sigma_s,
                "speed_per_volt_counts_s": model.speed_per_volt_counts_s,
                "speed_per_volt_sigma_counts_s": fit.speed_per_volt_sigma_counts_s,
                "coulomb_v": model.coulomb_v, "coulomb_sigma_v": fit.coulomb_sigma_v,
                "supply_v": model.supply_v},
            "gains": {"kp": gains.kp, "ki": gains.ki, "kd": gains.kd},
            "loop": {"crossover_hz": design.margins.crossover_hz,
                     "phase_margin_deg": _finite(design.margins.phase_margin_deg),
                     "gain_margin_db": _finite(design.margins.gain_margin_db)},
            "checks": checks,
            "written_to": written or None,
        }

    def select_system(self, system: object) -> None:
        """Make ``system`` (1 = G54) the active coordinate system, as a program's ``G55``
        then ``M2`` leaves it: kept in the parameter file, so the next run, the MDI lines
        and the live model all use it.

        Raises:
            RefusedError: a system out of 1..9 (400), busy (409).
        """
        if not isinstance(system, int) or isinstance(system, bool) or not (
                1 <= system <= MAX_SYSTEM):
            raise _bad(f"system {system!r}: allowed 1 (G54) .. 6 (G59), 7..9 (G59.1..G59.3)")
        self._idle_or_refuse("select a coordinate system")

        def go() -> None:
            offsets = self.session.work_offsets()
            self.session.save_work_offsets(replace(offsets, coordinate_system=system))
            self.operator.feed = None  # the MDI lines start again from the file's state
            self.session.read_live()
            self._plan()

        self._call(go)
        self.message(f"{system_name(system)} is active")

    # --- helpers ----------------------------------------------------------------------------

    def _axis_names(self, axes: object, what: str) -> list[str]:
        if not isinstance(axes, list | tuple) or not axes or not all(
                isinstance(a, str) for a in axes):
            raise _bad(f"{what} axes: a list of axis letters, such as [\"X\", \"Y\"]")
        names = [a.upper() for a in axes]
        bad = [a for a in names if a not in self.axes]
        if bad:
            raise _bad(f"{what} axes {' '.join(bad)}: allowed {', '.join(self.axes)}")
        return names

    def _idle_or_refuse(self, what: str) -> None:
        if self.operator.busy:
            raise _not_now(f"the machine is busy ({self.session.state.value}): {what} when"
                           " it is Idle")

    def _call(self, action: Callable[[], T], *, refused: int = 409) -> T:
        """Run ``action`` on the worker and wait for its result (the operator no longer
        busy on its account: a call right after it is not refused as busy).

        Raises:
            RefusedError: it failed (its error: ``refused`` for an ArgumentError, else 409)
                or did not end within CALL_TIMEOUT_S.
        """
        try:
            return self.operator.call(action, timeout_s=CALL_TIMEOUT_S)
        except TimeoutError as error:
            raise _not_now(str(error)) from None
        except UsbMotionError as error:
            status = refused if isinstance(error, ArgumentError | OutOfRangeError) else 409
            raise RefusedError(status, str(error)) from None
