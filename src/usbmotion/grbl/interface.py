"""What the grbl front needs from a machine session: :class:`GrblMachine`.

The front (:mod:`usbmotion.grbl.protocol`) owns everything grbl-specific: the receive
buffer, real-time bytes, the alarm lock, check mode, the status report's format and its
refresh counters, the override steps, start-up lines and the ``$`` commands. The machine
owns motion: it parses and plans G-code, executes it, holds and resumes, homes, jogs, and
says where it is. One adapter onto the real machine session implements this protocol; the
tests implement it with a simulated machine.

Positions, offsets and errors are per axis, in the order of :meth:`GrblMachine.axes`, in
millimetres. All calls are made from one thread and must return promptly (no call may
wait for motion): the front polls.
"""

from __future__ import annotations

import enum
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable


class MotionState(enum.Enum):
    """The machine's own motion state. The front adds what is its own (check mode, the
    alarm lock it keeps, sleep, the safety door) when it names the state in a report."""

    IDLE = "Idle"
    """At rest, nothing queued or running."""
    RUN = "Run"
    """Executing the streamed program (or about to: blocks queued and starting)."""
    HOLD_COMPLETE = "Hold:0"
    """Held and at rest: :meth:`GrblMachine.cycle_start` resumes."""
    HOLD_IN_PROGRESS = "Hold:1"
    """Decelerating to a hold."""
    JOG = "Jog"
    """Executing jog moves (or decelerating after a jog cancel)."""
    HOMING = "Home"
    """Running the homing cycle started by :meth:`GrblMachine.home`."""
    ALARM = "Alarm"
    """Locked by the machine: not homed yet, or a fault (see :attr:`MachineStatus.fault`).
    G-code is refused until :meth:`GrblMachine.unlock` or a successful homing."""


class Admission(enum.Enum):
    """A line or jog the machine took, or could not take yet."""

    ACCEPTED = "accepted"
    """Parsed and queued for execution."""
    PLANNER_FULL = "planner full"
    """No room in the planner now; the front offers the same line again later."""


@dataclass(frozen=True, slots=True)
class Rejected:
    """A line the machine refused: grbl's error number for it and why, in words."""

    code: int
    """grbl's error number (``error:N``): 20 unsupported command, 33 invalid target, ..."""
    message: str
    """What was wrong, for a ``[MSG:...]`` line."""


SubmitResult = Admission | Rejected


@dataclass(frozen=True, slots=True)
class Taken:
    """A setting the machine took, with what the sender's operator should know of it (a
    ``[MSG:...]`` line before the ``ok``)."""

    message: str


@dataclass(frozen=True, slots=True)
class Fault:
    """Why the machine stopped on its own: it becomes ``[MSG:...]`` then ``ALARM:N``."""

    alarm: int
    """grbl's alarm number: 1 hard limit (position likely lost), 2 soft limit, 8 and 9
    homing failed, ..."""
    message: str
    """What happened, in words (``following error 1.20 mm over 0.50 mm``)."""
    axis: str | None = None
    """The axis letter the fault is on, if one."""
    line_number: int | None = None
    """The program line running when it happened (its ``N`` word), if known."""


@dataclass(frozen=True, slots=True)
class MachineStatus:
    """One snapshot of the machine, for a status report."""

    machine_position_mm: tuple[float, ...]
    """Where each axis is, machine coordinates."""
    work_offset_mm: tuple[float, ...]
    """The current work coordinate offset per axis (active G54-G59 system plus G92 plus
    tool length offset): work position = machine position - this."""
    feed_mm_min: float = 0.0
    """The current feed along the path (after overrides)."""
    line_number: int | None = None
    """The ``N`` number of the program line executing, if it had one."""
    following_error_mm: tuple[float, ...] = ()
    """Commanded minus measured position per axis, the devices' sign (empty: not measured)."""
    limit_pins: frozenset[str] = frozenset()
    """Axis letters whose limit switch reads triggered."""
    fault: Fault | None = None
    """Why the machine stopped on its own, until :meth:`GrblMachine.unlock` or a successful
    homing clears it (a soft reset keeps it)."""
    spindle_rpm: float = 0.0
    """The spindle's speed as its encoder measures it (0: stopped, or no spindle)."""
    probe: bool = False
    """The probe input reads closed (grbl's ``Pn:P``)."""
    accessories: str = ""
    """grbl's ``A:`` field: ``S`` spindle (or laser) on clockwise, ``C`` counter-clockwise,
    ``F`` flood, ``M`` mist ("" none on)."""


@dataclass(frozen=True, slots=True)
class JogMove:
    """One ``$J=`` jog, checked by the front and put in millimetres."""

    words_mm: Mapping[str, float]
    """Axis letter to target (or distance, when ``incremental``), millimetres."""
    feed_mm_min: float
    """Feed along the jog."""
    incremental: bool
    """G91: ``words_mm`` are distances from where the last queued jog ends."""
    machine_coordinates: bool
    """G53: targets are machine coordinates (else work coordinates)."""
    line_number: int | None = None


@dataclass(frozen=True, slots=True)
class ModalState:
    """The G-code parser's state, for ``$G`` and for jogs (units and distance mode)."""

    motion: str = "G0"
    coordinate_system: str = "G54"
    plane: str = "G17"
    units: str = "G21"
    distance: str = "G90"
    feed_rate_mode: str = "G94"
    program: str | None = None
    """``M0``, ``M2`` or ``M30`` while one is in effect, else None."""
    spindle: str = "M5"
    coolant: str = "M9"
    tool: int = 0
    feed: float = 0.0
    """Programmed feed, current units per minute."""
    spindle_speed: float = 0.0


