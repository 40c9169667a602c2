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

import math
from collections.abc import Callable
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
from usbmotion.motion.replanning import Leg, PathPoint, locate, plan_rest, whole_program
from usbmotion.motion.sampler import sample_plan
from usbmotion.motion.stopping import stop_setpoints
from usbmotion.protocol import FaultCode
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
                 on_progress: Callable[[Progress], None] | None, homing_s: float) -> None:
        self.session = session
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
        self.rows_before = 0
        """Rows executed before the last resume."""
        self.hold_point: PathPoint | None = None
        """Where on the program the axes came to rest in a feed hold."""
        self.holds: list[tuple[float, int, float, float]] = []
        """Every hold's request time (s), the device tick its deceleration began on, its
        planned v^2/2a and its distance (mm)."""
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
        for index, name in enumerate(self.axes):
            self.streams[name] = SetpointStream(
                self.machine.axis(name).client, self.setpoints[:, index], period_s=self.period_s,
                verify=True, on_progress=self._progress)

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
        run_streams(list(self.streams.values()), should_stop=self._should_stop,
                    max_wait_s=self.check_s)
        if not self._interrupted():
            self._wait_drained()
        if not self._interrupted():
            self.drained = True
            self._settle()
        if self.drained and not (self.faults or session.stop_requested):
            return _Ending(StopReason.COMPLETED.value)
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
            self.on_progress(Progress(self.session.state, where, line_at(self.plan, done_s),
                                      done_s, self.plan.duration_s))

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

    def _wait_drained(self) -> None:
        """Until every queue is empty (the last setpoint being executed), or a stop."""
        clients = [self.machine.axis(n).client for n in self.axes]
        while True:
            if self._should_stop():
                return
            queued = max(client.queue_status()[0] for client in clients)
            self._tell(min(stream.sent for stream in self.streams.values()) - queued)
            if not queued:
                return
            self.clock.sleep(min(FAULT_CHECK_S, max(self.period_s, queued * self.period_s)))

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

    def _replace(self, tick: int, index: int, rows: npt.NDArray[np.integer]) -> None:
        """Every axis's queued future from ``tick`` (row ``index``) replaced by ``rows``:
        the first :data:`REPLACE_BATCH` with call 38, the rest streamed after them."""
        batch = rows[:REPLACE_BATCH]
        for column, name in enumerate(self.axes):
            client = self.machine.axis(name).client
            try:
                client.replace_from(tick, batch[:, column].tolist())
            except UsbMotionError as error:
                self.notes.append(f"axis {name}: could not replace its queue ({error})")
            self.streams[name].replace_future(index, rows[:, column], sent=batch.shape[0])
        self.setpoints = np.vstack((self.setpoints[:index], rows)).astype(np.int32)

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
        self._replace(tick, index, stop_rows)
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
        if session._stop_now_requested():
            self.notes.append("a second stop request stopped every axis at once (servos off:"
                              " the axes coasted)")

    # --- holding, resuming, overrides -----------------------------------------------------------

    def _hold(self) -> _Ending | None:
        """At rest in Hold: until a resume (the rest of the path planned and streamed from
        there; None), a stop or a fault (the run's ending). The devices hear from the host
        at least every keep-alive period, so no watchdog trips while the operator waits."""
        session, clock = self.session, self.clock
        keep_alive_s = session.keep_alive_period_s()
        pinged = clock.now()
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
        point = self.hold_point
        self.overrides = (self.session.feed_override_percent,
                          self.session.rapid_override_percent)
        leg = self._plan_rest(point) if point is not None else None
        if leg is None:
            self.drained = True
            return _Ending(StopReason.COMPLETED.value)
        self.rows_before += self.setpoints.shape[0]
        self.legs = [(0, leg)]
        self.setpoints = self._sample(leg)
        clients = [self.machine.axis(n).client for n in self.axes]
        self.sync = synchronise_start(clients, margin_s=RESUME_MARGIN_S, zero=False)
        self.start_tick = self.sync.devices[0].start_tick
        self._open_streams()
        return None

    def _apply_overrides(self) -> None:
        """The queued future planned again at the session's overrides from a row a device
        tick just ahead, at the speed the axes have there, and replaced from that tick."""
        session = self.session
        self.overrides = (session.feed_override_percent, session.rapid_override_percent)
        asked_s = session.override_at_s
        index, _ = self._seam()
        scalar = self.config.motion_scalar
        sent = min(stream.sent for stream in self.streams.values())
        while index < min(sent, self.setpoints.shape[0] - 1):
            first, leg = self._leg_at(index)
            point = locate(self.plan, leg, (index - first) * self.period_s)
            try:
                rest = self._plan_rest(point)
            except PlanningError:
                index += RESEAM_ROWS
                continue
            if rest is None:
                return
            tick = self.start_tick + index * scalar
            self._replace(tick, index, self._sample(rest))
            self.legs = [(row, old) for row, old in self.legs if row < index] + [(index, rest)]
            self.seams.append((asked_s, tick))
            return
        self.notes.append(f"overrides {self.overrides} came too late to change the program's"
                          " end")

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
