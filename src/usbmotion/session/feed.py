"""A program the machine runs while it is still being written: G-code lines arrive one at
a time (from a file read as it runs, a console, a sender), each is interpreted against the
modal state the feed keeps and checked against every axis's travel as it comes, and the
run plans the moves it has with look-ahead, always able to stop at the end of the last one
(the invariant grbl's and Klipper's planners keep).

A feed is written from one thread (a front: :meth:`ProgramFeed.add`) and read by the run
in another; everything the two share is behind one lock. A feed with a *source* (an
iterator of lines, such as a file) is read by the run itself, as far ahead of the machine as
the look-ahead needs (:meth:`ProgramFeed.pull`): no thread, so it runs the same in virtual
time.

The planner's window is bounded (:attr:`ProgramFeed.window`, moves not yet executed, and
:attr:`ProgramFeed.horizon_s`, their planned seconds): a front that outruns the machine is
told the feed is full and tries again (grbl's planner buffer), so memory stays bounded on
an endless stream and what a front acknowledges stays close to what the machine executes.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable, Iterator
from dataclasses import dataclass

from usbmotion.errors import ArgumentError, GCodeError, PlanningError
from usbmotion.host.config import MachineConfig
from usbmotion.motion.dialects import Dialect
from usbmotion.motion.gcode import GCodeProgram, GCodeStream, Modes, Pause, Pauses
from usbmotion.motion.limits import check_travel, settled_band_mm
from usbmotion.motion.moves import Linear, Move, Point, start_of
from usbmotion.motion.offsets import NO_OFFSETS, WorkOffsets
from usbmotion.motion.planner import Plan, plan_moves
from usbmotion.motion.tools import NO_TOOLS, ToolTable
from usbmotion.session.planning import machine_axes, machine_dialect, plan_axes, planner_inputs

WINDOW_MOVES = 256
"""The most moves a feed holds that the machine has not executed yet (its planner buffer)."""
FRONT_WINDOW_MOVES = 15
"""A front's feed (a sender's, a console's): the most moves not yet executed, the one
executing among them, as grbl's planner buffer holds 15 blocks, so a sender's ``ok``
follows the machine."""
FRONT_HORIZON_S = 2.0
"""A front's feed: the most planned seconds of moves ahead of the machine."""
PULL_MOVES = 64
"""The most moves one pull of a source adds (the run plans again after each pull)."""


@dataclass(frozen=True, slots=True)
class FeedSnapshot:
    """What the run reads of a feed at one moment: every move so far, the pauses, and
    whether more can come."""

    moves: tuple[Move, ...]
    pauses: tuple[Pause, ...]
    version: int
    complete: bool
    """No more moves will come (the source ended, a line ended the program, or the feed
    was closed)."""


