"""One run of a prepared program (:meth:`MachineSession.run`).

Every axis is started on the same device tick and streamed its setpoints; the run watches
the alarms the devices print (and, now and then, their status) and the operator's stop
requests. A fault or a stop brings every axis to rest along the program's path at its
planned deceleration; a lost link stops every axis at once. The report says why the run
ended and how the axes followed.

A feed hold decelerates as a stop does and keeps the program's place (the point of the path
where the axes came to rest, :class:`usbmotion.motion.replanning.PathPoint`); a resume
plans the rest of the path from rest there and starts every axis on one device tick, as
the run's start does. An override plans the queued future again at the new speed from the
speed the axes have a device tick just ahead, and replaces it there (call 38): the
setpoints streamed are a sequence of legs, each planned from a point of the program.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Callable, Sequence
from contextlib import ExitStack
from dataclasses import dataclass, replace
from functools import partial
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from usbmotion.errors import (
    DeviceError,
    DeviceTimeoutError,
    LinkCorruptedError,
    LinkLostError,
    PlanningError,
    UsbMotionError,
)
from usbmotion.host.device import Alarm, MotionStats, Status
from usbmotion.host.stream import SetpointStream, StreamProgress, run_streams
from usbmotion.host.timesync import synchronise_start
from usbmotion.motion.gcode import Pause
from usbmotion.motion.moves import Dwell, Move
from usbmotion.motion.planner import Plan, SegmentKind
from usbmotion.motion.replanning import Leg, PathPoint, locate, plan_rest, whole_program
from usbmotion.motion.sampler import sample_plan
from usbmotion.motion.stopping import stop_setpoints
from usbmotion.protocol import FaultCode
from usbmotion.session.feed import FeedSnapshot, ProgramFeed
from usbmotion.session.planning import Prepared, planner_inputs
from usbmotion.session.progress import Progress
from usbmotion.session.report import (
    SETTLE_COUNTS,
    FaultRecord,
    RunReport,
    Trace,
    build_report,
    line_at,
)
from usbmotion.session.rest import REST_POLL_S, SETTLE_TIMEOUT_S, STOP_LEAD_S, wait_for_rest
from usbmotion.session.state import MachineState, StopReason

if TYPE_CHECKING:
    from usbmotion.session.session import MachineSession

DIAGNOSTICS_PERIOD_S = 0.01
"""The shortest period of the diagnostics lines of the trace (plots, end points, settling):
the peak and RMS error come from the devices' own statistics (call 35), so the trace need
not be dense."""
TRACE_POINTS = 10_000
"""The most diagnostics lines per axis the trace aims at: a longer program gets a sparser
trace (10 minutes, one line every 60 ms; an hour, every 0.36 s)."""
START_MARGIN_S = 0.2
FAULT_CHECK_S = 0.05
"""The longest a run goes without reading the alarms the devices printed (no exchange:
lines that came); it reads them whenever it wakes, at least this often."""
STATUS_CHECK_S = 1.0
"""How often a run also asks every device its status, in case an alarm line was lost."""
REQUEST_CHECK_S = 0.01
"""The longest a run goes without looking at the operator's requests (hold, stop,
overrides): with :data:`STOP_LEAD_S` it bounds a hold's latency."""
RESUME_MARGIN_S = 0.05
"""A resume's common start tick, beyond the round trips that arm it."""
REPLACE_BATCH = 600
"""The most new values a replacement (call 38) carries; the stream sends the rest."""
RESEAM_ROWS = 20
"""When the rest cannot be planned from the seam at the speed the axes have there (too
little of the segment left to slow to the new speed), the seam moves on by this many rows."""


READ_AHEAD_S = 2.0
"""A feed with a source is read this far ahead of the rows given to the streams (its
plan's look-ahead; more than any stop takes)."""
FEED_FLOOR_S = 0.3
"""When a feed runs short of moves, the rows given to the streams still keep this much
queued ahead of the machine (it runs into the end's deceleration rather than out of
setpoints)."""
DRY_MARGIN_S = 0.03
"""A feed that grows when the rows given last less than this beyond the machine waits for
them to play out and starts again from rest (the queues may run empty before more come)."""
RELEASE_S = 0.1
"""A feed's rows are given to the streams in steps of at least this much."""


def _pause_segments(plan: Plan, moves: Sequence[Move], pauses: Sequence[Pause]) -> list[int]:
    """The plan's segment of each pause: its zero-second dwell (dwells are never merged
    or dropped, so the k-th dwell move is the k-th dwell segment)."""
    if not pauses:
        return []
    dwell_segments = np.flatnonzero(plan.kind == SegmentKind.DWELL)
    ordinal: dict[int, int] = {}
    for index, move in enumerate(moves):
        if isinstance(move, Dwell):
            ordinal[index] = len(ordinal)
    return [int(dwell_segments[ordinal[pause.move]]) for pause in pauses
            if ordinal.get(pause.move, len(dwell_segments)) < len(dwell_segments)]


def trace_period_s(duration_s: float) -> float:
    """The diagnostics period of the trace of a program lasting ``duration_s``."""
    return max(DIAGNOSTICS_PERIOD_S, duration_s / TRACE_POINTS)


