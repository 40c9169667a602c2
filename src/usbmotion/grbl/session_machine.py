"""The grbl front's machine (:class:`~usbmotion.grbl.interface.GrblMachine`) on a real
machine session, through an :class:`~usbmotion.session.operator.Operator`: G-code lines
go into the operator's feed, read as grbl reads them (the grbl dialect: a soft reset puts
the modal state back to power-on and clears G92) and planned with look-ahead as they come,
at most 15 moves not yet executed, as grbl's planner holds (so a sender's ``ok`` follows
the machine); jogs, homing, holds and resets are the operator's, and a status report is
the session's live model (the encoders' positions, the line the devices execute, the feed
they move at, each axis's following error). No call waits for motion or for a device:
the operator's worker alone talks to the devices, and when the machine is idle the
front's polls read it through :meth:`SessionMachine.poll`.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path

from usbmotion.errors import (
    ConfigError,
    FeedRateError,
    GCodeError,
    MachineStateError,
    PlanningError,
    UnsupportedGCodeError,
    UsbMotionError,
)
from usbmotion.files import write_text_atomically
from usbmotion.grbl.codes import AlarmCode, GrblErrorCode
from usbmotion.grbl.interface import (
    Admission,
    AxisSettings,
    Fault,
    JogMove,
    MachineSettings,
    MachineStatus,
    ModalState,
    MotionState,
    Rejected,
    SubmitResult,
    Taken,
    WorkOffsets,
)
from usbmotion.grbl.reports import machine_setting_values
from usbmotion.host.config import MachineConfig
from usbmotion.host.config_file import Key, Value, changed_config
from usbmotion.motion.dialects import Dialect
from usbmotion.motion.gcode import GCodeStream
from usbmotion.motion.moves import AXIS_ORDER
from usbmotion.protocol import FaultCode
from usbmotion.session.live import LiveSnapshot
from usbmotion.session.operator import IdleReader, Operator
from usbmotion.session.planning import machine_axes, program_axes
from usbmotion.session.probing import ProbeFailedError, probing_line
from usbmotion.session.state import MachineState


def rejection(error: GCodeError | PlanningError | MachineStateError) -> Rejected:
    """grbl's error for a line the session refused, by the kind of refusal."""
    if isinstance(error, MachineStateError):
        code = GrblErrorCode.SYSTEM_GC_LOCK
    elif isinstance(error, PlanningError):
        code = GrblErrorCode.INVALID_TARGET  # a soft limit, or a move it cannot make
    elif isinstance(error, UnsupportedGCodeError):
        code = GrblErrorCode.UNSUPPORTED_COMMAND
    elif isinstance(error, FeedRateError):
        code = GrblErrorCode.UNDEFINED_FEED_RATE
    else:
        code = GrblErrorCode.EXPECTED_COMMAND_LETTER
    return Rejected(code, str(error))


_FIXED_ON = {20: "soft limits are the travel ($130..), kept on a homed machine",
             21: "every device stops its axis at a limit switch",
             22: "homing gives the machine coordinates soft limits need"}
_HOMING_KEYS = {24: ("slow_speed_mm_s", 1 / 60.0), 25: ("speed_mm_s", 1 / 60.0),
                27: ("pull_off_mm", 1.0)}
"""grbl's homing settings (one for every axis): the machine file's key, and the factor
from grbl's unit (mm/min) to its own."""