class ProgramFeed:
    """G-code lines in, moves out, for a machine (see the module docstring).

    Parameters:
        config: the machine.
        start_mm: where the machine stands (one coordinate per program axis).
        homed: whether that is a homed position (soft limits are checked line by line).
        file: the name errors give the feed (a file's name, ``<console>``, ...).
        source: lines the run reads as it needs them (a file); none: lines come by
            :meth:`add`.
        dialect, tools, offsets, pauses: as :func:`usbmotion.motion.gcode.parse_gcode`'s.
        window: the most moves not yet executed (see :attr:`window`).
        horizon_s: the most planned seconds of moves not yet executed (see
            :attr:`horizon_s`; None: no bound but the window).
    """

    def __init__(self, config: MachineConfig, *, start_mm: Point, homed: bool,
                 file: str = "<stream>", source: Iterator[str] | None = None,
                 dialect: Dialect | None = None, tools: ToolTable = NO_TOOLS,
                 offsets: WorkOffsets | None = None, pauses: Pauses = Pauses.PROGRAM,
                 window: int = WINDOW_MOVES, horizon_s: float | None = None) -> None:
        if isinstance(window, bool) or not isinstance(window, int) or window < 1:
            raise ArgumentError(f"window {window!r}: a whole number of moves, at least 1",
                                reason="window")
        if horizon_s is not None and not (math.isfinite(horizon_s) and horizon_s > 0):
            raise ArgumentError(f"horizon_s {horizon_s!r}: seconds > 0 (or None)",
                                reason="horizon_s")
        self.config = config
        self.file = file
        self.homed = homed
        self.start_mm = start_mm
        self.offsets = offsets or NO_OFFSETS
        self.window = window
        """The most moves the feed holds beyond those the machine executed."""
        self.horizon_s = horizon_s
        """The most planned seconds of moves beyond the machine's place (by the last plan
        the run made: moves added since count toward :attr:`window` only)."""
        self._executed_s = 0.0
        self._stream = GCodeStream(file=file, start=start_mm, machine=machine_axes(config),
                                   dialect=machine_dialect(config, dialect), tools=tools,
                                   offsets=self.offsets, pauses=pauses)
        self._source = source
        self._lock = threading.Lock()
        self._version = 0
        self._closed = False
        self._executed_moves = 0
        self._travel = [axis.travel_mm for axis in plan_axes(config)]
        self._axes = machine_axes(config).axes
        self._limits, self._planner, counts_per_mm = planner_inputs(config)
        self._band = settled_band_mm(counts_per_mm)
        self._plan: tuple[int, Plan] | None = None
        self.error: GCodeError | PlanningError | None = None
        """The error that ended a source (its line could not be interpreted)."""
        self.more_coming: Callable[[], bool] | None = None
        """True while the writer is about to add lines (a sender's lines in a front's
        receive buffer): :meth:`finish_if` then keeps the feed open. It must answer at once
        and take no lock the writer holds while adding."""

    # --- writing ------------------------------------------------------------------------------

    def add(self, text: str, *, line: int | None = None) -> bool:
        """Interpret one line and take its moves; False when the window is full (nothing
        was done: try again once the machine has moved) or the feed is closed (or its
        program ended: the line belongs to the next one, on a restarted feed).

        Raises:
            GCodeError: the line is invalid or comes after the program's end.
            PlanningError: one of its moves leaves an axis's travel (SoftLimitError) or
                cannot be planned. A line that fails adds nothing.
        """
        with self._lock:
            if self._closed or self._stream.ended_by:
                return False
            if self._full():
                return False
            self._take(text, line)
            return True

    def _full(self) -> bool:
        """Whether the window or the horizon is full (under the lock)."""
        if len(self._stream.moves) - self._executed_moves >= self.window:
            return True
        plan = self._plan
        return (self.horizon_s is not None and plan is not None
                and plan[1].duration_s - self._executed_s >= self.horizon_s)

    def _take(self, text: str, line: int | None) -> None:
        moves = self._stream.feed(text, line=line,
                                  check=self._check_travel if self.homed else None)
        if moves:
            self._version += 1

    def _check_travel(self, moves: list[Move]) -> None:
        """Soft limits on a line's moves (every chord of every arc), in machine coordinates."""
        plan = plan_moves(moves, self._limits, self._planner, start=start_of(moves[0]),
                          axes=self._axes)
        check_travel(plan.vertices_mm, plan.line, self._travel, axes=tuple(plan.axes),
                     band_mm=self._band)

    def probe_target(self, text: str, *, line: int | None = None) -> tuple[Point, float]:
        """Where a probing line goes and at what feed: ``text`` is the line with its G38.n
        read as G1 (:func:`usbmotion.session.probing.probing_line`), interpreted with the
        feed's modes (distance mode, units, offsets; its feed word kept for the lines after
        it): the move's machine end, one coordinate per program axis, and its feed, mm/min.
        The feed then stands at that end until :meth:`restart` puts it where the probe
        stopped.

        Raises:
            GCodeError: the line is invalid, or makes no single straight move with a feed.
            PlanningError: the move leaves an axis's travel (SoftLimitError).
        """
        with self._lock:
            number = line if line is not None else self._stream.lines + 1
            moves = self._stream.feed(text, line=line,
                                      check=self._check_travel if self.homed else None)
            if len(moves) != 1 or not isinstance(moves[0], Linear):
                raise GCodeError("a probing line (G38.2 to G38.5) makes one straight move:"
                                 " give the axis words of its target", file=self.file,
                                 line=number)
            move = moves[0]
            if not move.feed_mm_min > 0:
                raise GCodeError("a probing move needs a feed rate: give F (mm/min)",
                                 file=self.file, line=number)
            return move.end, move.feed_mm_min

    def close(self) -> None:
        """No more lines: the run plays out what the feed has and ends."""
        with self._lock:
            self._closed = True
            self._version += 1

    def restart(self, start_mm: Point) -> None:
        """Begin a new program on the same feed from ``start_mm`` (where the machine
        stands): the moves so far are dropped, the modal state (distance mode, feed, plane,
        coordinate system, tool) is kept, as a controller keeps it between the lines an
        operator or a sender writes; the feed takes lines again."""
        with self._lock:
            stream = self._stream
            stream.restart(start_mm)
            self.start_mm = start_mm
            self._closed = False
            self._executed_moves = 0
            self._executed_s = 0.0
            self._plan = None
            self.error = None
            self._version += 1

    def use_tools(self, tools: ToolTable) -> None:
        """The tool table the next lines read (:meth:`GCodeStream.use_tools`)."""
        with self._lock:
            self._stream.use_tools(tools)

    def reset(self, start_mm: Point) -> None:
        """A controller reset (grbl's soft reset) with the machine at ``start_mm``: as
        :meth:`restart`, and what the dialect's reset clears is cleared (grbl and Marlin:
        the modal state back to power-on and the G92 offset cleared; LinuxCNC keeps them)."""
        with self._lock:
            self._stream.reset(start_mm)
            self.start_mm = start_mm
            self._closed = False
            self._executed_moves = 0
            self._executed_s = 0.0
            self._plan = None
            self.error = None
            self._version += 1

    def reconfigure(self, config: MachineConfig) -> None:
        """The machine's changed configuration (same axes) for the lines to come: soft
        limits and planning from it. Only between runs; the modal state stays."""
        with self._lock:
            self.config = config
            self._travel = [axis.travel_mm for axis in plan_axes(config)]
            self._limits, self._planner, counts_per_mm = planner_inputs(config)
            self._band = settled_band_mm(counts_per_mm)
            self._plan = None

    def modes(self) -> Modes:
        """The modal state the lines so far leave."""
        with self._lock:
            return self._stream.modes()

    @property
    def lines(self) -> int:
        """The number of the last line taken (lines are numbered on from feed to feed: a
        restart goes on counting)."""
        with self._lock:
            return self._stream.lines

    @property
    def has_moves(self) -> bool:
        """True when the feed holds moves (a run has something to do)."""
        with self._lock:
            return bool(self._stream.moves)

    def finish_if(self, version: int) -> bool:
        """Close the feed unless it changed since ``version`` or more lines are coming
        (:attr:`more_coming`): a run that played out all it was given ends only if no line
        came meanwhile and none is on its way. True when it closed."""
        coming = self.more_coming
        if coming is not None and coming():
            return False
        with self._lock:
            if self._version != version:
                return False
            self._closed = True
            self._version += 1
            return True

    @property
    def closed(self) -> bool:
        """True once the feed takes no more lines (closed, or a line ended the program)."""
        with self._lock:
            return self._closed or bool(self._stream.ended_by)

    @property
    def blocks_free(self) -> int:
        """How many more moves the window takes now (0 while the horizon is full)."""
        with self._lock:
            if self._full():
                return 0
            return max(0, self.window - (len(self._stream.moves) - self._executed_moves))

    # --- reading (the run) ----------------------------------------------------------------------

    def pull(self) -> bool:
        """Read the source's next lines (at most :data:`PULL_MOVES` moves, within the
        window); True when moves were added. A line that fails ends the source
        (:attr:`error`) and closes the feed: the program runs up to it."""
        source = self._source
        if source is None:
            return False
        with self._lock:
            added = 0
            before = len(self._stream.moves)
            while not self._closed and added < PULL_MOVES and not self._full():
                try:
                    text = next(source)
                except StopIteration:
                    self._closed = True
                    break
                try:
                    self._take(text, None)
                except (GCodeError, PlanningError) as error:
                    self.error = error
                    self._closed = True
                    break
                if self._stream.ended_by:
                    self._closed = True
                added = len(self._stream.moves) - before
            if self._closed:
                self._version += 1
            return added > 0

    @property
    def has_source(self) -> bool:
        """True when the run reads the lines itself (:meth:`pull`)."""
        return self._source is not None

    def snapshot(self) -> FeedSnapshot:
        """Every move so far and whether more can come."""
        with self._lock:
            stream = self._stream
            complete = self._closed or bool(stream.ended_by)
            return FeedSnapshot(tuple(stream.moves), tuple(stream.pauses), self._version,
                                complete)

    @property
    def version(self) -> int:
        """Changes whenever moves are added or the feed closes."""
        with self._lock:
            return self._version

    def plan(self, snapshot: FeedSnapshot) -> Plan:
        """The look-ahead plan of every move of ``snapshot``, from the start, ending at rest
        (cached by version)."""
        cached = self._plan
        if cached is not None and cached[0] == snapshot.version:
            return cached[1]
        plan = plan_moves(snapshot.moves, self._limits, self._planner, start=self.start_mm,
                          axes=self._axes)
        self._plan = (snapshot.version, plan)
        return plan

    def executed(self, moves: int, *, at_s: float | None = None) -> None:
        """The machine has executed the first ``moves`` moves, and is ``at_s`` seconds
        into the feed's last plan (frees the window and the horizon)."""
        with self._lock:
            self._executed_moves = max(self._executed_moves, moves)
            if at_s is not None:
                self._executed_s = max(self._executed_s, at_s)

    def program(self) -> GCodeProgram:
        """The program as fed so far."""
        with self._lock:
            return self._stream.result()


__all__ = ["FeedSnapshot", "ProgramFeed"]
