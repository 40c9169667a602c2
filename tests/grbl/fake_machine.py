"""A simulated machine behind the grbl front: straight lines at the programmed feed (no
acceleration), on a clock the test gives it (virtual time, or the wall clock for real
senders), and a record of every move it finished, to compare with the program's path."""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field, replace

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
    WorkOffsets,
)
from usbmotion.grbl.lines import MM_PER_INCH, WordError, words

PLANNER_BLOCKS = 15
HOLD_DECEL_S = 0.05
"""How long a hold takes to come to rest."""
HOMING_S = 0.3
FOLLOWING_ERROR_S = 0.0005
"""Following error while moving: the distance covered in this time, per axis."""


@dataclass(frozen=True, slots=True)
class Move:
    """A straight move to ``target_mm`` (machine coordinates)."""

    target_mm: tuple[float, ...]
    feed_mm_min: float
    rapid: bool = False
    jog: bool = False
    line_number: int | None = None


@dataclass(frozen=True, slots=True)
class Dwell:
    seconds: float
    line_number: int | None = None


Block = Move | Dwell


@dataclass(frozen=True, slots=True)
class Done:
    """A move the machine finished: where it ended and at which programmed feed."""

    target_mm: tuple[float, ...]
    feed_mm_min: float
    rapid: bool
    jog: bool
    line_number: int | None


@dataclass(slots=True)
class _Parser:
    modal: ModalState = field(default_factory=ModalState)
    coordinate_systems: list[tuple[float, ...]] = field(default_factory=list)
    g92: tuple[float, ...] = ()


_AXIS_LIMIT_MM = 1000.0