@dataclass(frozen=True, slots=True)
class _Ending:
    """How the streaming ended: the reason in the report's words and, when a link was
    lost, its error and the axis it was (when known)."""

    reason: str
    link_error: str = ""
    lost_axis: str = ""


class Run:
    """One run of a prepared program on a session's machine; :meth:`go` runs it once.

    Parameters:
        session: the session, in Run.
        prepared: the program, prepared from where the machine stands.
        on_progress: called with the run's progress as setpoints go.
        homing_s: how long the homing before the run took, for the report.
    """

    def __init__(self, session: MachineSession, prepared: Prepared,
                 on_progress: Callable[[Progress], None] | None, homing_s: float,
                 feed: ProgramFeed | None = None) -> None:
        self.session = session
        self.feed = feed
        """The feed of a program still being written (None: the prepared program is whole)."""
        self.fed_version = -1
        """The feed's version the plan was made from."""
        self.fed_complete = feed is None
        """True once no more moves can come."""
        self.machine = session.machine
        self.config = session.config
        self.clock = session.clock
        self.prepared = prepared
        self.plan = prepared.plan
        self.on_progress = on_progress
        self.homing_s = homing_s
        self.faults: list[FaultRecord] = []
        self.notes: list[str] = [] if prepared.homed else [
            "the machine is not homed: the program ran in the devices' own counts and soft"
            " limits were not checked"]
        self.period_s = self.config.motion_period_s
        self.tick_s = self.config.servo_period_s
        self.axes = prepared.axes
        """The program axes: the axes the run streams to."""
        counts_per_mm = [self.config.axis(n).counts_per_mm for n in self.axes]
        self.counts_per_mm = np.array(counts_per_mm)
        self.limits, self.planner_config, _ = planner_inputs(self.config)
        self.overrides = (session.feed_override_percent, session.rapid_override_percent)
        """The feed and rapid overrides the streamed setpoints were planned at."""
        first = whole_program(self.plan)
        if self.overrides != (100, 100):
            start = locate(self.plan, first, 0.0)
            first = self._plan_rest(start) or first
        self.legs: list[tuple[int, Leg]] = [(0, first)]
        """The legs being streamed, each with the row it starts on."""
        self.setpoints: npt.NDArray[np.int32] = self._sample(first)
        """The setpoints being streamed (rows since the last start or resume)."""
        self.released = self.setpoints.shape[0] if feed is None else 0
        """How many rows of :attr:`setpoints` the streams were given: all of a whole
        program; of a feed, those that more moves cannot change (:meth:`_release_limit`)."""
        axes_config = [self.config.axis(n) for n in self.axes]
        self.stop_time_s = max(a.max_velocity_mm_s / a.max_accel_mm_s2 for a in axes_config) * (
            math.sqrt(len(self.axes)) if len(self.axes) > 1 else 1.0)
        """Longer than any stop from full speed takes: a feed's plan is final up to this
        long before its end (the look-ahead's end at rest cannot reach further back)."""
        self.pause_segments: list[int] = _pause_segments(self.plan, prepared.program.moves,
                                                         prepared.program.pauses)
        """The program plan's segments where it pauses (M0, M1, M6), in order."""
        self.pauses_passed = 0
        """How many of them the machine has passed."""
        self.pause_records: list[Pause] = list(prepared.program.pauses)
        self.pausing: Pause | None = None
        """The pause the machine waits at (None: none)."""
        self.fed_moves = len(prepared.program.moves)
        self.fed_lines: list[int] = [move.line for move in prepared.program.moves]
        self.dry = False
        """True when every row given has been executed and the queues ran empty: more
        motion starts on a common tick again (:meth:`_restart`)."""
        self.rest_point: PathPoint | None = None
        """Where the machine rests when it has played out everything it was given."""
        self.rows_before = 0
        """Rows executed before the last resume."""
        self.hold_point: PathPoint | None = None
        """Where on the program the axes came to rest in a feed hold."""
        self.holds: list[tuple[float, int, float, float]] = []
        """Every hold's request time (s), the device tick its deceleration began on, its
        planned v^2/2a and its distance (mm)."""
        self.stop_tick = 0
        """The device tick a stop's deceleration began on (0: no stop)."""
        self.paused: list[Pause] = []
        """The program pauses the run waited at, in order."""
        self.seams: list[tuple[float, int]] = []
        """Every override's request time (s) and the device tick its new speed began on."""
        self.drained = False
        self.faults_read_s = 0.0
        self.check_s = REQUEST_CHECK_S if session.live_control else FAULT_CHECK_S
        """How long the stream waits at most between looks at requests and faults."""
        self.trace = Trace(tick_s=self.tick_s, start_tick=0,
                           counts_per_mm={n: self.machine.axis(n).config.counts_per_mm
                                          for n in self.machine.axes})
        self.streams: dict[str, SetpointStream] = {}
        self.start_tick = 0
        self.status_checked_s = 0.0
        """When the run last asked every device its status (the session's clock)."""
        self.stop_distance_mm = 0.0
        self.stop_planned_mm = 0.0
        self.stop_latency_s = 0.0
        self.stopped_index: float | None = None
        self.faulted_axes: list[str] = []
        """The axes whose device was in a fault when the run ended."""
        self.faulted = False
        """True when the run ended on a fault or a lost link (the machine is in Alarm)."""

    def go(self) -> tuple[RunReport, Trace]:
        """The run: its report and its trace (the devices' diagnostics lines are the
        trace's, and their alarms the run's faults, only while it runs)."""
        with ExitStack() as listening:
            self._enable_axes()
            for name, axis in self.machine.axes.items():
                listening.enter_context(axis.client.listening(diagnostics=self.trace.record(name)))
            self._start_together()
            self._open_streams()
            for name, axis in self.machine.axes.items():
                listening.enter_context(axis.client.listening(alarms=partial(self._on_alarm, name)))
            ending = self._stream()
            return self._finish(ending)

    # --- the steps of a run ---------------------------------------------------------------------

    def _enable_axes(self) -> None:
        """Every axis of the program with an empty queue, its servo enabled."""
        for name in self.axes:
            client = self.machine.axis(name).client
            client.clear_queue()
            client.set_servo_enable(True)

    def _start_together(self) -> None:
        """Every axis of the program to start on the same device tick, its statistics
        reset, its diagnostics lines at the trace's period."""
        diag_ticks = max(1, round(trace_period_s(self.plan.duration_s) / self.tick_s))
        self.sync = self.machine.synchronise(margin_s=START_MARGIN_S, axes=tuple(self.axes))
        self.skew_s = self.sync.estimated_skew_s
        self.start_tick = self.trace.start_tick = self.sync.devices[0].start_tick
        for name in self.axes:
            client = self.machine.axis(name).client
            client.reset_motion_stats()
            client.set_diagnostics_interval(diag_ticks)

    def _open_streams(self) -> None:
        self.released = 0
        self.released = self._release_limit(executed=0)
        for index, name in enumerate(self.axes):
            self.streams[name] = SetpointStream(
                self.machine.axis(name).client, self.setpoints[:self.released, index],
                period_s=self.period_s, verify=True, on_progress=self._progress)

    def _stream(self) -> _Ending:
        """Stream the program until it has played out and settled, or a fault or a stop
        brings every axis to rest along the path, or a link is lost (every axis stopped at
        once)."""
        self.status_checked_s = self.faults_read_s = self.clock.now()
        try:
            while True:
                ending = self._stream_leg()
                if ending is not None:
                    return ending
        except (LinkLostError, LinkCorruptedError, DeviceTimeoutError) as error:
            lost_axis = next((n for n in self.axes if self.machine.axis(n).client.name
                              == getattr(error, "device", None)), "")
            try:
                self.machine.stop()
            except UsbMotionError as also:
                self.notes.append(f"stopping: {also}")
            return _Ending(f"{StopReason.LINK.value}: {error}", link_error=str(error),
                           lost_axis=lost_axis)

    def _stream_leg(self) -> _Ending | None:
        """Stream until the program ends, a fault or a stop ends it (an ending), or a hold
        that resumed or an override asks to go on streaming (None)."""
        session = self.session
        if self.feed is not None or self.pause_segments:
            played = self._stream_feed()
            if not self._interrupted():
                if self.pausing is not None:
                    return self._pause()
                if played:
                    self.drained = True
                    return _Ending(StopReason.COMPLETED.value)
        else:
            run_streams(list(self.streams.values()), should_stop=self._should_stop,
                        max_wait_s=self.check_s)
            if not self._interrupted():
                self._wait_drained()
            if not self._interrupted():
                self.drained = True
                self._settle()
        if self.drained and not (self.faults or session.stop_requested):
            return _Ending(StopReason.COMPLETED.value)
        return self._interruption()

    def _interruption(self) -> _Ending | None:
        """What a fault, a stop, an override or a hold that interrupted the streaming does:
        the run's ending, or None to go on streaming."""
        session = self.session
        if self.faults or session.stop_requested:
            reason = (f"fault: {self._fault_words()}" if self.faults
                      else session.stop_requested)
            session._enter(MachineState.HOLD)
            self._decelerate()
            return _Ending(reason)
        if self._overrides_changed():
            self._apply_overrides()
            return None
        session._enter(MachineState.HOLD)
        self._decelerate(hold=True)
        return self._hold()

    def _finish(self, ending: _Ending) -> tuple[RunReport, Trace]:
        """The report, from what every device says at the end; its diagnostics off."""
        reason = ending.reason
        if self.feed is not None:
            self.prepared = replace(self.prepared, program=self.feed.program(), plan=self.plan)
            if self.feed.error is not None and reason == StopReason.COMPLETED.value:
                reason = f"error: {self.feed.error}"
        if self.faults and not reason.startswith("fault"):
            reason = f"fault: {self._fault_words()}"
        statuses: dict[str, Status] = {}
        stats: dict[str, MotionStats] = {}
        for name in self.axes:
            client = self.machine.axis(name).client
            try:
                statuses[name] = client.status()
                stats[name] = client.motion_stats()
                client.set_diagnostics_interval(0)
            except UsbMotionError as error:
                self.notes.append(f"axis {name}: {error}")
        report = build_report(
            self.prepared.program, self.machine, self.plan,
            self.rows_before + self.setpoints.shape[0], self.trace,
            self.homing_s, statuses, stats, self.faults,
            completed=reason == StopReason.COMPLETED.value,
            consumed=self._confirmed(ending, statuses), skew_s=self.skew_s,
            stop_reason=reason, stop_distance_mm=self.stop_distance_mm,
            stop_planned_mm=self.stop_planned_mm, stop_latency_s=self.stop_latency_s,
            link_error=ending.link_error, notes=tuple(self.notes))
        self.faulted_axes = [name for name, status in statuses.items()
                             if status.fault != FaultCode.NONE]
        self.faulted = bool(self.faults) or bool(ending.link_error) or bool(self.faulted_axes)
        return report, self.trace

    # --- watching -------------------------------------------------------------------------------

    def _progress(self, update: StreamProgress) -> None:
        self._tell(min(s.consumed_estimate for s in self.streams.values()))

    def _program_time_s(self, row: float) -> float:
        """When the uninterrupted program passes where row ``row`` of the setpoints is."""
        if self.rows_before == 0 and len(self.legs) == 1 and self.legs[0][1].plan is self.plan:
            return row * self.period_s
        first, leg = self._leg_at(row)
        return locate(self.plan, leg, (row - first) * self.period_s).program_time_s

    def _leg_at(self, row: float) -> tuple[int, Leg]:
        """The leg row ``row`` of the setpoints belongs to, and the row it starts on."""
        found = self.legs[0]
        for first, leg in self.legs:
            if first <= row:
                found = (first, leg)
        return found

    def _tell(self, done: float) -> None:
        """Report progress: ``done`` setpoints of every axis executed."""
        if self.on_progress is not None:
            done_s = min(self._program_time_s(max(0.0, done)), self.plan.duration_s)
            row = self.setpoints[min(max(0, int(done) - 1), self.setpoints.shape[0] - 1)]
            where = {name: float(row[index]) / self.counts_per_mm[index]
                     for index, name in enumerate(self.axes)}
            actual: dict[str, float] = {}
            error: dict[str, float] = {}
            for name in self.axes:
                seen, wanted = self.trace.actual.get(name), self.trace.desired.get(name)
                if seen and wanted:
                    scale = self.config.axis(name).counts_per_mm
                    actual[name] = seen[-1] / scale
                    error[name] = (seen[-1] - wanted[-1]) / scale
            self.on_progress(Progress(self.session.state, where, line_at(self.plan, done_s),
                                      done_s, self.plan.duration_s, actual, error))

    def _on_alarm(self, axis: str, alarm: Alarm) -> None:
        self._record(axis, alarm.fault_name, alarm.tick)

    def _record(self, axis: str, fault: str, tick: int) -> None:
        if any(f.axis == axis for f in self.faults):
            return
        elapsed = (tick - self.trace.start_tick) * self.tick_s
        self.faults.append(FaultRecord(axis, fault, elapsed, line_at(self.plan, elapsed)))

    def _should_stop(self) -> bool:
        """Whether the streaming stops: a stop, a hold or an override was asked, or a device
        faulted. Every :data:`FAULT_CHECK_S` reads the alarm lines that came, and every
        :data:`STATUS_CHECK_S` asks every device its status in case one was lost."""
        return self._requested() or self._check_faults()

    def _check_faults(self, *, now_: bool = False) -> bool:
        """Whether a device faulted: reads the alarm lines that came (every
        :data:`FAULT_CHECK_S`, or at once with ``now_``) and every :data:`STATUS_CHECK_S`
        asks every device its status."""
        now = self.clock.now()
        if (not now_ and not self.faults
                and now - self.faults_read_s + self.check_s <= FAULT_CHECK_S):
            # the next wake still comes within FAULT_CHECK_S of the last read
            return bool(self.faults)
        self.faults_read_s = now
        for axis in self.machine.axes.values():
            axis.client.read_pending()
        if now - self.status_checked_s >= STATUS_CHECK_S:
            self.status_checked_s = now
            for name, axis in self.machine.axes.items():
                status = axis.client.status()
                if status.fault != FaultCode.NONE:
                    _, fault_tick = axis.client.fault()
                    self._record(name, status.fault_name, fault_tick)
        return bool(self.faults)

    def _requested(self) -> bool:
        """A stop or (before the program has played out) a hold or an override was asked."""
        session = self.session
        return bool(session.stop_requested) or (not self.drained and (
            session.hold_requested or self._overrides_changed()))

    def _overrides_changed(self) -> bool:
        return (self.session.feed_override_percent,
                self.session.rapid_override_percent) != self.overrides

    def _interrupted(self) -> bool:
        """A fault was seen, or a stop, a hold or an override asked."""
        return bool(self.faults) or self._requested()

    def _fault_words(self) -> str:
        return "; ".join(f"axis {f.axis} {f.fault}" for f in self.faults)

    def _wait_drained(self) -> bool:
        """Until every queue is empty (the last setpoint being executed): True; or a stop,
        or (a feed) more moves came: False."""
        clients = [self.machine.axis(n).client for n in self.axes]
        while True:
            if (self._should_stop() or self._feed_changed()
                    or self._release_limit() > self.released):
                return False
            queued = max(client.queue_status()[0] for client in clients)
            self._tell(min(stream.sent for stream in self.streams.values()) - queued)
            if not queued:
                return True
            wait = min(FAULT_CHECK_S, max(self.period_s, queued * self.period_s))
            self.clock.sleep(wait if self.feed is None else min(wait, self.check_s))

    def _settle(self) -> None:
        """After the last setpoint: until every axis is within SETTLE_COUNTS of it, for at
        most SETTLE_TIMEOUT_S."""
        deadline = self.clock.now() + SETTLE_TIMEOUT_S
        while self.clock.now() < deadline:
            statuses = self.machine.status()
            if all(abs(s.desired_counts - s.actual_counts) <= SETTLE_COUNTS
                   for s in statuses.values()):
                return
            self.clock.sleep(REST_POLL_S)

    # --- stopping -------------------------------------------------------------------------------

    def _seam(self) -> tuple[int, int]:
        """The first row that can still be replaced, a device tick just ahead, and its
        tick (call 38 replaces the queued future from there)."""
        estimate = self.sync.devices[0].estimate
        tick = math.ceil(estimate.ticks_at(self.clock.now()) + STOP_LEAD_S / self.tick_s)
        scalar = self.config.motion_scalar
        sent = min(stream.sent for stream in self.streams.values())
        index = min(max(0, -(-(tick - self.start_tick) // scalar)), sent)
        return index, max(tick, self.start_tick + index * scalar)

    def _replace(self, tick: int, index: int, rows: npt.NDArray[np.integer], *,
                 whole: bool = False) -> None:
        """Every axis's queued future from ``tick`` (row ``index``) replaced by ``rows``:
        the first :data:`REPLACE_BATCH` with call 38, the rest streamed after them."""
        self.setpoints = np.vstack((self.setpoints[:index], rows)).astype(np.int32)
        self.released = index
        limit = (index + rows.shape[0] if whole else
                 max(index + min(REPLACE_BATCH, rows.shape[0]), self._release_limit()))
        given = rows[:limit - index]
        for column, name in enumerate(self.axes):
            self.streams[name].replace_from(tick, index, given[:, column],
                                            most=REPLACE_BATCH)
        self.released = limit
        self.dry = False

    def _decelerate(self, *, hold: bool = False) -> None:
        """Every axis still enabled to rest along the path at its planned deceleration:
        the queued future replaced from a device tick just ahead (call 38). A hold keeps
        where on the program the axes came to rest (:attr:`hold_point`)."""
        session, machine, clock = self.session, self.machine, self.clock
        index, tick = self._seam()
        accel = [self.config.axis(n).max_accel_mm_s2 * self.config.axis(n).counts_per_mm
                 for n in self.axes]
        asked_s = (session._requests.hold_at_s if hold else
                   session._requests.at_s if session.stop_requested else clock.now())
        if index == 0 or index >= self.setpoints.shape[0]:
            stop_rows = np.zeros((0, len(self.axes)), dtype=np.int64)
            end = float(min(index, self.setpoints.shape[0]) - 1)
        else:
            stop = stop_setpoints(self.setpoints, index, period_s=self.period_s,
                                  accel_counts_s2=accel)
            stop_rows, end = stop.setpoints, stop.end_index
            speed_mm_s = float(np.linalg.norm(np.array(stop.velocity_counts_s)
                                              / self.counts_per_mm))
            decel_mm_s2 = stop.step * speed_mm_s / self.period_s
            if decel_mm_s2 > 0:
                self.stop_planned_mm = speed_mm_s**2 / (2 * decel_mm_s2)
        first, leg = self._leg_at(end)
        self.hold_point = replace(locate(self.plan, leg, (end - first) * self.period_s),
                                  speed_mm_s=0.0)
        self.stopped_index = (end if self._program_time_s(end) == end * self.period_s
                              else self.hold_point.program_time_s / self.period_s)
        self._replace(tick, index, stop_rows, whole=True)
        try:
            wait_for_rest(machine, list(self.axes), stop_now=session._stop_now_requested)
        except DeviceError as error:
            self.notes.append(f"stop: {error}")
            machine.stop()
        self.stop_latency_s = clock.now() - asked_s
        if index > 0:
            statuses = machine.status()
            rest = np.array([statuses[n].actual_counts for n in self.axes], dtype=np.float64)
            began = self.setpoints[index - 1].astype(np.float64)
            self.stop_distance_mm = float(np.linalg.norm((rest - began) / self.counts_per_mm))
        if hold:
            self.holds.append((asked_s, tick, self.stop_planned_mm, self.stop_distance_mm))
        else:
            self.stop_tick = tick
        if session._stop_now_requested():
            self.notes.append("a second stop request stopped every axis at once (servos off:"
                              " the axes coasted)")


    # --- a program still being written (a feed) and program pauses ------------------------------

    def _stream_feed(self) -> bool:
        """Stream a feed's moves as they come (and a program with pauses, up to each): True
        when the program has played out and settled; False when a request or a fault
        interrupted it, or the machine came to rest at a pause (:attr:`pausing`)."""
        while True:
            self._take_feed()
            self._release()
            run_streams(list(self.streams.values()), should_stop=self._feed_wake,
                        max_wait_s=self.check_s)
            if self._interrupted():
                return False
            if (self._feed_changed() or self._release_limit() > self.released
                    or not all(stream.done_sending for stream in self.streams.values())):
                continue
            if not self._wait_drained():
                if self._interrupted():
                    return False
                continue
            self._settle()
            if self._at_pause():
                return False
            self.dry = True
            self.rest_point = self._point_at(self.setpoints.shape[0] - 1)
            if self.fed_complete:
                return True
            feed = self.feed
            if feed is not None and not feed.has_source:
                if feed.finish_if(self.fed_version):
                    self.fed_complete = True
                    return True
                if not self._feed_changed():  # lines on their way: at rest until they come
                    self.clock.sleep(REQUEST_CHECK_S)

    def _feed_wake(self) -> bool:
        """Whether the streaming stops to look again: a request, a fault, more moves, a
        source to read further, or rows to give the streams."""
        if self._should_stop() or self._feed_changed():
            return True
        feed = self.feed
        if (feed is not None and feed.has_source and not self.fed_complete
                and feed.blocks_free > 0 and self._lookahead_s() < READ_AHEAD_S):
            return True
        return self._release_limit() >= self.released + math.ceil(RELEASE_S / self.period_s)

    def _feed_changed(self) -> bool:
        return self.feed is not None and self.feed.version != self.fed_version

    def _lookahead_s(self) -> float:
        """How much of the plan lies ahead of the machine, s."""
        return float((self.setpoints.shape[0] - self._executed()) * self.period_s)

    def _executed(self) -> int:
        """Rows of the setpoints the devices have probably executed."""
        return min((s.consumed_estimate for s in self.streams.values()), default=0)

    def _take_feed(self, *, streaming: bool = True) -> None:
        """Read a source further when the look-ahead runs short, and plan the moves the feed
        gained, joining them to what streams (:meth:`_join`)."""
        feed = self.feed
        if feed is None:
            return
        if streaming and self.streams:
            executed = self._point_at(max(0, min(self._executed(), self.setpoints.shape[0] - 1)))
            line = int(self.plan.line[executed.segment]) if 0 <= executed.segment < len(
                self.plan) else (self.fed_lines[-1] + 1 if self.fed_lines else 0)
            feed.executed(bisect.bisect_left(self.fed_lines, line))
        if (feed.has_source and not self.fed_complete
                and (not streaming or self._lookahead_s() < READ_AHEAD_S)):
            feed.pull()
        snapshot = feed.snapshot()
        if snapshot.version == self.fed_version:
            return
        self.fed_version = snapshot.version
        self.fed_complete = snapshot.complete
        if len(snapshot.moves) == self.fed_moves:
            return
        self.fed_moves = len(snapshot.moves)
        self.fed_lines = [move.line for move in snapshot.moves]
        self._join(feed.plan(snapshot), snapshot, streaming=streaming)

    def _swap_plan(self, plan: Plan, snapshot: FeedSnapshot) -> None:
        self.plan = plan
        self.pause_segments = _pause_segments(plan, snapshot.moves, snapshot.pauses)
        self.pause_records = list(snapshot.pauses)

    def _join(self, plan: Plan, snapshot: FeedSnapshot, *, streaming: bool) -> None:
        """The program's plan grown by more moves (its earlier segments are the same ones),
        joined to what streams: the rest is planned again from the latest row that cannot
        have felt the old plan's end at rest (:attr:`stop_time_s` before it), or from the
        first row the devices can still have replaced when that one has passed; rows not
        sent yet are revised in the streams, rows sent are replaced from a device tick just
        ahead (call 38), as an override does. After the machine ran everything and its
        queues ran empty, it starts again from there on a common tick."""
        self._swap_plan(plan, snapshot)
        if not streaming or not self.streams:
            return
        if not self.dry and self._queued_s() < DRY_MARGIN_S:
            self._drain()
        if self.dry:
            self._start_leg_at_rest()
            return
        first, leg = self.legs[-1]
        safe = first + int(max(0.0, leg.plan.duration_s - self.stop_time_s) / self.period_s)
        seam, _ = self._seam()
        row = max(min(self.released, safe), seam)
        sent = min(stream.sent for stream in self.streams.values())
        # A join inside a short segment (an arc's chord) may be unable to keep the speed
        # there (the piece left is short, so is its corner's limit): try the rows before it
        # (down to the seam), then those after it (up to the safe row).
        candidates = [*range(row, seam - 1, -RESEAM_ROWS), *range(row + RESEAM_ROWS, safe,
                                                                   RESEAM_ROWS)]
        for row in candidates:
            if row < sent:
                if self._replan_from_seam(start=row, only=True) is not None:
                    return
                continue
            try:
                rest = self._plan_rest(self._point_at(row))
            except PlanningError:
                continue
            break
        else:
            self.notes.append("more moves came too late to join the plan: the machine came"
                              " to rest before them")
            self._drain()
            self._start_leg_at_rest()
            return
        if rest is None:
            return
        rows = self._sample(rest)
        self.legs = [(at, old) for at, old in self.legs if at < row] + [(row, rest)]
        self.setpoints = np.vstack((self.setpoints[:row], rows)).astype(np.int32)
        given = max(row, min(self.released, self.setpoints.shape[0]))
        for column, name in enumerate(self.axes):
            self.streams[name].revise(row, rows[:given - row, column])
        self.released = given

    def _start_leg_at_rest(self) -> None:
        """The rest of the program from where the machine rests, on a common tick."""
        point = self.rest_point or self._point_at(self.setpoints.shape[0] - 1)
        leg = self._plan_rest(replace(point, speed_mm_s=0.0))
        if leg is not None:
            self._start_leg(leg)

    def _queued_s(self) -> float:
        """How long the rows given to the streams last beyond what the devices executed."""
        return (self.released - self._executed()) * self.period_s

    def _drain(self) -> None:
        """Until every queue is empty (whatever the feed does meanwhile), or a stop."""
        clients = [self.machine.axis(n).client for n in self.axes]
        while not self._should_stop() and max(c.queue_status()[0] for c in clients):
            self.clock.sleep(self.check_s)
        self.rest_point = self._point_at(self.setpoints.shape[0] - 1)

    def _release_limit(self, *, executed: int | None = None) -> int:
        """How many rows the streams may have: all of a complete program up to its next
        pause; of a feed still being written, those more moves cannot change (up to
        :attr:`stop_time_s` before its plan's end), or, when the feed runs short, enough
        to keep :data:`FEED_FLOOR_S` queued (the machine then runs into the end's
        deceleration: it can always stop at the end of the last move)."""
        total = self.setpoints.shape[0]
        limit = total
        if not self.fed_complete:
            first, leg = self.legs[-1]
            safe = first + int(max(0.0, leg.plan.duration_s - self.stop_time_s) / self.period_s)
            done = self._executed() if executed is None else executed
            limit = min(total, max(safe, done + math.ceil(FEED_FLOOR_S / self.period_s)))
        pause_row = self._next_pause_row()
        if pause_row is not None:
            limit = min(limit, pause_row + 1)
        return int(max(limit, self.released))

    def _release(self) -> None:
        """Give the streams the rows :meth:`_release_limit` allows."""
        limit = self._release_limit()
        if limit <= self.released:
            return
        for column, name in enumerate(self.axes):
            self.streams[name].extend(self.setpoints[self.released:limit, column])
        self.released = limit
        self.dry = False

    def _next_pause_row(self) -> int | None:
        """The row of the next pause on the leg streaming (None: none on it)."""
        if self.pauses_passed >= len(self.pause_segments):
            return None
        segment = self.pause_segments[self.pauses_passed]
        first, leg = self.legs[-1]
        hits = np.flatnonzero((leg.source == segment) & (leg.plan.kind == SegmentKind.DWELL))
        if not hits.size:
            return None
        return first + int(float(leg.plan.start_time_s[hits[0]]) / self.period_s)

    def _at_pause(self) -> bool:
        """Whether the machine came to rest at the next pause (then :attr:`pausing` and the
        hold point are set)."""
        row = self._next_pause_row()
        if row is None or self.released != row + 1:
            return False
        segment = self.pause_segments[self.pauses_passed]
        self.pausing = self.pause_records[self.pauses_passed]
        self.hold_point = PathPoint(segment, 0.0, 0.0,
                                    tuple(float(c) for c in self.plan.vertices_mm[segment]),
                                    0.0, float(self.plan.start_time_s[segment]))
        return True

    def _pause(self) -> _Ending | None:
        """At rest at a program pause: Hold until the operator resumes (the rest planned
        from there) or stops, as in a feed hold."""
        session, pause = self.session, self.pausing
        assert pause is not None
        self.pauses_passed += 1
        self.paused.append(pause)
        session._enter(MachineState.HOLD)
        session._pause_at(pause)
        try:
            return self._hold()
        finally:
            self.pausing = None
            session._pause_at(None)

    # --- holding, resuming, overrides -----------------------------------------------------------

    def _hold(self) -> _Ending | None:
        """At rest in Hold: until a resume (the rest of the path planned and streamed from
        there; None), a stop or a fault (the run's ending). The devices hear from the host
        at least every keep-alive period, so no watchdog trips while the operator waits."""
        session, clock = self.session, self.clock
        keep_alive_s = session.keep_alive_period_s()
        pinged = clock.now()
        session.held = True
        try:
            return self._hold_at_rest(keep_alive_s, pinged)
        finally:
            session.held = False

    def _hold_at_rest(self, keep_alive_s: float, pinged: float) -> _Ending | None:
        session, clock = self.session, self.clock
        while True:
            if session._stop_now_requested():
                self.machine.stop()
                return _Ending(session.stop_requested)
            if session.stop_requested:
                return _Ending(session.stop_requested)
            if self._check_faults(now_=True):
                return _Ending(f"fault: {self._fault_words()}")
            _, resume = session._take_hold_request()
            if resume:
                break
            now = clock.now()
            if keep_alive_s and now - pinged >= keep_alive_s:
                session.keep_alive()
                pinged = now
            clock.sleep(REQUEST_CHECK_S)
        session._enter(MachineState.RUN)
        return self._resume()

    def _resume(self) -> _Ending | None:
        """The rest of the path planned from rest where the hold left the axes, and every
        axis started on it on one device tick (call 31, the clocks not zeroed)."""
        self._take_feed(streaming=False)
        point = self.hold_point
        self.overrides = (self.session.feed_override_percent,
                          self.session.rapid_override_percent)
        leg = self._plan_rest(point) if point is not None else None
        if leg is None:
            if self.feed is not None and not self.fed_complete:
                return self._wait_for_feed()
            self.drained = True
            return _Ending(StopReason.COMPLETED.value)
        self._start_leg(leg)
        return None

    def _start_leg(self, leg: Leg) -> None:
        """Stream ``leg`` from rest, every axis started on one device tick (call 31, the
        clocks not zeroed)."""
        self.rows_before += self.setpoints.shape[0]
        self.legs = [(0, leg)]
        self.setpoints = self._sample(leg)
        clients = [self.machine.axis(n).client for n in self.axes]
        self.sync = synchronise_start(clients, margin_s=RESUME_MARGIN_S, zero=False)
        self.start_tick = self.sync.devices[0].start_tick
        self.dry = False
        self._open_streams()

    def _wait_for_feed(self) -> _Ending | None:
        """Resumed at the end of what a feed has given: at rest there until more comes."""
        self.dry = True
        self.rest_point = self.hold_point
        self.released = self.setpoints.shape[0]
        return None

    def _apply_overrides(self) -> None:
        """The queued future planned again at the session's overrides from a row a device
        tick just ahead, at the speed the axes have there, and replaced from that tick."""
        session = self.session
        self.overrides = (session.feed_override_percent, session.rapid_override_percent)
        tick = self._replan_from_seam()
        if tick is None:
            self.notes.append(f"overrides {self.overrides} came too late to change the"
                              " program's end")
        else:
            self.seams.append((session.override_at_s, tick))

    def _replan_from_seam(self, *, start: int = 0, only: bool = False) -> int | None:
        """The queued future planned again (the program's rest at the overrides) from a row
        a device tick just ahead (or row ``start``, when later), at the speed the axes have
        there, and replaced from that tick (call 38): the tick, or None when no row is left
        to replace (or, with ``only``, when that row cannot be planned from)."""
        index = max(self._seam()[0], start)
        scalar = self.config.motion_scalar
        sent = min(stream.sent for stream in self.streams.values())
        while index < min(sent, self.setpoints.shape[0] - 1) or (
                index < sent and self.feed is not None):
            point = self._point_at(index)
            try:
                rest = self._plan_rest(point)
            except PlanningError:
                if only:
                    return None
                index += RESEAM_ROWS
                continue
            if rest is None:
                return None
            tick = self.start_tick + index * scalar
            self.legs = [(row, old) for row, old in self.legs if row < index] + [(index, rest)]
            self._replace(tick, index, self._sample(rest))
            return tick
        return None

    def _point_at(self, row: int) -> PathPoint:
        """The point of the program where row ``row`` of the setpoints is (after the end of
        its leg: that end, at rest, on the segment after the leg's last)."""
        first, leg = self._leg_at(row)
        elapsed = (row - first) * self.period_s
        if len(leg.plan) and elapsed < leg.plan.duration_s:
            return locate(self.plan, leg, elapsed)
        end = leg.plan.vertices_mm[-1]
        segment = int(leg.source[-1]) + 1 if len(leg.plan) else 0
        when = (float(self.plan.start_time_s[segment]) if segment < len(self.plan)
                else self.plan.duration_s)
        return PathPoint(segment, 0.0, 0.0, tuple(float(c) for c in end), 0.0, when)

    def _plan_rest(self, point: PathPoint) -> Leg | None:
        feed, rapid = self.overrides
        return plan_rest(self.plan, point, self.limits, self.planner_config,
                         feed_scale=feed / 100.0, rapid_scale=rapid / 100.0)

    def _sample(self, leg: Leg) -> npt.NDArray[np.int32]:
        return sample_plan(leg.plan, period_s=self.period_s,
                           counts_per_mm=list(self.counts_per_mm))

    def _confirmed(self, ending: _Ending, statuses: dict[str, Status]) -> int:
        """How many setpoints of every axis the devices are known to have executed."""
        if ending.link_error:
            return self.streams[ending.lost_axis].sent if ending.lost_axis else min(
                s.sent for s in self.streams.values())
        if self.stopped_index is not None:
            return max(0, math.floor(self.stopped_index) + 1)
        return min(self.streams[n].sent - statuses[n].queued for n in self.axes
                   if n in statuses)