class SessionMachine:
    """A machine session, as the grbl front sees it.

    Parameters:
        operator: the session's operator (its worker runs the motion).
    """

    def __init__(self, operator: Operator, *, keep_settings: bool = False) -> None:
        self.operator = operator
        operator.dialect = Dialect.GRBL  # lines are read, and reset, as grbl reads them
        self.keep_settings = keep_settings
        """Settings changed with ``$N=value`` are written to the machine file (else they
        hold for the session only)."""
        self._file_text: str | None = None
        """The machine file's text with the changes taken so far (read at the first)."""
        self.session = operator.session
        self.config = self.session.config
        self._axes = tuple(program_axes(self.config))
        self._fault: Fault | None = None
        self._homing = False
        self._measured: str | Rejected = ""
        """What the last tool measurement found (``$TLS``), or why it failed."""
        self._checker: GCodeStream | None = None
        self._reading = IdleReader(operator, on_error=self._unreadable,
                                   name="usbmotion-grbl-read")

    # --- what the front polls --------------------------------------------------------------

    def start(self) -> None:
        """Read the machine while it is idle, on a thread of its own (:class:`IdleReader`:
        its watchdogs fed, its positions and switches current)."""
        self._reading.start()

    def close(self) -> None:
        """Stop reading the machine."""
        self._reading.close()

    def _unreadable(self, error: UsbMotionError) -> None:
        self._fault = Fault(AlarmCode.ABORT_CYCLE, f"the machine cannot be read: {error}")

    def poll(self) -> None:
        """Take up how the last action ended (a fault, a failed homing)."""
        if not self.operator.busy:
            self._take_ending()

    def _take_ending(self) -> None:
        if self._homing:
            self._homing = False
            if self.operator.last_error:
                self._fault = Fault(AlarmCode.HOMING_FAIL_APPROACH, self.operator.last_error)
        failure = self.operator.last_failure
        if isinstance(failure, ProbeFailedError) and self._fault is None:
            alarm = (AlarmCode.PROBE_FAIL_INITIAL if failure.at_start
                     else AlarmCode.PROBE_FAIL_CONTACT)
            self._fault = Fault(alarm, str(failure))
            self.operator.last_failure = None
        report = self.operator.last_report
        if report is not None and report.faults and self._fault is None:
            first = report.faults[0]
            alarm = (AlarmCode.HARD_LIMIT if first.code == FaultCode.LIMIT_SWITCH
                     else AlarmCode.ABORT_CYCLE)
            self._fault = Fault(alarm, first.fault, first.axis, first.line or None)
            self.operator.last_report = None

    def axes(self) -> tuple[str, ...]:
        return self._axes

    def state(self) -> MotionState:
        self.poll()
        session = self.session
        state = session.state
        if self._fault is not None or state is MachineState.ALARM:
            return MotionState.ALARM
        if state is MachineState.HOMING or self._homing:
            return MotionState.HOMING
        if session.jogging or state is MachineState.JOG:
            return MotionState.JOG
        if state is MachineState.HOLD:
            return MotionState.HOLD_COMPLETE if session.held else MotionState.HOLD_IN_PROGRESS
        if state is MachineState.PAUSED:
            return MotionState.HOLD_COMPLETE
        if state is MachineState.STOPPING:
            return MotionState.HOLD_IN_PROGRESS
        if session.hold_requested:  # asked while idle: the next motion starts held
            return MotionState.HOLD_IN_PROGRESS if state is MachineState.RUN \
                else MotionState.HOLD_COMPLETE
        if self.operator.busy:
            return MotionState.RUN
        if not session.is_homed and not self.operator.unlocked:
            return MotionState.ALARM
        return MotionState.IDLE

    def status(self) -> MachineStatus:
        now = self.session.live.read()
        where = tuple(now.axes[axis].measured_mm for axis in self._axes)
        error = tuple(now.axes[axis].following_error_mm for axis in self._axes)
        limits = frozenset(name for name, axis in now.axes.items() if axis.limit)
        moving = self.operator.busy and not now.at_rest
        spindle = now.spindle.measured_rpm if now.spindle is not None else 0.0
        turning = now.spindle.commanded_rpm if now.spindle is not None else float(
            now.outputs.get("laser", 0))
        accessories = ("S" if turning > 0 else "C" if turning < 0 else "") + (
            "F" if now.outputs.get("flood") else "") + ("M" if now.outputs.get("mist") else "")
        return MachineStatus(where, self._work_offset(now), now.feed_mm_min if moving else 0.0,
                             now.line or None if self.operator.busy else None, error, limits,
                             self._fault, spindle_rpm=spindle, probe=now.probe,
                             accessories=accessories)

    def _work_offset(self, now: LiveSnapshot) -> tuple[float, ...]:
        return tuple(now.work_offset_mm.get(axis, 0.0) for axis in self._axes)

    # --- lines --------------------------------------------------------------------------------

    def submit(self, line: str, line_number: int | None) -> SubmitResult:
        if self._fault is not None:
            return Rejected(GrblErrorCode.SYSTEM_GC_LOCK, "the machine is in alarm: $X or $H")
        try:
            taken = self.operator.submit(line)
        except (GCodeError, PlanningError, MachineStateError) as error:
            return rejection(error)
        return Admission.ACCEPTED if taken else Admission.PLANNER_FULL

    def check(self, line: str) -> Rejected | None:
        checker = self._checker
        if checker is None:
            machine = machine_axes(self.config)
            where = self.session.live.read().machine_mm(measured=False)
            checker = self._checker = GCodeStream(
                file="<check>", machine=machine, dialect=Dialect.GRBL,
                start=tuple(where.get(a, 0.0) for a in machine.axes))
        probing = probing_line(line)
        try:
            checker.feed(line if probing is None else probing[1])
        except GCodeError as error:
            return rejection(error)
        return None

    def motion_done(self) -> bool:
        if self.operator.busy:
            return False
        self._take_ending()  # a failure (a probe that found nothing) is an alarm, not done
        return self._fault is None

    def planner_blocks(self) -> int:
        return self.operator.window

    def planner_blocks_free(self) -> int:
        feed = self.operator.feed
        if feed is None or feed.closed:
            return self.planner_blocks()
        return feed.blocks_free

    # --- real-time ----------------------------------------------------------------------------

    def feed_hold(self) -> None:
        if self.session.jogging:
            self.operator.jog_cancel()
        else:
            self.operator.hold()

    def cycle_start(self) -> None:
        self.operator.resume()

    def soft_reset(self) -> None:
        self._checker = None
        if self.session.jogging:
            self.operator.jog_cancel()
        else:
            self.operator.reset()

    def attach_front(self, lines_waiting: Callable[[], bool]) -> None:
        self.operator.lines_waiting = lines_waiting

    def jog(self, move: JogMove) -> SubmitResult:
        if self.operator.busy:
            return Admission.PLANNER_FULL
        if not self.session.is_homed:
            return Rejected(GrblErrorCode.TRAVEL_EXCEEDED,
                            "a jog needs a homed machine (its soft limits): $H")
        now = self.session.live.read()
        where = now.machine_mm(measured=False)
        offset = dict(zip(self._axes, self._work_offset(now), strict=True))
        targets: dict[str, float] = {}
        for axis, value in move.words_mm.items():
            if axis not in self._axes:
                return Rejected(GrblErrorCode.UNSUPPORTED_COMMAND,
                                f"the machine has no axis {axis}")
            if move.incremental:
                targets[axis] = where.get(axis, 0.0) + value
            else:
                targets[axis] = value + (0.0 if move.machine_coordinates else offset[axis])
        for axis, target in targets.items():
            low, high = self.config.axis(axis).travel_mm
            if not low - 1e-9 <= target <= high + 1e-9:
                return Rejected(GrblErrorCode.TRAVEL_EXCEEDED,
                                f"{axis} to {target:.3f} mm is beyond its travel"
                                f" {low:g}..{high:g} mm")
        if not math.isfinite(move.feed_mm_min) or move.feed_mm_min <= 0:
            return Rejected(GrblErrorCode.UNDEFINED_FEED_RATE, "a jog needs a feed rate")
        try:
            self.operator.jog(targets, feed_mm_min=move.feed_mm_min, absolute=True)
        except (MachineStateError, UsbMotionError) as error:
            return Rejected(GrblErrorCode.SYSTEM_GC_LOCK, str(error))
        return Admission.ACCEPTED

    def jog_cancel(self) -> None:
        self.operator.jog_cancel()

    def set_feed_override(self, percent: int) -> None:
        self.session.set_feed_override(min(200, max(10, percent)))

    def set_rapid_override(self, percent: int) -> None:
        self.session.set_rapid_override(percent if percent in (25, 50, 100) else 100)

    def set_spindle_override(self, percent: int) -> None:
        self.session.set_spindle_override(percent)

    def home(self) -> None:
        self._fault = None
        try:
            self.operator.home()
        except MachineStateError as error:
            self._fault = Fault(AlarmCode.HOMING_FAIL_APPROACH, str(error))
            return
        self._homing = True

    def unlock(self) -> None:
        self._fault = None
        self.operator.unlocked = True
        if self.session.state is MachineState.ALARM and not self.operator.busy:
            self.operator.do(self.session.reset)

    # --- settings and state ---------------------------------------------------------------------

    def settings(self) -> MachineSettings:
        config = self.config
        # A wrapped rotary axis turns on without end: no travel ($13x 0, grbl's "none").
        axes = tuple(AxisSettings(a.counts_per_mm, a.max_velocity_mm_s * 60.0, a.max_accel_mm_s2,
                                  0.0 if a.wrapped else a.travel_mm[1] - a.travel_mm[0])
                     for a in (config.axis(name) for name in self._axes))
        first = config.axis(self._axes[0])
        mask = sum(1 << index for index, name in enumerate(self._axes)
                   if config.axis(name).homing.direction < 0)
        return MachineSettings(axes, junction_deviation_mm=config.junction_deviation_mm,
                               arc_tolerance_mm=config.arc_tolerance_mm, soft_limits=True,
                               hard_limits=True, homing=True, homing_dir_mask=mask,
                               homing_feed_mm_min=first.homing.slow_speed_mm_s * 60.0,
                               homing_seek_mm_min=first.homing.speed_mm_s * 60.0,
                               homing_pull_off_mm=first.homing.pull_off_mm,
                               extra={**_spindle_settings(config), **_step_settings(config)})

    def set_setting(self, number: int, value: float) -> Rejected | Taken | None:
        current = self._setting_values().get(number)
        if current is not None and math.isclose(value, current, rel_tol=1e-6, abs_tol=5e-4):
            return None  # a backup written back
        changes = self._changes(number, value)
        if isinstance(changes, Rejected):
            return changes
        if not changes:
            return None
        if self.operator.busy:
            return Rejected(GrblErrorCode.IDLE_ERROR,
                            f"${number} changes only while the machine is idle")
        try:
            if self._file_text is None:
                self._file_text = Path(self.config.path).read_text(encoding="utf-8")
            config, text = changed_config(self.config, self._file_text, changes)
            unhomed = self.operator.reconfigure(config)
        except (OSError, UnicodeDecodeError) as error:
            return Rejected(GrblErrorCode.INVALID_STATEMENT,
                            f"${number}: the machine file {self.config.path} cannot be"
                            f" read: {error}")
        except ConfigError as error:
            return Rejected(GrblErrorCode.INVALID_STATEMENT,
                            f"${number}={value:g} refused: {error}")
        except MachineStateError as error:
            return Rejected(GrblErrorCode.IDLE_ERROR, f"${number}: {error}")
        self.config = self.session.config
        self._file_text = text
        self._checker = None
        notes = []
        if self.keep_settings:
            try:
                write_text_atomically(config.path, text)
            except OSError as error:
                notes.append(f"taken for this session; the machine file {config.path} could"
                             f" not be written: {error}")
        else:
            notes.append("taken for this session (the built-in machine: give usbmotion grbl"
                         " -m FILE to keep settings)")
        if unhomed:
            notes.append(f"home again ($H): the change moved {', '.join(unhomed)}'s homed"
                         " position")
        return Taken("; ".join(notes)) if notes else None

    def _changes(self, number: int, value: float) -> dict[Key, Value] | Rejected:
        """The machine file's keys a grbl setting maps onto, given its new value."""
        axes = self._axes
        if number == 0:
            steppers = [name for name in self.config.axis_names
                        if self.config.axis(name).stepper is not None]
            if not steppers:
                return Rejected(GrblErrorCode.INVALID_STATEMENT,
                                "$0 does not apply here: servo axes take no step pulses")
            return {("axes", name, "step_pulse_ns"): round(value * 1000.0)
                    for name in steppers}
        if number in (11, 12):
            key = "junction_deviation_mm" if number == 11 else "arc_tolerance_mm"
            return {(key,): float(value)}
        if number in _FIXED_ON:
            if value == 1:
                return {}
            return Rejected(GrblErrorCode.INVALID_STATEMENT,
                            f"${number} stays 1 here: {_FIXED_ON[number]}")
        if number == 23:
            if value != int(value) or not 0 <= value < 1 << len(axes):
                return Rejected(GrblErrorCode.INVALID_STATEMENT,
                                f"$23={value:g}: a mask of the axes' bits,"
                                f" 0..{(1 << len(axes)) - 1}")
            return {("axes", name, "homing", "direction"): -1 if int(value) >> i & 1 else 1
                    for i, name in enumerate(axes)}
        if number in _HOMING_KEYS:
            key, scale = _HOMING_KEYS[number]
            return {("axes", name, "homing", key): round(value * scale, 6) for name in axes}
        group, index = divmod(number, 10)
        if group not in (10, 11, 12, 13) or index >= len(axes):
            return Rejected(GrblErrorCode.INVALID_STATEMENT,
                            f"${number} is no setting of this machine")
        name = axes[index]
        if group == 10:
            key = "steps_per_mm" if self.config.axis(name).stepper is not None else "counts_per_mm"
            return {("axes", name, key): float(value)}
        if group == 11:
            return {("axes", name, "max_velocity_mm_s"): round(value / 60.0, 6)}
        if group == 12:
            return {("axes", name, "max_accel_mm_s2"): float(value)}
        axis = self.config.axis(name)
        low, high = axis.travel_mm
        length = float(value)
        travel = [low, low + length] if axis.homing.direction < 0 else [high - length, high]
        return {("axes", name, "travel_mm"): travel}

    def _setting_values(self) -> dict[int, float]:
        """The mapped settings' values as ``$$`` shows them (a sender restoring a backup
        writes them back: that is no change)."""
        return machine_setting_values(self.settings())

    def work_offsets(self) -> WorkOffsets:
        feed = self.operator.feed
        offsets = feed.program().offsets if feed is not None else self.session.work_offsets()

        def pick(point: tuple[float, ...]) -> tuple[float, ...]:
            return tuple(point[AXIS_ORDER.index(a)] for a in self._axes)

        tool_z = 0.0
        if feed is not None:  # the lines' G92 as it applies now (grbl keeps it volatile)
            modes = feed.modes()
            g92 = tuple(modes.g92_mm)
            if "Z" in self._axes and modes.tool_mm:
                tool_z = modes.tool_mm[self._axes.index("Z")]
        else:
            g92 = pick(offsets.g92) if offsets.g92_enabled else (0.0,) * len(self._axes)
        probe = self.session.last_probe
        found = (tuple(probe.position_mm.get(a, 0.0) for a in self._axes) if probe is not None
                 else ())
        return WorkOffsets(tuple(pick(p) for p in offsets.g5x[:6]), pick(offsets.g28),
                           pick(offsets.g30), g92, probe=found,
                           probe_succeeded=probe is not None and probe.tripped,
                           tool_length_offset=tool_z)

    def measure_tool(self) -> Rejected | None:
        session = self.session
        if self._fault is not None:
            return Rejected(GrblErrorCode.SYSTEM_GC_LOCK, "the machine is in alarm: $X or $H")
        if self.config.tool_setter is None:
            return Rejected(GrblErrorCode.SETTING_DISABLED,
                            "no [tool_setter] table in the machine file: no tool to measure on")
        if not session.is_homed:
            return Rejected(GrblErrorCode.SYSTEM_GC_LOCK,
                            "$TLS needs a homed machine: $H first")
        feed = self.operator.feed
        tool = feed.modes().tool if feed is not None else session.live.read().tool
        self._measured = ""
        operator = self.operator

        def go() -> None:
            applied = ""
            try:
                found = session.measure_tool(
                    tool, write=self.config.tool_table is not None and tool > 0)
                if found.length_mm is not None:  # grblHAL's way: the active offset at once
                    applied = f"G43.1 Z{found.length_mm:.4f}"
                self._measured = found.describe()
            except ProbeFailedError:
                raise  # alarm 5, as a probe's (motion_done)
            except UsbMotionError as error:
                self._measured = Rejected(GrblErrorCode.INVALID_STATEMENT, str(error))
            finally:
                operator.measured_tool(applied)

        operator.do(go)
        return None

    def tool_measurement(self) -> str | Rejected:
        return self._measured

    def modal_state(self) -> ModalState:
        feed = self.operator.feed
        if feed is None:
            return ModalState()
        modes = feed.modes()
        motion = modes.motion_x10
        system = modes.coordinate_system
        spindle = self.session.live.read().spindle
        rpm = spindle.commanded_rpm if spindle is not None else 0.0
        return ModalState(
            spindle="M3" if rpm > 0 else "M4" if rpm < 0 else "M5", spindle_speed=abs(rpm),
            motion="G80" if motion < 0 else f"G{motion // 10}" + (
                f".{motion % 10}" if motion % 10 else ""),
            coordinate_system=f"G{53 + system}" if system <= 6 else f"G59.{system - 6}",
            plane=f"G{modes.plane}", units="G20" if modes.inches else "G21",
            distance="G91" if modes.incremental else "G90", tool=modes.tool,
            feed_rate_mode="G93" if modes.inverse_time else "G94",
            feed=modes.feed_mm_min / (25.4 if modes.inches and not modes.inverse_time
                                      else 1.0))


def _step_settings(config: MachineConfig) -> dict[int, float]:
    """``$0``, the step pulse in microseconds, on a machine with stepper axes: the first
    stepper axis's ``step_pulse_ns`` (grbl has one for every axis; writing it sets every
    stepper axis's)."""
    for name in config.axis_names:
        stepper = config.axis(name).stepper
        if stepper is not None:
            return {0: stepper.step_pulse_ns / 1000.0}
    return {}


def _spindle_settings(config: MachineConfig) -> dict[int, float]:
    """``$30`` (the spindle's max_rpm, or the laser's S of full power) and ``$32`` (laser
    mode: 1 on a machine with a laser output)."""
    if config.spindle is not None:
        return {30: config.spindle.max_rpm}
    if config.outputs is not None and "laser" in config.outputs.pins:
        return {30: config.outputs.laser_max_s, 32: 1.0}
    return {}


__all__ = ["SessionMachine"]