class FakeMachine:
    """A :class:`usbmotion.grbl.interface.GrblMachine` in simulated time.

    Parameters:
        clock: seconds now (a virtual clock the test advances, or ``time.monotonic``).
        axes: the axis letters.
        homing: homing enabled ($22); the machine then starts in alarm, not homed.
        max_rate_mm_min: every axis's rapid rate.
        max_travel_mm: every axis's travel (jogs beyond it are refused).
        homing_s: how long the homing cycle takes.
    """

    def __init__(self, clock: Callable[[], float], *, axes: tuple[str, ...] = ("X", "Y", "Z"),
                 homing: bool = True, max_rate_mm_min: float = 3000.0,
                 max_travel_mm: float = 300.0, homing_s: float = HOMING_S) -> None:
        self._clock = clock
        self._axes = axes
        self._homing_s = homing_s
        self._last_s = clock()
        n = len(axes)
        self.position_mm: tuple[float, ...] = (0.0,) * n
        self._queue: deque[Block] = deque()
        self._block_start_s: float | None = None
        self._segment_from: tuple[float, ...] = self.position_mm
        self._speed_mm_s = 0.0
        self._hold: str | None = None  # None, "decel" or "held"
        self._hold_done_s = 0.0
        self._homing_done_s: float | None = None
        self.homed = not homing
        self._fault: Fault | None = None
        self._settings = MachineSettings(
            axes=tuple(AxisSettings(counts_per_mm=1000.0, max_rate_mm_min=max_rate_mm_min,
                                    accel_mm_s2=500.0, max_travel_mm=max_travel_mm)
                       for _ in axes),
            homing=homing)
        self._parser = _Parser(coordinate_systems=[(0.0,) * n for _ in range(6)],
                               g92=(0.0,) * n)
        self._check_parser: _Parser | None = None
        self._planned_end_mm = self.position_mm
        self._jog_end_mm = self.position_mm
        self.feed_override = 100
        self.rapid_override = 100
        self.done: list[Done] = []
        self.fault_on_line: tuple[int, Fault] | None = None
        """Raise this fault when the block of this line number starts."""
        self.fault_after_moves: tuple[int, Fault] | None = None
        """Raise this fault when a block starts after this many moves are done."""
        self.homing_fails = False
        self.homings = 0
        """Homing cycles completed (readable from another thread: the machine itself is
        driven from the server's thread only)."""
        self.limit_pins: frozenset[str] = frozenset()
        """The axis letters whose limit switch reads triggered."""
        self.calls: list[str] = []
        """The control calls received, in order (feed_hold, cycle_start, soft_reset...)."""
        self.lines_waiting: Callable[[], bool] = lambda: False
        """The front's question (attach_front): lines on their way?"""

    # ---- time

    def _advance(self) -> None:
        now = self._clock()
        while self._last_s < now:
            if self._homing_done_s is not None:
                if now < self._homing_done_s:
                    self._last_s = now
                    return
                self._last_s = self._homing_done_s
                self._finish_homing()
                continue
            if not self._queue or self._fault is not None:
                self._last_s = now
                return
            if self._hold == "held":
                self._last_s = now
                return
            end = now
            if self._hold == "decel":
                end = min(now, self._hold_done_s)
            self._run_until(end)
            if self._hold == "decel" and self._last_s >= self._hold_done_s:
                self._hold = "held"
                self._speed_mm_s = 0.0

    def _run_until(self, end_s: float) -> None:
        block = self._queue[0]
        if self._block_start_s is None:
            self._block_start_s = self._last_s
            self._segment_from = self.position_mm
            if self._fault_starts(block):
                return
        if isinstance(block, Dwell):
            finish = self._block_start_s + block.seconds
            self._speed_mm_s = 0.0
            if finish <= end_s:
                self._last_s = finish
                self._next_block()
            else:
                self._last_s = end_s
            return
        speed = self._speed_for(block)
        self._speed_mm_s = speed
        remaining = _distance(self.position_mm, block.target_mm)
        available = (end_s - self._last_s) * speed
        if remaining <= available or remaining < 1e-12:
            self._last_s += remaining / speed if speed > 0 else 0.0
            self.position_mm = block.target_mm
            self.done.append(Done(block.target_mm, block.feed_mm_min, block.rapid, block.jog,
                                  block.line_number))
            self._next_block()
        else:
            fraction = available / remaining
            self.position_mm = tuple(p + (t - p) * fraction
                                     for p, t in zip(self.position_mm, block.target_mm,
                                                     strict=True))
            self._last_s = end_s

    def _speed_for(self, block: Move) -> float:
        if block.rapid:
            return self._settings.axes[0].max_rate_mm_min / 60 * self.rapid_override / 100
        if block.jog:
            return block.feed_mm_min / 60
        return block.feed_mm_min / 60 * self.feed_override / 100

    def _next_block(self) -> None:
        self._queue.popleft()
        self._block_start_s = None
        if not self._queue:
            self._speed_mm_s = 0.0

    def _fault_starts(self, block: Block) -> bool:
        if self.fault_on_line is not None and block.line_number == self.fault_on_line[0]:
            self._fault = self.fault_on_line[1]
            self.fault_on_line = None
        elif self.fault_after_moves is not None and \
                len(self.done) >= self.fault_after_moves[0]:
            self._fault = self.fault_after_moves[1]
            self.fault_after_moves = None
        else:
            return False
        self._drop_queue()
        return True

    def _drop_queue(self) -> None:
        self._queue.clear()
        self._block_start_s = None
        self._speed_mm_s = 0.0
        self._hold = None
        self._planned_end_mm = self._jog_end_mm = self.position_mm

    def _finish_homing(self) -> None:
        self._homing_done_s = None
        if self.homing_fails:
            self._fault = Fault(int(AlarmCode.HOMING_FAIL_APPROACH),
                                "homing: the switch was not found within the search distance",
                                axis=self._axes[0])
            return
        self.position_mm = (0.0,) * len(self._axes)
        self._planned_end_mm = self._jog_end_mm = self.position_mm
        self.homed = True
        self.homings += 1

    # ---- GrblMachine

    def axes(self) -> tuple[str, ...]:
        return self._axes

    def state(self) -> MotionState:
        self._advance()
        if self._homing_done_s is not None:
            return MotionState.HOMING
        if self._fault is not None or not self.homed:
            return MotionState.ALARM
        if self._hold == "decel":
            return MotionState.HOLD_IN_PROGRESS
        if self._hold == "held":
            return MotionState.HOLD_COMPLETE
        if not self._queue:
            return MotionState.IDLE
        first = self._queue[0]
        return MotionState.JOG if isinstance(first, Move) and first.jog else MotionState.RUN

    def status(self) -> MachineStatus:
        state = self.state()
        moving = state in (MotionState.RUN, MotionState.JOG, MotionState.HOLD_IN_PROGRESS)
        block = self._queue[0] if self._queue else None
        following = tuple(0.0 for _ in self._axes)
        if moving and isinstance(block, Move):
            length = _distance(self._segment_from, block.target_mm) or 1.0
            following = tuple((t - f) / length * self._speed_mm_s * FOLLOWING_ERROR_S
                              for f, t in zip(self._segment_from, block.target_mm,
                                              strict=True))
        return MachineStatus(
            machine_position_mm=self.position_mm,
            work_offset_mm=self._work_offset(self._parser),
            feed_mm_min=self._speed_mm_s * 60 if moving else 0.0,
            line_number=block.line_number if block is not None else None,
            following_error_mm=following,
            limit_pins=self.limit_pins,
            fault=self._fault,
        )

    def submit(self, line: str, line_number: int | None) -> SubmitResult:
        self._advance()
        if len(self._queue) >= PLANNER_BLOCKS:
            return Admission.PLANNER_FULL
        parsed = self._parse(line, self._parser, self._planned_end_mm)
        if isinstance(parsed, Rejected):
            return parsed
        for block in parsed:
            self._queue.append(block)
            if isinstance(block, Move):
                self._planned_end_mm = block.target_mm
        return Admission.ACCEPTED

    def check(self, line: str) -> Rejected | None:
        if self._check_parser is None:
            self._check_parser = replace(self._parser, coordinate_systems=list(
                self._parser.coordinate_systems))
        parsed = self._parse(line, self._check_parser, self._planned_end_mm)
        return parsed if isinstance(parsed, Rejected) else None

    def motion_done(self) -> bool:
        self._advance()
        return not self._queue

    def planner_blocks(self) -> int:
        return PLANNER_BLOCKS

    def planner_blocks_free(self) -> int:
        self._advance()
        return PLANNER_BLOCKS - len(self._queue)

    def attach_front(self, lines_waiting: Callable[[], bool]) -> None:
        self.lines_waiting = lines_waiting

    def feed_hold(self) -> None:
        self._advance()
        self.calls.append("feed_hold")
        if self._hold is not None:
            return
        if self._queue and self._speed_mm_s > 0:
            self._hold = "decel"
            self._hold_done_s = self._last_s + HOLD_DECEL_S
        else:
            self._hold = "held"

    def cycle_start(self) -> None:
        self._advance()
        self.calls.append("cycle_start")
        if self._hold == "held":
            self._hold = None

    def soft_reset(self) -> None:
        self._advance()
        self.calls.append("soft_reset")
        self._homing_done_s = None
        self._drop_queue()
        self._check_parser = None
        modal = self._parser.modal
        self._parser.modal = ModalState(coordinate_system=modal.coordinate_system)
        self._parser.g92 = (0.0,) * len(self._axes)

    def jog(self, move: JogMove) -> SubmitResult:
        self._advance()
        if len(self._queue) >= PLANNER_BLOCKS:
            return Admission.PLANNER_FULL
        start = self._jog_end_mm if self._queue else self.position_mm
        offset = (0.0,) * len(self._axes) if move.machine_coordinates \
            else self._work_offset(self._parser)
        target = list(start)
        for index, axis in enumerate(self._axes):
            if axis in move.words_mm:
                value = move.words_mm[axis]
                target[index] = start[index] + value if move.incremental and \
                    not move.machine_coordinates else value + offset[index]
        if any(abs(value) > self._settings.axes[i].max_travel_mm
               for i, value in enumerate(target)):
            return Rejected(int(GrblErrorCode.TRAVEL_EXCEEDED), "jog target beyond the travel")
        block = Move(tuple(target), move.feed_mm_min, jog=True, line_number=move.line_number)
        self._queue.append(block)
        self._jog_end_mm = self._planned_end_mm = block.target_mm
        return Admission.ACCEPTED

    def jog_cancel(self) -> None:
        self._advance()
        self.calls.append("jog_cancel")
        self._drop_queue()

    def set_feed_override(self, percent: int) -> None:
        self._advance()
        self.calls.append(f"feed_override {percent}")
        self.feed_override = percent

    def set_rapid_override(self, percent: int) -> None:
        self._advance()
        self.calls.append(f"rapid_override {percent}")
        self.rapid_override = percent

    def set_spindle_override(self, percent: int) -> None:
        self._advance()
        self.calls.append(f"spindle_override {percent}")

    def home(self) -> None:
        self._advance()
        self.calls.append("home")
        self._fault = None
        self._homing_done_s = self._last_s + self._homing_s

    def unlock(self) -> None:
        self.calls.append("unlock")
        self._fault = None
        self.homed = True

    def settings(self) -> MachineSettings:
        return self._settings

    def set_setting(self, number: int, value: float) -> Rejected | None:
        if number == 22:
            self._settings = replace(self._settings, homing=bool(value))
            return None
        if number == 20:
            self._settings = replace(self._settings, soft_limits=bool(value))
            return None
        if 110 <= number < 110 + len(self._axes):
            axes = list(self._settings.axes)
            axes[number - 110] = replace(axes[number - 110], max_rate_mm_min=value)
            self._settings = replace(self._settings, axes=tuple(axes))
            return None
        return Rejected(int(GrblErrorCode.INVALID_STATEMENT),
                        f"${number} is read from the machine file; edit it there")

    def measure_tool(self) -> Rejected | None:
        self.calls.append("measure_tool")
        return Rejected(int(GrblErrorCode.SETTING_DISABLED), "no tool setter")

    def tool_measurement(self) -> str | Rejected:
        return ""

    def work_offsets(self) -> WorkOffsets:
        zero = (0.0,) * len(self._axes)
        return WorkOffsets(coordinate_systems=tuple(self._parser.coordinate_systems),
                           g28=zero, g30=zero, g92=self._parser.g92)

    def modal_state(self) -> ModalState:
        return self._parser.modal

    # ---- its G-code

    def _work_offset(self, parser: _Parser) -> tuple[float, ...]:
        system = int(parser.modal.coordinate_system[1:]) - 54
        return tuple(c + g for c, g in zip(parser.coordinate_systems[system], parser.g92,
                                           strict=True))

    def _parse(self, line: str, parser: _Parser,
               start_mm: tuple[float, ...]) -> list[Block] | Rejected:
        try:
            found = words(line)
        except WordError as error:
            return Rejected(int(error.code), f"{line!r} is not G-code words")
        modal = parser.modal
        values: dict[str, float] = {}
        g_codes: list[int] = []
        m_codes: list[int] = []
        for letter, value in found:
            if letter == "G":
                g_codes.append(round(value * 10))
            elif letter == "M":
                m_codes.append(round(value))
            elif letter in values:
                return Rejected(int(GrblErrorCode.WORD_REPEATED), f"{letter} repeated")
            else:
                values[letter] = value
        number = int(values.pop("N")) if "N" in values else None
        values_g10 = 0
        motion = modal.motion
        dwell: float | None = None
        set_offsets: int | None = None
        for code in g_codes:
            if code in (0, 10):
                motion = f"G{code // 10}"
            elif code == 40:
                dwell = values.pop("P", None)
                if dwell is None:
                    return Rejected(int(GrblErrorCode.VALUE_WORD_MISSING), "G4 needs P")
            elif code in (200, 210):
                modal = replace(modal, units=f"G{code // 10}")
            elif code in (900, 910):
                modal = replace(modal, distance=f"G{code // 10}")
            elif code in (170, 940):
                pass
            elif code in (540, 550, 560, 570, 580, 590):
                modal = replace(modal, coordinate_system=f"G{code // 10}")
            elif code == 100:
                set_offsets = int(values.pop("L", 0))
                system = int(values.pop("P", 0)) or (int(modal.coordinate_system[1:]) - 53)
                values_g10 = system
            elif code == 920:
                set_offsets = 92
            else:
                return Rejected(int(GrblErrorCode.UNSUPPORTED_COMMAND),
                                f"G{code / 10:g} is not supported by the test machine")
        for code in m_codes:
            if code in (3, 4, 5):
                modal = replace(modal, spindle=f"M{code}")
            elif code in (7, 8, 9):
                modal = replace(modal, coolant=f"M{code}")
            elif code in (0, 2, 30):
                pass
            else:
                return Rejected(int(GrblErrorCode.UNSUPPORTED_COMMAND),
                                f"M{code} is not supported by the test machine")
        scale = MM_PER_INCH if modal.units == "G20" else 1.0
        if "F" in values:
            modal = replace(modal, feed=values.pop("F"))
        if "S" in values:
            modal = replace(modal, spindle_speed=values.pop("S"))
        if "T" in values:
            modal = replace(modal, tool=int(values.pop("T")))
        axis_words = {a: values.pop(a) * scale for a in self._axes if a in values}
        if values:
            return Rejected(int(GrblErrorCode.UNUSED_WORDS),
                            f"unused words {''.join(sorted(values))}")
        modal = replace(modal, motion=motion)
        blocks: list[Block] = []
        if set_offsets is not None:
            parser.modal = modal
            return self._set_offsets(parser, set_offsets, values_g10, axis_words, start_mm)
        if dwell is not None:
            blocks.append(Dwell(dwell, number))
        if axis_words:
            offset = self._work_offset(replace(parser, modal=modal))
            target = list(start_mm)
            for index, axis in enumerate(self._axes):
                if axis in axis_words:
                    if modal.distance == "G91":
                        target[index] = start_mm[index] + axis_words[axis]
                    else:
                        target[index] = axis_words[axis] + offset[index]
            feed_mm_min = modal.feed * scale
            if motion == "G1" and feed_mm_min <= 0:
                return Rejected(int(GrblErrorCode.UNDEFINED_FEED_RATE), "G1 with no F yet")
            if any(abs(value) > _AXIS_LIMIT_MM for value in target):
                return Rejected(int(GrblErrorCode.INVALID_TARGET), "target out of reach")
            blocks.append(Move(tuple(target), feed_mm_min, rapid=motion == "G0",
                               line_number=number))
        parser.modal = modal
        return blocks

    def _set_offsets(self, parser: _Parser, kind: int, system: int,
                     axis_words: dict[str, float],
                     start_mm: tuple[float, ...]) -> list[Block] | Rejected:
        if kind == 92:
            current = self._work_offset(parser)
            g92 = list(parser.g92)
            for index, axis in enumerate(self._axes):
                if axis in axis_words:
                    base = current[index] - g92[index]
                    g92[index] = start_mm[index] - base - axis_words[axis]
            parser.g92 = tuple(g92)
            return []
        if kind not in (2, 20) or not 1 <= system <= 6:
            return Rejected(int(GrblErrorCode.UNSUPPORTED_COMMAND),
                            f"G10 L{kind} P{system} is not supported by the test machine")
        offsets = list(parser.coordinate_systems[system - 1])
        for index, axis in enumerate(self._axes):
            if axis in axis_words:
                offsets[index] = axis_words[axis] if kind == 2 \
                    else start_mm[index] - parser.g92[index] - axis_words[axis]
        parser.coordinate_systems[system - 1] = tuple(offsets)
        return []


def _distance(a: tuple[float, ...], b: tuple[float, ...]) -> float:
    return math.sqrt(sum((x - y) ** 2 for x, y in zip(a, b, strict=True)))
