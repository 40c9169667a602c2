"""The grbl 1.1h protocol front, sans I/O: bytes in through :meth:`GrblProtocol.receive`,
bytes out through the ``write`` callable, and :meth:`GrblProtocol.poll` called every few
milliseconds to move lines on to the machine.

Real-time bytes (``?``, ``!``, ``~``, Ctrl-X and every byte above 0x7F) are acted on as they
arrive and never enter the 128-byte receive buffer; every other byte is kept there until the
pre-parser takes it, or dropped when the buffer is full (as grbl drops it). A line is taken
out of the buffer only while nothing before it waits (room in the planner, the end of the
motion before a G4, a homing cycle), so a sender that counts characters never overflows the
buffer, and ``ok`` goes out when a line has left it for the planner.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from usbmotion.grbl.codes import AlarmCode, GrblErrorCode
from usbmotion.grbl.interface import (
    Admission,
    Fault,
    GrblMachine,
    JogMove,
    MotionState,
    Rejected,
    SubmitResult,
)
from usbmotion.grbl.lines import (
    LineEffects,
    PreParser,
    WordError,
    line_effects,
    line_number,
    parse_jog,
    read_number,
)
from usbmotion.grbl.reports import (
    BANNER,
    HELP,
    NOT_APPLICABLE,
    UNLOCK_HINT,
    build_info_lines,
    coordinates,
    machine_setting_values,
    message,
    modal_line,
    parameter_lines,
    probe_line,
    rate,
    setting_value,
    settings_lines,
)

RX_BUFFER_BYTES = 128
STARTUP_LINES = 2

STATUS_REPORT = 0x3F  # '?'
CYCLE_START = 0x7E  # '~'
FEED_HOLD = 0x21  # '!'
SOFT_RESET = 0x18
SAFETY_DOOR = 0x84
JOG_CANCEL = 0x85
FEED_OVERRIDE_RESET = 0x90
FEED_OVERRIDE_COARSE_PLUS = 0x91
FEED_OVERRIDE_COARSE_MINUS = 0x92
FEED_OVERRIDE_FINE_PLUS = 0x93
FEED_OVERRIDE_FINE_MINUS = 0x94
RAPID_OVERRIDE_RESET = 0x95
RAPID_OVERRIDE_MEDIUM = 0x96
RAPID_OVERRIDE_LOW = 0x97
SPINDLE_OVERRIDE_RESET = 0x99
SPINDLE_OVERRIDE_COARSE_PLUS = 0x9A
SPINDLE_OVERRIDE_COARSE_MINUS = 0x9B
SPINDLE_OVERRIDE_FINE_PLUS = 0x9C
SPINDLE_OVERRIDE_FINE_MINUS = 0x9D

OVERRIDE_MIN_PERCENT = 10
OVERRIDE_MAX_PERCENT = 200
_FEED_STEPS = {FEED_OVERRIDE_COARSE_PLUS: 10, FEED_OVERRIDE_COARSE_MINUS: -10,
               FEED_OVERRIDE_FINE_PLUS: 1, FEED_OVERRIDE_FINE_MINUS: -1}
_SPINDLE_STEPS = {SPINDLE_OVERRIDE_COARSE_PLUS: 10, SPINDLE_OVERRIDE_COARSE_MINUS: -10,
                  SPINDLE_OVERRIDE_FINE_PLUS: 1, SPINDLE_OVERRIDE_FINE_MINUS: -1}
_RAPID_VALUES = {RAPID_OVERRIDE_RESET: 100, RAPID_OVERRIDE_MEDIUM: 50, RAPID_OVERRIDE_LOW: 25}

WCO_REFRESH_BUSY, WCO_REFRESH_IDLE = 30, 10
OVR_REFRESH_BUSY, OVR_REFRESH_IDLE = 20, 10
"""Every how many status reports WCO: and Ov: come again, in motion and at rest."""

CRITICAL_ALARMS = frozenset({int(AlarmCode.HARD_LIMIT), int(AlarmCode.SOFT_LIMIT)})
"""Alarms after which grbl reads nothing until a soft reset."""

REPORT_MACHINE_POSITION = 1
REPORT_BUFFER_STATE = 2
DEFAULT_REPORT_MASK = REPORT_MACHINE_POSITION | REPORT_BUFFER_STATE
"""``$10``: MPos and Bf (grbl's default shows no Bf; the front's buffer is worth seeing)."""

_BUSY = frozenset({MotionState.RUN, MotionState.JOG, MotionState.HOMING,
                   MotionState.HOLD_COMPLETE, MotionState.HOLD_IN_PROGRESS})
_MOVING = frozenset({MotionState.RUN, MotionState.JOG, MotionState.HOMING,
                     MotionState.HOLD_IN_PROGRESS})


@dataclass(frozen=True, slots=True)
class _Resubmit:
    """A G-code line the planner had no room for."""

    line: str
    number: int | None
    effects: LineEffects


@dataclass(frozen=True, slots=True)
class _Rejog:
    """A jog the planner had no room for."""

    move: JogMove


@dataclass(frozen=True, slots=True)
class _AwaitMotion:
    """A line queued whose ``ok`` waits for the motion before it to end."""

    effects: LineEffects


@dataclass(frozen=True, slots=True)
class _AwaitHoming:
    """``$H`` running."""


@dataclass(frozen=True, slots=True)
class _AwaitMeasure:
    """``$TLS`` running."""


_Waiting = _Resubmit | _Rejog | _AwaitMotion | _AwaitHoming | _AwaitMeasure


@dataclass(slots=True)
class Statistics:
    """What the front measured of its receive buffer."""

    max_rx_bytes: int = 0
    """The most bytes the receive buffer held at once."""
    dropped_rx_bytes: int = 0
    """Bytes lost because the buffer was full (a sender that does not count characters)."""
    lines: int = 0
    """Lines taken from the buffer."""


class GrblProtocol:
    """One grbl session on one machine.

    Parameters:
        machine: the machine session (:class:`GrblMachine`).
        write: called with each piece of output, whole lines.
        build_text: the ``$I`` user text.
    """

    def __init__(self, machine: GrblMachine, write: Callable[[bytes], None], *,
                 build_text: str = "") -> None:
        self.machine = machine
        self._write = write
        self._axes = machine.axes()
        self._rx = bytearray()
        self._parser = PreParser()
        self._waiting: _Waiting | None = None
        self._alarm = False
        self._fault_reported = False
        self._critical = False
        self._check_mode = False
        self._sleeping = False
        self._door = False
        self._feed_override = self._rapid_override = self._spindle_override = 100
        self._report_mask = DEFAULT_REPORT_MASK
        self._report_inches = False
        self._startup_lines = [""] * STARTUP_LINES
        self._build_text = build_text
        self._wco_counter = self._ovr_counter = 0
        self._last_wco: tuple[float, ...] | None = None
        self.statistics = Statistics()
        machine.attach_front(self.lines_waiting)

    # ---- output

    def _line(self, text: str) -> None:
        self._write(text.encode("ascii", "replace") + b"\r\n")

    def _ok(self) -> None:
        self._line("ok")

    def _error(self, code: int) -> None:
        self._line(f"error:{int(code)}")

    def _rejected(self, rejection: Rejected) -> None:
        if rejection.message:
            self._line(message(rejection.message))
        self._error(rejection.code)

    # ---- connection and reset

    def connect(self) -> None:
        """A sender has just connected: reset as grbl does when its port opens (the
        banner, the unlock hint in alarm, the start-up lines otherwise). A machine still in
        motion is stopped with ``ALARM:3``, as a soft reset would."""
        self._reset(announce_alarm=True)

    def _reset(self, *, announce_alarm: bool) -> None:
        state = self.machine.state()
        if announce_alarm and state in _MOVING:
            self._alarm = True
            alarm = AlarmCode.HOMING_FAIL_RESET if state is MotionState.HOMING \
                else AlarmCode.ABORT_CYCLE
            self.machine.soft_reset()
            self._line(f"ALARM:{int(alarm)}")
        else:
            self.machine.soft_reset()
        self._rx.clear()
        self._parser.clear()
        self._waiting = None
        self._check_mode = self._door = self._critical = False
        if self._sleeping:
            self._sleeping = False
            self._alarm = True
        for percent, setter in ((self._feed_override, self.machine.set_feed_override),
                                (self._rapid_override, self.machine.set_rapid_override)):
            if percent != 100:
                setter(100)
        self._feed_override = self._rapid_override = self._spindle_override = 100
        self._wco_counter = self._ovr_counter = 0
        self._last_wco = None
        self._write(b"\r\n")
        self._line(BANNER)
        if self._locked():
            self._line(UNLOCK_HINT)
        else:
            self._run_startup_lines()

    def _locked(self) -> bool:
        return self._alarm or self.machine.state() is MotionState.ALARM

    def _run_startup_lines(self) -> None:
        for line in self._startup_lines:
            if not line:
                continue
            result = self.machine.submit(line, line_number(line))
            if isinstance(result, Rejected):
                self._line(f">{line}:error:{result.code}")
            else:
                self._line(f">{line}:ok")

    # ---- bytes in

    def receive(self, data: bytes) -> None:
        """Take bytes as they arrive: real-time ones acted on now, the rest buffered, or
        dropped once the buffer is full. Hand over at most :attr:`rx_bytes_free` at a time,
        polling between, to drain it as grbl's main loop does while a serial line
        delivers bytes (a character-counting sender never needs it)."""
        stats = self.statistics
        for byte in data:
            if byte == STATUS_REPORT:
                self._status_report()
            elif byte == SOFT_RESET:
                self._reset(announce_alarm=True)
            elif byte == FEED_HOLD:
                self._feed_hold()
            elif byte == CYCLE_START:
                self._cycle_start()
            elif byte > 0x7F:
                self._extended(byte)
            elif len(self._rx) < RX_BUFFER_BYTES:
                self._rx.append(byte)
                stats.max_rx_bytes = max(stats.max_rx_bytes, len(self._rx))
            else:
                stats.dropped_rx_bytes += 1

    def lines_waiting(self) -> bool:
        """True when the receive buffer holds a whole line the next poll hands to the
        machine without waiting for its motion to end, or a line waits for room in the
        planner. Safe from another thread (it only reads)."""
        if self._sleeping or self._critical or self._check_mode:
            return False
        waiting = self._waiting
        if waiting is not None:
            return isinstance(waiting, _Resubmit)
        rx = self._rx
        return b"\n" in rx or b"\r" in rx

    @property
    def rx_bytes_free(self) -> int:
        """Room left in the receive buffer."""
        return RX_BUFFER_BYTES - len(self._rx)

    def _feed_hold(self) -> None:
        if self._check_mode or self._sleeping or self._locked():
            return
        state = self.machine.state()
        if state is MotionState.JOG:
            self.machine.jog_cancel()
        elif state in (MotionState.IDLE, MotionState.RUN):
            self.machine.feed_hold()

    def _cycle_start(self) -> None:
        if self._sleeping or self._locked():
            return
        if self.machine.state() is MotionState.HOLD_COMPLETE:
            self._door = False
            self.machine.cycle_start()

    def _extended(self, byte: int) -> None:
        if byte == JOG_CANCEL:
            if self.machine.state() is MotionState.JOG:
                self.machine.jog_cancel()
        elif byte == SAFETY_DOOR:
            self._safety_door()
        elif byte == FEED_OVERRIDE_RESET or byte in _FEED_STEPS:
            target = 100 if byte == FEED_OVERRIDE_RESET \
                else self._feed_override + _FEED_STEPS[byte]
            target = min(max(target, OVERRIDE_MIN_PERCENT), OVERRIDE_MAX_PERCENT)
            if target != self._feed_override:
                self._feed_override = target
                self.machine.set_feed_override(target)
                self._ovr_counter = 0
        elif byte in _RAPID_VALUES:
            target = _RAPID_VALUES[byte]
            if target != self._rapid_override:
                self._rapid_override = target
                self.machine.set_rapid_override(target)
                self._ovr_counter = 0
        elif byte == SPINDLE_OVERRIDE_RESET or byte in _SPINDLE_STEPS:
            target = 100 if byte == SPINDLE_OVERRIDE_RESET \
                else self._spindle_override + _SPINDLE_STEPS[byte]
            target = min(max(target, OVERRIDE_MIN_PERCENT), OVERRIDE_MAX_PERCENT)
            if target != self._spindle_override:
                self._spindle_override = target
                self.machine.set_spindle_override(target)
                self._ovr_counter = 0
        # Every other extended byte (spindle stop, coolant toggles, unknown) is dropped.

    def _safety_door(self) -> None:
        if self._check_mode or self._sleeping or self._locked():
            return
        state = self.machine.state()
        if state is MotionState.HOMING:
            self.machine.soft_reset()
            self._raise_alarm(Fault(int(AlarmCode.HOMING_FAIL_DOOR),
                                    "safety door opened while homing"))
            return
        self._door = True
        if state is MotionState.JOG:
            self.machine.jog_cancel()
        elif state in (MotionState.IDLE, MotionState.RUN):
            self.machine.feed_hold()

    # ---- status report

    def _state_name(self, state: MotionState) -> str:
        if self._sleeping:
            return "Sleep"
        if self._check_mode:
            return "Check"
        if self._locked():
            return "Alarm"
        if self._door and state in (MotionState.HOLD_COMPLETE, MotionState.IDLE):
            return "Door:0"
        if self._door and state in (MotionState.HOLD_IN_PROGRESS, MotionState.RUN):
            return "Door:2"
        return state.value

    def _status_report(self) -> None:
        state = self.machine.state()
        status = self.machine.status()
        inches = self._report_inches
        letters = "".join(self._axes)
        fields = [self._state_name(state)]
        if self._report_mask & REPORT_MACHINE_POSITION:
            fields.append("MPos:" + coordinates(status.machine_position_mm, inches=inches,
                                                 axes=letters))
        else:
            work = [m - o for m, o in zip(status.machine_position_mm, status.work_offset_mm,
                                          strict=True)]
            fields.append(f"WPos:{coordinates(work, inches=inches, axes=letters)}")
        if self._report_mask & REPORT_BUFFER_STATE:
            fields.append(f"Bf:{self.machine.planner_blocks_free()},{self.rx_bytes_free}")
        if status.line_number and state in (MotionState.RUN, MotionState.HOLD_COMPLETE,
                                            MotionState.HOLD_IN_PROGRESS):
            fields.append(f"Ln:{status.line_number}")
        fields.append(f"FS:{rate(status.feed_mm_min, inches=inches)},"
                      f"{abs(status.spindle_rpm):.0f}")
        pins = "".join(axis for axis in self._axes if axis in status.limit_pins) + (
            "P" if status.probe else "")
        if pins:
            fields.append(f"Pn:{pins}")
        busy = state in _BUSY
        if status.work_offset_mm != self._last_wco:
            self._wco_counter = 0
        if self._wco_counter > 0:
            self._wco_counter -= 1
        else:
            self._wco_counter = (WCO_REFRESH_BUSY if busy else WCO_REFRESH_IDLE) - 1
            if self._ovr_counter == 0:
                self._ovr_counter = 1
            self._last_wco = status.work_offset_mm
            fields.append("WCO:" + coordinates(status.work_offset_mm, inches=inches,
                                                axes=letters))
        if self._ovr_counter > 0:
            self._ovr_counter -= 1
        else:
            self._ovr_counter = (OVR_REFRESH_BUSY if busy else OVR_REFRESH_IDLE) - 1
            fields.append(f"Ov:{self._feed_override},{self._rapid_override},"
                          f"{self._spindle_override}")
        if status.accessories:
            fields.append(f"A:{status.accessories}")
        if status.following_error_mm:
            fields.append("FE:" + coordinates(status.following_error_mm, inches=inches,
                                               axes=letters))
        self._line(f"<{'|'.join(fields)}>")

    # ---- the loop

    def poll(self) -> None:
        """Report new faults, finish what waits, and take lines while nothing waits."""
        self._watch_faults()
        if self._sleeping or self._critical:
            return
        if self._waiting is not None and not self._resume():
            return
        while self._rx:
            byte = self._rx.pop(0)
            taken = self._parser.feed(byte)
            if taken is None:
                continue
            self.statistics.lines += 1
            self._execute(*taken)
            if self._waiting is not None or self._sleeping:
                return

    def _watch_faults(self) -> None:
        if self._fault_reported or isinstance(self._waiting, _AwaitHoming) or \
                self.machine.state() is not MotionState.ALARM:
            return
        fault = self.machine.status().fault
        if fault is not None:
            self._raise_alarm(fault)

    def _raise_alarm(self, fault: Fault) -> None:
        """``[MSG:...]`` naming the fault, ``ALARM:N``, and the lock. A hard or soft limit
        (alarms 1 and 2) is critical, as in grbl: ``[MSG:Reset to continue]`` and no line
        is read until a soft reset (status reports are still answered)."""
        where = f"{fault.axis} axis: " if fault.axis else ""
        line = f" (program line {fault.line_number})" if fault.line_number is not None else ""
        self._line(message(f"{where}{fault.message}{line}"))
        self._line(f"ALARM:{fault.alarm}")
        self._alarm = True
        self._fault_reported = True
        self._critical = fault.alarm in CRITICAL_ALARMS
        if self._critical:
            self._line("[MSG:Reset to continue]")
            if not isinstance(self._waiting, _AwaitHoming):
                self._waiting = None
        elif isinstance(self._waiting, (_Resubmit, _Rejog, _AwaitMotion, _AwaitMeasure)):
            self._waiting = None
            self._error(GrblErrorCode.SYSTEM_GC_LOCK)

    def _resume(self) -> bool:
        """Try what waits again; True once nothing waits."""
        waiting = self._waiting
        if isinstance(waiting, _Resubmit):
            self._waiting = None
            self._submit(waiting.line, waiting.number, waiting.effects)
        elif isinstance(waiting, _Rejog):
            self._waiting = None
            self._answer_jog(waiting.move)
        elif isinstance(waiting, _AwaitMotion):
            if self.machine.motion_done():
                self._waiting = None
                self._after_motion(waiting.effects)
        elif isinstance(waiting, _AwaitMeasure):
            if self.machine.motion_done():
                self._waiting = None
                found = self.machine.tool_measurement()
                if isinstance(found, Rejected):
                    self._rejected(found)
                else:
                    self._line(message(found))
                    self._ok()
        elif isinstance(waiting, _AwaitHoming) and \
                self.machine.state() is not MotionState.HOMING:
            self._waiting = None
            self._homing_ended()
        return self._waiting is None

    # ---- lines

    def _execute(self, line: str, overflow: bool) -> None:
        if overflow:
            self._error(GrblErrorCode.OVERFLOW)
        elif not line:
            self._ok()
        elif line.startswith("$"):
            self._system_command(line)
        elif self._locked() or self.machine.state() is MotionState.JOG:
            self._error(GrblErrorCode.SYSTEM_GC_LOCK)
        elif self._check_mode:
            rejection = self.machine.check(line)
            if rejection is None:
                self._ok()
            else:
                self._rejected(rejection)
        else:
            self._submit(line, line_number(line), line_effects(line))

    def _submit(self, line: str, number: int | None, effects: LineEffects) -> None:
        result = self.machine.submit(line, number)
        if result is Admission.PLANNER_FULL:
            self._waiting = _Resubmit(line, number, effects)
        elif isinstance(result, Rejected):
            self._rejected(result)
        elif effects.sync:
            self._waiting = _AwaitMotion(effects)
            self._resume()
        else:
            self._ok()

    def _after_motion(self, effects: LineEffects) -> None:
        if effects.offsets:
            self._wco_counter = 0
        if effects.pause:
            self.machine.feed_hold()
        if effects.end:
            self._line("[MSG:Pgm End]")
        if effects.probe:
            self._line(probe_line(self.machine.work_offsets(), inches=self._report_inches))
        self._ok()

    # ---- $ commands

    def _system_command(self, line: str) -> None:
        state = self.machine.state()
        idle_or_alarm = self._locked() or (state is MotionState.IDLE and not self._check_mode)
        word = line[1:]
        if word == "":
            self._line(HELP)
            self._ok()
        elif word.startswith("J"):
            if self._locked() or self._check_mode or \
                    state not in (MotionState.IDLE, MotionState.JOG):
                self._error(GrblErrorCode.IDLE_ERROR)
            elif not word.startswith("J="):
                self._error(GrblErrorCode.INVALID_STATEMENT)
            else:
                self._jog(word[2:])
        elif word == "$":
            if state in (MotionState.RUN, MotionState.HOLD_COMPLETE,
                         MotionState.HOLD_IN_PROGRESS):
                self._error(GrblErrorCode.IDLE_ERROR)
                return
            for text in settings_lines(self.machine.settings(), report_mask=self._report_mask,
                                       report_inches=self._report_inches):
                self._line(text)
            self._ok()
        elif word == "G":
            self._line(modal_line(self.machine.modal_state()))
            self._ok()
        elif word == "C":
            self._toggle_check_mode(state)
        elif word == "X":
            self._unlock()
        elif word[:1] in ("G", "C", "X", "$"):
            self._error(GrblErrorCode.INVALID_STATEMENT)
        elif not idle_or_alarm:
            self._error(GrblErrorCode.IDLE_ERROR)
        else:
            self._idle_command(word)

    def _idle_command(self, word: str) -> None:
        """A ``$`` command allowed only when idle or in alarm."""
        if word == "#":
            for text in parameter_lines(self.machine.work_offsets(),
                                        inches=self._report_inches):
                self._line(text)
            self._ok()
        elif word == "H":
            self._home()
        elif word == "TLS":
            rejected = self.machine.measure_tool()
            if rejected is not None:
                self._rejected(rejected)
            else:
                self._waiting = _AwaitMeasure()
                self._resume()
        elif word.startswith("H"):
            self._error(GrblErrorCode.INVALID_STATEMENT)
        elif word == "SLP":
            self._ok()
            self.machine.soft_reset()
            self._sleeping = True
            self._line("[MSG:Sleeping]")
        elif word == "I":
            for text in build_info_lines(self._build_text,
                                         planner_blocks=self.machine.planner_blocks(),
                                         rx_buffer_bytes=RX_BUFFER_BYTES):
                self._line(text)
            self._ok()
        elif word.startswith("I="):
            self._build_text = word[2:]
            self._ok()
        elif word.startswith("RST="):
            self._line(message("$RST is not supported: settings live in the machine file"))
            self._error(GrblErrorCode.INVALID_STATEMENT)
        elif word == "N":
            for index, text in enumerate(self._startup_lines):
                self._line(f"$N{index}={text}")
            self._ok()
        elif word.startswith("N"):
            self._store_startup_line(word[1:])
        else:
            self._store_setting(word)

    def _toggle_check_mode(self, state: MotionState) -> None:
        if self._check_mode:
            self._line("[MSG:Disabled]")
            self._ok()
            self._check_mode = False
            self._reset(announce_alarm=False)
        elif self._locked() or state is not MotionState.IDLE:
            self._error(GrblErrorCode.IDLE_ERROR)
        else:
            self._check_mode = True
            self._line("[MSG:Enabled]")
            self._ok()

    def _unlock(self) -> None:
        if self._locked():
            if self.machine.state() is MotionState.ALARM:
                self.machine.unlock()
            self._alarm = False
            self._fault_reported = False
            self._line("[MSG:Caution: Unlocked]")
        self._ok()

    def _home(self) -> None:
        if not self.machine.settings().homing:
            self._error(GrblErrorCode.SETTING_DISABLED)
            return
        self._fault_reported = False
        self.machine.home()
        self._waiting = _AwaitHoming()
        self._resume()

    def _homing_ended(self) -> None:
        # A failed homing is answered like grbl: the alarm, then ok for the $H.
        fault = self.machine.status().fault if self.machine.state() is MotionState.ALARM \
            else None
        if fault is not None:
            self._raise_alarm(fault)
        elif self.machine.state() is MotionState.ALARM:
            self._raise_alarm(Fault(int(AlarmCode.HOMING_FAIL_APPROACH), "homing failed"))
        else:
            self._alarm = False
            self._run_startup_lines()
        self._ok()

    def _jog(self, text: str) -> None:
        try:
            move = parse_jog(text, self._axes, self.machine.modal_state())
        except WordError as error:
            self._error(error.code)
            return
        self._answer_jog(move)

    def _answer_jog(self, move: JogMove) -> None:
        result: SubmitResult = self.machine.jog(move)
        if result is Admission.PLANNER_FULL:
            self._waiting = _Rejog(move)
        elif isinstance(result, Rejected):
            self._rejected(result)
        else:
            self._ok()

    def _store_startup_line(self, text: str) -> None:
        number = read_number(text, 0)
        if number is None:
            self._error(GrblErrorCode.BAD_NUMBER_FORMAT)
            return
        value, end = number
        if text[end:end + 1] != "=":
            self._error(GrblErrorCode.INVALID_STATEMENT)
            return
        if self._locked() or self.machine.state() is not MotionState.IDLE:
            self._error(GrblErrorCode.IDLE_ERROR)
            return
        index = int(value)
        if index != value or not 0 <= index < STARTUP_LINES:
            self._error(GrblErrorCode.INVALID_STATEMENT)
            return
        block = text[end + 1:]
        if block:
            result = self.machine.submit(block, line_number(block))
            if isinstance(result, Rejected):
                self._rejected(result)
                return
        self._startup_lines[index] = block
        self._ok()

    def _store_setting(self, text: str) -> None:
        parameter = read_number(text, 0)
        if parameter is None:
            self._error(GrblErrorCode.BAD_NUMBER_FORMAT)
            return
        number_value, end = parameter
        if text[end:end + 1] != "=":
            self._error(GrblErrorCode.INVALID_STATEMENT)
            return
        value_read = read_number(text, end + 1)
        if value_read is None:
            self._error(GrblErrorCode.BAD_NUMBER_FORMAT)
            return
        value, after = value_read
        if after != len(text) or number_value > 255 or number_value != int(number_value):
            self._error(GrblErrorCode.INVALID_STATEMENT)
            return
        if value < 0:
            self._error(GrblErrorCode.NEGATIVE_VALUE)
            return
        self._set(int(number_value), value)

    def _set(self, number: int, value: float) -> None:
        if number == 10:
            self._report_mask = int(value) & (REPORT_MACHINE_POSITION | REPORT_BUFFER_STATE)
            self._ok()
        elif number == 13:
            self._report_inches = bool(int(value))
            self._ok()
        elif number in NOT_APPLICABLE and number not in self.machine.settings().extra:
            shown, why = NOT_APPLICABLE[number]
            if setting_value(number, value) == setting_value(number, shown):
                self._ok()  # a settings backup written back unchanged
            else:
                self._line(message(f"${number} does not apply here: {why}"))
                self._error(GrblErrorCode.INVALID_STATEMENT)
        elif number in machine_setting_values(self.machine.settings()):
            if number == 20 and value and not self.machine.settings().homing:
                self._error(GrblErrorCode.SOFT_LIMIT_ERROR)
                return
            result = self.machine.set_setting(number, value)
            if isinstance(result, Rejected):
                self._rejected(result)
            else:
                if result is not None:
                    self._line(message(result.message))
                self._ok()
        else:
            self._error(GrblErrorCode.INVALID_STATEMENT)