@dataclass(frozen=True, slots=True)
class WorkOffsets:
    """What ``$#`` prints, millimetres per axis in machine coordinates."""

    coordinate_systems: tuple[tuple[float, ...], ...]
    """G54 to G59, six entries."""
    g28: tuple[float, ...]
    g30: tuple[float, ...]
    g92: tuple[float, ...]
    tool_length_offset: float = 0.0
    probe: tuple[float, ...] = ()
    """The last probe position (empty: none yet)."""
    probe_succeeded: bool = False


@dataclass(frozen=True, slots=True)
class AxisSettings:
    """One axis's part of ``$$`` (``$100`` up)."""

    counts_per_mm: float
    """The device's counts per millimetre, shown as grbl's steps per millimetre: a
    stepper's microsteps (its ``steps_per_mm``), a servo's encoder counts."""
    max_rate_mm_min: float
    accel_mm_s2: float
    max_travel_mm: float


@dataclass(frozen=True, slots=True)
class MachineSettings:
    """The grbl settings that map onto the machine."""

    axes: tuple[AxisSettings, ...]
    junction_deviation_mm: float = 0.01
    arc_tolerance_mm: float = 0.002
    soft_limits: bool = False
    hard_limits: bool = False
    homing: bool = False
    homing_dir_mask: int = 0
    """Bit per axis (X is bit 0): home towards negative."""
    homing_feed_mm_min: float = 25.0
    homing_seek_mm_min: float = 500.0
    homing_debounce_ms: int = 250
    homing_pull_off_mm: float = 1.0
    extra: Mapping[int, float] = field(default_factory=dict)
    """Further ``$N`` settings the machine gives values for (rarely needed)."""


@runtime_checkable
class GrblMachine(Protocol):
    """A machine session seen by the grbl front. Every call returns promptly."""

    def axes(self) -> tuple[str, ...]:
        """The axis letters, in report order (``("X", "Y", "Z")``)."""
        ...

    def state(self) -> MotionState:
        """The machine's motion state now."""
        ...

    def status(self) -> MachineStatus:
        """A snapshot for a status report."""
        ...

    def submit(self, line: str, line_number: int | None) -> SubmitResult:
        """Queue one G-code line of the streamed program.

        Parameters:
            line: the block as grbl parses it: upper case, no spaces, no comments
                (``G1X10.5F300``).
            line_number: its ``N`` word, if it has one.

        The front answers ``ok`` for G4, M0, M2 and M30 (and offset changes) only once
        :meth:`motion_done` says everything before them finished.
        """
        ...

    def check(self, line: str) -> Rejected | None:
        """Parse one line in check mode (``$C``): its error, or None; nothing moves."""
        ...

    def motion_done(self) -> bool:
        """True when every queued block, dwells included, has finished."""
        ...

    def planner_blocks(self) -> int:
        """The planner's size in blocks (``[OPT:...]``)."""
        ...

    def planner_blocks_free(self) -> int:
        """Blocks the planner has room for now (``Bf:``)."""
        ...

    def feed_hold(self) -> None:
        """Decelerate to a hold along the path (also when idle: the next motion waits)."""
        ...

    def attach_front(self, lines_waiting: Callable[[], bool]) -> None:
        """The front, once, at its start: ``lines_waiting()`` says (at once, from any
        thread) whether lines it is about to submit are in its receive buffer, so a streamed
        program that has played out what it was given need not end while more is coming."""
        ...

    def cycle_start(self) -> None:
        """Resume from a hold."""
        ...

    def soft_reset(self) -> None:
        """Decelerate to rest and drop everything queued; stay homed. A fault stays."""
        ...

    def jog(self, move: JogMove) -> SubmitResult:
        """Queue a jog (only while idle or jogging). Rejected(15): beyond the travel."""
        ...

    def jog_cancel(self) -> None:
        """Stop jogging at once (decelerating) and drop the queued jogs."""
        ...

    def set_feed_override(self, percent: int) -> None:
        """Scale programmed feeds, 10 to 200 %."""
        ...

    def set_rapid_override(self, percent: int) -> None:
        """Scale rapids: 25, 50 or 100 %."""
        ...

    def set_spindle_override(self, percent: int) -> None:
        """Scale the spindle's speed, 10 to 200 % (a machine without one ignores it)."""
        ...

    def home(self) -> None:
        """Start the homing cycle; :meth:`state` is HOMING until it ends, then IDLE, or
        ALARM with :attr:`MachineStatus.fault` telling why it failed."""
        ...

    def unlock(self) -> None:
        """Clear the machine's alarm lock (``$X``): G-code is accepted again."""
        ...

    def settings(self) -> MachineSettings:
        """The settings that map onto the machine."""
        ...

    def set_setting(self, number: int, value: float) -> Rejected | Taken | None:
        """Change one mapped setting (``$N=value``): its error, or None (or a note) when
        it was taken."""
        ...

    def work_offsets(self) -> WorkOffsets:
        """The offsets ``$#`` prints."""
        ...

    def measure_tool(self) -> Rejected | None:
        """Start measuring the tool in the spindle on the machine's tool setter (``$TLS``,
        from Idle): :meth:`motion_done` is false until it ends, then its length is the
        active tool length offset (grbl's ``G43.1``), or a failure is an alarm (no contact:
        alarm 5, as a probe's). Its refusal when it cannot start."""
        ...

    def tool_measurement(self) -> str | Rejected:
        """What the last tool measurement found, in words ("" before any), or why it could
        not measure (the setter's table, a tool table)."""
        ...

    def modal_state(self) -> ModalState:
        """The parser state ``$G`` prints."""
        ...
