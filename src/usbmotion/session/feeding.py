"""Streaming a program in steps: a program still being written (a
:class:`~usbmotion.session.feed.ProgramFeed`), its moves planned and joined as they come,
and a program's pauses (M0, M1, M6), up to each of which the rows are given.

A feed's rows are given to the streams only as far as more moves cannot change them (up
to a stop's length before the plan's end at rest), or, when the feed runs short, far
enough to keep :data:`FEED_FLOOR_S` queued: the machine then runs into the end's
deceleration rather than out of setpoints, so it can always stop at the end of the last
move, the invariant grbl's and Klipper's planners keep.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Callable
from dataclasses import replace

from usbmotion.motion.gcode import Pause
from usbmotion.motion.planner import Plan
from usbmotion.motion.replanning import PathPoint
from usbmotion.session.feed import FeedSnapshot, ProgramFeed
from usbmotion.session.legs import Legs, pause_segments
from usbmotion.session.planning import Prepared
from usbmotion.session.seams import join_rows
from usbmotion.session.streaming import RunStreams
from usbmotion.session.watch import FAULT_CHECK_S

READ_AHEAD_S = 2.0
"""A feed with a source is read this far ahead of the rows given to the streams (its
plan's look-ahead; more than any stop takes)."""
FEED_FLOOR_S = 0.3
"""When a feed runs short of moves, the rows given to the streams still keep this much
queued ahead of the machine."""
DRY_MARGIN_S = 0.03
"""A feed that grows when the rows given last less than this beyond the machine waits for
them to play out and starts again from rest (the queues may run empty before more come)."""
RELEASE_S = 0.1
"""A feed's rows are given to the streams in steps of at least this much."""


class Feeding:
    """What a run keeps of a program streamed in steps (see the module docstring).

    Parameters:
        prepared: the program as prepared (of a feed: its moves so far).
        feed: the feed of a program still being written (None: the program is whole).
        legs, streams: the run's rows and streams.
        stop_time_s: longer than any stop from full speed.
    """

    def __init__(self, prepared: Prepared, feed: ProgramFeed | None, legs: Legs,
                 streams: RunStreams, *, stop_time_s: float) -> None:
        self.feed = feed
        self.legs = legs
        self.streams = streams
        self.stop_time_s = stop_time_s
        self.version = -1
        """The feed's version the plan was made from."""
        self.complete = feed is None
        """True once no more moves can come."""
        program = prepared.program
        self.moves = len(program.moves)
        self.lines: list[int] = [move.line for move in program.moves]
        self.pause_segments = pause_segments(legs.plan, program.moves, program.pauses)
        """The program plan's segments where it pauses, in order."""
        self.pause_records: list[Pause] = list(program.pauses)
        self.pauses_passed = 0
        self.dry = False
        """Every row given has been executed and the queues ran empty: more motion starts
        again from rest on a common tick."""
        self.rest_point: PathPoint | None = None
        """Where the machine rests when it has played out everything it was given."""
        self.notes: list[str] = []

    @property
    def stepped(self) -> bool:
        """Whether the program streams in steps (a feed, or pauses)."""
        return self.feed is not None or bool(self.pause_segments)

    @property
    def has_source(self) -> bool:
        """A feed that the run reads itself (a file)."""
        return self.feed is not None and self.feed.has_source

    def changed(self) -> bool:
        """More moves (or the feed's end) came since the plan was made."""
        return self.feed is not None and self.feed.version != self.version

    def lookahead_s(self) -> float:
        """How much of the plan lies ahead of the machine, s."""
        return float((self.legs.count - self.streams.executed()) * self.legs.period_s)

    def lines_total(self) -> int:
        """The last line with a move so far."""
        return self.lines[-1] if self.lines else 0

    # --- rows to give ----------------------------------------------------------------------------

    def release_limit(self, *, executed: int | None = None) -> int:
        """How many rows the streams may have: all of a complete program up to its next
        pause; of a feed still being written, those more moves cannot change, or enough to
        keep :data:`FEED_FLOOR_S` queued."""
        legs = self.legs
        limit = legs.count
        if not self.complete:
            done = self.streams.executed() if executed is None else executed
            limit = min(legs.count, max(legs.final_row(self.stop_time_s),
                                        done + math.ceil(FEED_FLOOR_S / legs.period_s)))
        pause_row = self.next_pause_row()
        if pause_row is not None:
            limit = min(limit, pause_row + 1)
        return int(max(limit, self.streams.released))

    def release(self) -> None:
        """Give the streams the rows :meth:`release_limit` allows."""
        if self.streams.release(self.legs.rows, self.release_limit()):
            self.dry = False

    def wake(self) -> bool:
        """Whether there is more to give the streams: more moves, a source to read further,
        or a step of rows released."""
        if self.changed():
            return True
        feed = self.feed
        if (feed is not None and feed.has_source and not self.complete
                and feed.blocks_free > 0 and self.lookahead_s() < READ_AHEAD_S):
            return True
        return self.release_limit() >= self.streams.released + math.ceil(
            RELEASE_S / self.legs.period_s)

    # --- pauses ---------------------------------------------------------------------------------

    def next_pause_row(self) -> int | None:
        """The row of the next pause on the leg streaming (None: none on it)."""
        if self.pauses_passed >= len(self.pause_segments):
            return None
        return self.legs.pause_row(self.pause_segments[self.pauses_passed])

    def at_pause(self) -> Pause | None:
        """The pause the machine came to rest at (the rows given end there), or None."""
        row = self.next_pause_row()
        if row is None or self.streams.released != row + 1:
            return None
        return self.pause_records[self.pauses_passed]

    def pass_pause(self) -> PathPoint:
        """The machine leaves the pause it rests at: where the rest of the program starts."""
        segment = self.pause_segments[self.pauses_passed]
        self.pauses_passed += 1
        return self.legs.segment_point(segment)

    # --- more moves -----------------------------------------------------------------------------

    def take(self, *, streaming: bool, restart: Callable[[PathPoint], None],
             drain: Callable[[], None]) -> None:
        """Read a source further when the look-ahead runs short, and plan the moves the feed
        gained, joining them to what streams. ``restart`` starts the rest of the program
        from rest at a point (the queues ran empty); ``drain`` waits for them to."""
        feed = self.feed
        if feed is None:
            return
        if (feed.has_source and not self.complete
                and (not streaming or self.lookahead_s() < READ_AHEAD_S)):
            feed.pull()
        snapshot = feed.snapshot()
        if snapshot.version == self.version:
            return
        self.version = snapshot.version
        self.complete = snapshot.complete
        if len(snapshot.moves) == self.moves:
            return
        self.moves = len(snapshot.moves)
        self.lines = [move.line for move in snapshot.moves]
        self._join(feed.plan(snapshot), snapshot, streaming=streaming, restart=restart,
                   drain=drain)

    def executed_moves(self, line: int, at_s: float) -> None:
        """Tell the feed the machine executes program line ``line``, ``at_s`` into the
        feed's plan (what the live model shows: a front acknowledges what follows it), so
        every move before that line is done (frees the window and the horizon)."""
        feed = self.feed
        if feed is None:
            return
        if self.dry:  # at rest after everything given: every move so far is done
            feed.executed(self.moves, at_s=self.legs.plan.duration_s)
            return
        feed.executed(bisect.bisect_left(self.lines, line), at_s=at_s)

    def _join(self, plan: Plan, snapshot: FeedSnapshot, *, streaming: bool,
              restart: Callable[[PathPoint], None], drain: Callable[[], None]) -> None:
        legs = self.legs
        legs.plan = plan
        self.pause_segments = pause_segments(plan, snapshot.moves, snapshot.pauses)
        self.pause_records = list(snapshot.pauses)
        if not streaming or not self.streams.streams:
            return
        if not self.dry:
            self.release()  # the rows the old plan allows, before judging what is queued
            if self.queued_s() < DRY_MARGIN_S:
                drain()
                self.played_out()
        if self.dry:
            point = self.rest_point or legs.point_at(self.streams.released - 1)
            restart(replace(point, speed_mm_s=0.0))
            return
        if not join_rows(legs, self.streams, stop_time_s=self.stop_time_s,
                         release_limit=self.release_limit):
            self.notes.append("more moves came too late to join the plan: the machine came"
                              " to rest before them")
            drain()
            self.played_out()
            assert self.rest_point is not None
            restart(replace(self.rest_point, speed_mm_s=0.0))

    def queued_s(self) -> float:
        """How long the rows given to the streams last beyond what the devices executed."""
        return (self.streams.released - self.streams.executed()) * self.legs.period_s

    def rest_at(self, point: PathPoint | None) -> None:
        """Resumed at the end of what the feed has given: at rest at ``point`` until more
        comes."""
        self.dry = True
        self.rest_point = point
        self.streams.released = self.legs.count

    def played_out(self) -> None:
        """The machine executed every row given and came to rest there (the last row
        given): more starts from there."""
        self.dry = True
        self.rest_point = self.legs.point_at(max(0, self.streams.released - 1))

    # --- streaming in steps ---------------------------------------------------------------------

    def stream(self, look: Callable[[], bool], *, take: Callable[[], None],
               check_s: float) -> bool:
        """Stream a feed's moves as they come (and a program with pauses, up to each):
        True when the program played out and settled; False when ``look`` saw an event
        or the machine came to rest at a pause. ``take`` takes more moves."""
        streams = self.streams
        clock = streams.machine.clock
        while True:
            take()
            self.release()
            streams.stream(lambda: look() or self.wake(), max_wait_s=check_s)
            if look():
                return False
            if self.changed() or self.release_limit() > streams.released \
                    or not streams.all_sent:
                continue
            if not self.wait_drained(look, check_s=check_s):
                if look():
                    return False
                continue
            streams.settle()
            if self.at_pause() is not None:
                return False
            self.played_out()
            if self.complete:
                return True
            feed = self.feed
            if feed is not None and not feed.has_source:
                if feed.finish_if(self.version):
                    self.complete = True
                    return True
                if not self.changed():  # lines on their way: at rest until they come
                    clock.sleep(check_s)

    def wait_drained(self, look: Callable[[], bool], *, check_s: float) -> bool:
        """Until every queue is empty (the last setpoint being executed): True; or
        ``look`` saw an event, or (a feed) more moves came: False."""
        streams = self.streams
        period_s = self.legs.period_s
        while True:
            if look() or self.changed() or self.release_limit() > streams.released:
                return False
            queued = streams.queues()
            if not queued:
                return True
            wait = min(FAULT_CHECK_S, max(period_s, queued * period_s))
            streams.machine.clock.sleep(wait if self.feed is None else min(wait, check_s))
