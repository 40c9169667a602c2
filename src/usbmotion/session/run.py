"""One run of a program (or of lines as they come, or a jog) on a session's machine.

Every program axis starts on the same device tick and is streamed its setpoints
(:mod:`usbmotion.session.streaming`); the run listens to the devices
(:mod:`usbmotion.session.watch`: diagnostics into the live model and the trace, alarms)
and takes the operator's requests at each look (:mod:`usbmotion.session.requests`). What
happens is an event the machine's state decides on (:mod:`usbmotion.session.state`), and
the run does what the new state asks: Run and Jog stream; Hold decelerates along the path
(:mod:`usbmotion.session.seams`) and waits at rest for a resume (the rest of the path
planned from there, every axis started again on one device tick) or a stop; Paused waits
likewise; Stopping decelerates, then Idle; Alarm stops every other axis along the path (a
lost link: every axis at once). An override plans the queued future again at the new
speed from a device tick just ahead, without a change of state.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from contextlib import ExitStack
from dataclasses import replace

from usbmotion.errors import (
    DeviceTimeoutError,
    LinkCorruptedError,
    LinkLostError,
    QueueUnderrunError,
    StartMissedError,
    UsbMotionError,
)
from usbmotion.host.spindle import Spindle
from usbmotion.motion.gcode import Pause
from usbmotion.motion.replanning import PathPoint
from usbmotion.protocol import FaultCode
from usbmotion.session.context import RunContext
from usbmotion.session.ending import Ending, Stops, internal_error, link_lost, read_ends, report_of
from usbmotion.session.feed import ProgramFeed
from usbmotion.session.feeding import Feeding
from usbmotion.session.legs import Legs
from usbmotion.session.outputs import RunOutputs, laser_names
from usbmotion.session.planning import Prepared, planner_inputs
from usbmotion.session.progress import RunProgress
from usbmotion.session.report import RunReport, SpindleRecord, Trace
from usbmotion.session.seams import decelerate, rejoin, replan_from_seam, stop_time_s
from usbmotion.session.state import Event, MachineState, StopReason
from usbmotion.session.streaming import RunStreams
from usbmotion.session.watch import FAULT_CHECK_S, Watch

SPINDLE_POLL_S = 0.01
"""How often a spindle pause reads the spindle's speed while it waits for it."""
SPINDLE_CHECK_S = 0.1
"""How often a running program reads the spindle's speed (a stall's latency)."""
REQUEST_CHECK_S = 0.01
"""The longest a live run goes without looking at the operator's requests (hold, stop,
overrides): with the stop's lead it bounds a hold's latency."""


class Run:
    """One run on a session's machine (see the module docstring); :meth:`go` runs it once.

    Parameters:
        context: the session's parts.
        prepared: the program, prepared from where the machine stands.
        homing_s: how long the homing before the run took, for the report.
        feed: the feed of a program still being written (None: the program is whole).
        overrides: whether the feed and rapid overrides apply (a jog runs at 100 %).
    """

    def __init__(self, context: RunContext, prepared: Prepared, *, homing_s: float = 0.0,
                 feed: ProgramFeed | None = None, overrides: bool = True) -> None:
        self.context = context
        self.machine, self.config = context.machine, context.config
        self.clock = context.machine.clock
        self.states, self.requests, self.live = context.states, context.requests, context.live
        self.prepared = prepared
        self.homing_s = homing_s
        self.axes = prepared.axes
        config = self.config
        limits, planner, _ = planner_inputs(config)
        self.follows_overrides = overrides
        self.legs = Legs(prepared.plan, period_s=config.motion_period_s,
                         counts_per_mm=[config.axis(n).counts_per_mm for n in self.axes],
                         limits=limits, planner=planner, overrides=self._overrides())
        self.streams = RunStreams(self.machine, self.axes, period_s=config.motion_period_s,
                                  scalar=config.motion_scalar)
        axes_config = [config.axis(n) for n in self.axes]
        self.feeding = Feeding(prepared, feed, self.legs, self.streams, stop_time_s=stop_time_s(
            [(a.max_velocity_mm_s, a.max_accel_mm_s2) for a in axes_config]))
        self.accel_mm_s2 = [a.max_accel_mm_s2 for a in axes_config]
        self.trace = Trace(tick_s=config.servo_period_s, start_tick=0,
                           counts_per_mm={n: self.machine.axis(n).config.counts_per_mm
                                          for n in self.machine.axes})
        self.progress = RunProgress(self.live, self.legs, self.streams, self.feeding,
                                    prepared.program, fields=context.live_fields,
                                    hear=lambda: self.watch.hear())  # noqa: PLW0108 - made below
        self.watch = Watch(self.machine, self.trace, self.live,
                           line_at_tick=self.progress.line_at_tick)
        outputs = config.outputs
        self.outputs = None if outputs is None or not outputs.pins else RunOutputs(
            outputs, {name: axis.client for name, axis in self.machine.axes.items()},
            prepared.program.outputs, period_s=config.motion_period_s)
        self.check_s = REQUEST_CHECK_S if context.live_control else FAULT_CHECK_S
        self.notes: list[str] = [] if prepared.homed else [
            "the machine is not homed: the program ran in the devices' own counts and soft"
            " limits were not checked"]
        self.stops = Stops()
        self.hold_point: PathPoint | None = None
        self.rejoin = False
        """Whether the axes stand off the hold point (a hold that came late) until the resume
        brings them onto it."""
        self.paused: list[Pause] = []
        """The program pauses the run waited at, in order."""
        self.spindle_waits: list[tuple[int, float, float, float]] = []
        """Each spindle pause: its line, the speed asked (rpm), how long the program waited
        for it (s) and the speed measured when it went on (rpm)."""
        self._spindle_read_s = 0.0
        self.seams: list[tuple[float, int]] = []
        """Every override's request time (s) and the device tick its new speed began on."""
        self.skew_s = 0.0
        self.resting = False
        """Every axis came to rest (a stop, a hold, a pause) and nothing started since."""
        self.pause_line = 0
        """The line of the pause the machine waits at (0: none): the line it executes."""
        self.faulted_axes: list[str] = []
        self.faulted = False
        """True when the run ended on a fault or a lost link (the machine is in Alarm)."""

    @property
    def holds(self) -> list[tuple[float, int, float, float]]:
        """Every hold's request time (s), the device tick its deceleration began on, its
        planned v^2/2a and its distance (mm)."""
        return self.stops.holds

    def go(self) -> tuple[RunReport, Trace]:
        """The run: its report and its trace."""
        with ExitStack() as listening:
            ending = self._guarded(lambda: self._begin(listening))
            if ending is None:
                ending = self._guarded(self._drive)
            assert ending is not None
            return self._finish(ending)

    def _begin(self, listening: ExitStack) -> None:
        """Servos on, the devices heard, every axis started on one device tick."""
        self.streams.enable()
        self.watch.listen_diagnostics(listening)
        self._start(first=True)
        self.watch.listen_alarms(listening)

    def _guarded(self, step: Callable[[], Ending | None]) -> Ending | None:
        """``step``'s ending; a lost link (every axis stopped at once), a queue that ran dry
        or a start armed too late (every axis held where it stands: its schedule is lost) or
        an error on the way (every axis to rest along the path if it can be), starting too,
        ends the run in Alarm, never with the state left running."""
        try:
            return step()
        except (LinkLostError, LinkCorruptedError, DeviceTimeoutError) as error:
            ending = link_lost(self.machine, self.axes, error, self.notes)
        except (QueueUnderrunError, StartMissedError) as error:
            ending = internal_error(error)
            try:  # no schedule to decelerate along: every axis held where it stands
                self.streams.hold_where_they_stand()
            except UsbMotionError:
                self.machine.stop()
        except (UsbMotionError, ArithmeticError, LookupError, TypeError, ValueError) as error:
            ending = internal_error(error)
            if self.states.state is not MachineState.ALARM:
                self.states.fire(Event.FAULT)
            try:
                if self.streams.sync is None:  # nothing started: nothing to decelerate
                    raise ValueError("not started")
                self._decelerate(asked_s=self.clock.now())
            except (UsbMotionError, ArithmeticError, LookupError, TypeError, ValueError):
                self.machine.stop()
        if self.states.state is not MachineState.ALARM:
            self.states.fire(Event.FAULT)
        return ending

    # --- starting --------------------------------------------------------------------------------

    def _start(self, *, first: bool) -> None:
        """Every axis started on one device tick (the first time: statistics reset and the
        diagnostics lines at the trace's period, or the live one), its streams opened:
        every device held while its queue takes its first values, then all armed."""

        def fill() -> None:
            if first:
                self.watch.begin(self.axes, self.legs.plan.duration_s,
                                 live=self.context.live_control)
            self.streams.released = 0
            self.streams.open(self.legs.rows, self.feeding.release_limit(executed=0))
            self.streams.fill()

        self.resting = False
        sync = self.streams.start(fill, first=first)
        if first:
            self.skew_s = sync.estimated_skew_s
            self.trace.start_tick = self.streams.start_tick
        self._outputs_from(0)
        self.feeding.dry = False
        self.watch.start(self.clock.now(), check_s=self.check_s)

    def _restart(self, point: PathPoint) -> None:
        """The rest of the program from ``point`` (at rest), every axis started on one
        device tick again (the clocks not zeroed)."""
        leg = self.legs.plan_rest(point)
        if leg is not None:
            self.legs.start(leg)
            self._start(first=False)

    # --- the state machine's loop ----------------------------------------------------------------

    def _drive(self) -> Ending:
        while True:
            state = self.states.state
            if state in (MachineState.RUN, MachineState.JOG):
                ending = self._stream()
            elif state is MachineState.HOLD:
                ending = self._hold()
            elif state is MachineState.PAUSED:
                ending = self._wait_at_rest()
            elif state in (MachineState.STOPPING, MachineState.ALARM):
                return self._stop()
            else:
                return Ending(StopReason.COMPLETED.value)
            if ending is not None:
                return ending

    def _look(self, *, at_once: bool = False) -> bool:
        """Take the requests and read the faults; True when something asks the run to
        change what it does (a fault, a stop, a hold, a jog cancel, an override, a resume
        while held). Publishes the live model when due."""
        self.requests.take()
        faulted = self.watch.check(self.clock.now(), at_once=at_once)
        spindle = self.machine.spindle
        if spindle is not None and spindle.running:
            faulted = self._check_spindle(spindle) or faulted
        if self.outputs is not None and self.streams.sync is not None:
            now_tick = self.streams.device_tick()
            self.outputs.service(now_tick, tick_s=self.streams.tick_s)
            if self.feeding.dry:  # at rest after every row: a change with no move after it
                self.outputs.finish(self.legs.plan, tick=math.ceil(now_tick))
        fed = self.feeding.feed is not None
        self.publish(force=fed)
        if fed:  # a fed program's window follows what the live model shows
            shown = self.live.read()
            self.feeding.executed_moves(shown.line, shown.done_s)
        taken = self.requests.taken
        state = self.states.state
        return bool(faulted or taken.stop_reason
                    or (taken.jog_cancel and state is MachineState.JOG)
                    or (taken.hold and state in (MachineState.RUN, MachineState.JOG))
                    or (taken.resume and state in (MachineState.HOLD, MachineState.PAUSED))
                    or self._overrides() != self.legs.overrides)

    def _check_spindle(self, spindle: Spindle) -> bool:
        """The spindle's queue fed, and every :data:`SPINDLE_CHECK_S` its speed read: a
        stall is the run's fault."""
        spindle.service()
        now = self.clock.now()
        if now - self._spindle_read_s < SPINDLE_CHECK_S:
            return False
        self._spindle_read_s = now
        spindle.read()
        stalled = spindle.stalled()
        if stalled is None:
            return False
        self.watch.record_words("spindle", stalled, tick=self._device_tick(),
                                line=self.live.read().line)
        return True

    def _event(self) -> None:
        """What the run's requests and faults make of the state (or of the speed)."""
        taken = self.requests.taken
        if self.watch.faults:
            self.states.fire(Event.FAULT)
        elif taken.stop_reason or (taken.jog_cancel and self.states.state is MachineState.JOG):
            self.states.fire(Event.STOP, at_rest=False)
        elif taken.hold and self.states.state in (MachineState.RUN, MachineState.JOG):
            self.states.fire(Event.HOLD, at_rest=False)
        elif self._overrides() != self.legs.overrides:
            self._apply_overrides()

    def _overrides(self) -> tuple[int, int]:
        """The feed and rapid overrides the run plans at (100 % for a jog)."""
        taken = self.requests.taken
        return (taken.feed_override, taken.rapid_override) if self.follows_overrides else (
            100, 100)

    # --- Run and Jog -----------------------------------------------------------------------------

    def _stream(self) -> Ending | None:
        """Stream until the program plays out (Idle) or an event changes the state."""
        if self.feeding.stepped:
            done = self.feeding.stream(self._look, take=self._take_feed, check_s=self.check_s)
        else:
            self.streams.stream(self._look, max_wait_s=self.check_s,
                                sends_from=self.watch.next_status_s)
            done = not self._look() and self.feeding.wait_drained(self._look,
                                                                  check_s=self.check_s)
            if done:
                self.streams.settle()
        if done:
            if self.outputs is not None:
                self.outputs.finish(self.legs.plan, tick=math.ceil(self.streams.device_tick()))
            self.states.fire(Event.DONE)
            self.publish(force=True)
            return Ending(StopReason.COMPLETED.value)
        pause = None if self._look() else self.feeding.at_pause()
        if pause is not None:
            return self._enter_pause(pause)
        self._event()
        return None

    def _take_feed(self, *, streaming: bool = True) -> None:
        count = self.legs.count
        self.feeding.take(streaming=streaming, restart=self._restart, drain=self._drain)
        feed = self.feeding.feed
        if self.outputs is not None and feed is not None:
            changes = feed.program().outputs
            if changes != self.outputs.changes:
                self.outputs.changes = changes
                count = -1
        if self.outputs is not None and self.legs.count != count and self.streams.sync:
            self._outputs_from(self.streams.seam()[0])

    def _outputs_from(self, row: int) -> None:
        """The output changes queued again from row ``row`` of the rows now (a start, a
        seam, more lines), and those due sent."""
        if self.outputs is None:
            return
        self.outputs.rebuild(self.legs, start_tick=self.streams.start_tick,
                             scalar=self.streams.scalar, from_row=row)
        self.outputs.service(self.streams.device_tick(), tick_s=self.streams.tick_s)

    def _drain(self) -> None:
        self.streams.drain(lambda: bool(self._look() and self.requests.taken.stop_reason),
                           poll_s=self.check_s)

    # --- overrides -------------------------------------------------------------------------------

    def _apply_overrides(self) -> None:
        """The queued future planned again at the new overrides from a row a device tick
        just ahead, at the speed the axes have there, and replaced from that tick."""
        taken = self.requests.taken
        self.legs.overrides = self._overrides()
        tick = replan_from_seam(self.legs, self.streams, growing=not self.feeding.complete,
                                release_limit=self.feeding.release_limit)
        if tick is None:
            self.notes.append(f"overrides {self.legs.overrides} came too late to change the"
                              " program's end")
        else:
            self.seams.append((taken.override_at_s, tick))
            self._outputs_from(max(0, -(-(tick - self.streams.start_tick)
                                       // self.streams.scalar)))

    # --- Hold, Paused, Stopping ------------------------------------------------------------------

    def _decelerate(self, *, asked_s: float) -> None:
        """Every axis to rest along the path (:func:`decelerate`), its figures kept."""
        if self.outputs is not None:  # grbl's laser mode: the laser off on a hold or stop
            self.outputs.off_now(laser_names(self.config.outputs),
                                 tick=math.ceil(self.streams.device_tick()))
        stopped = decelerate(self.legs, self.streams, self.machine,
                             accel_mm_s2=self.accel_mm_s2, stop_now=self._stop_now)
        if stopped.note:
            self.notes.append(stopped.note)
        self.stops.take(stopped, asked_s=asked_s, now_s=self.clock.now(),
                        line=self.legs.place(stopped.stopped_row).line,
                        hold=self.states.state is MachineState.HOLD)
        self.hold_point = stopped.point
        self.rejoin = stopped.late_s > 0  # it ended beside the path where the path curves
        if self.requests.taken.stop_now:
            self.notes.append("a second stop request stopped every axis at once (servos off:"
                              " the axes coasted)")
        self.publish(force=True, at_rest=True)

    def _stop_now(self) -> bool:
        """Whether a second stop was asked (every axis stopped at once)."""
        self.requests.take()
        return self.requests.taken.stop_now

    def _hold(self) -> Ending | None:
        """A feed hold: decelerate along the path, then at rest until a resume (the rest
        of the path planned and streamed from there) or a stop."""
        self._decelerate(asked_s=self.requests.taken.hold_at_s)
        return self._wait_at_rest()

    def _enter_pause(self, pause: Pause) -> Ending | None:
        self.pause_line = pause.line
        if pause.spindle_rpm is not None:
            self.hold_point = self.feeding.pass_pause()
            return self._spindle_pause(pause, pause.spindle_rpm)
        self.requests.clear_hold()
        self.hold_point = self.feeding.pass_pause()
        self.paused.append(pause)
        self.states.fire(Event.PAUSE)
        self.context.on_pause(pause)
        self.publish(force=True, at_rest=True)
        return None

    def _spindle_pause(self, pause: Pause, rpm: float) -> Ending | None:
        """At rest at a spindle pause: the spindle to ``rpm``, and the program on once its
        encoder says it is there (within ``at_speed_tolerance``); no speed within the ramp
        and ``spin_up_timeout_s`` is an alarm. A stop or a fault meanwhile ends the run."""
        spindle = self.machine.spindle
        self.publish(force=True, at_rest=True)
        if spindle is not None:
            clock = self.clock
            began = clock.now()
            deadline = began + spindle.ramp_s(rpm) + spindle.config.spin_up_timeout_s
            unchanged = spindle.commanded_rpm == rpm and spindle.now.at_speed
            spindle.command(rpm)
            keep_alive_s, pinged = self.context.keep_alive_s, began
            taken = self.requests.taken
            while not spindle.read().at_speed:
                self._look(at_once=True)
                if self.watch.faults:
                    self.states.fire(Event.FAULT)
                    return self._stop()
                if taken.stop_reason:
                    self.states.fire(Event.STOP, at_rest=True)
                    self._spindle_off()
                    return Ending(taken.stop_reason)
                now = clock.now()
                if now > deadline:
                    measured = spindle.now.measured_rpm
                    self.watch.record_words(
                        "spindle", f"spindle not at speed: {measured:.0f} rpm measured"
                        f" {now - began:.1f} s after line {pause.line} asked {rpm:g} rpm",
                        tick=self._device_tick(), line=pause.line)
                    self.states.fire(Event.FAULT)
                    return self._stop()
                if keep_alive_s and now - pinged >= keep_alive_s:
                    self.context.keep_alive()
                    pinged = now
                clock.sleep(SPINDLE_POLL_S)
            if not unchanged:
                self.spindle_waits.append(
                    (pause.line, rpm, clock.now() - began, spindle.now.measured_rpm))
            self.publish(force=True, at_rest=True)
        return self._resume()

    def _device_tick(self) -> int:
        """The program axes' last device tick the live model has."""
        ticks = [axis.tick for axis in self.live.read().axes.values()]
        return max(ticks, default=self.streams.start_tick)

    def _spindle_off(self) -> None:
        """The spindle to rest along its ramp (a stop, an alarm: grbl's and LinuxCNC's
        spindle stops with the program)."""
        spindle = self.machine.spindle
        if spindle is not None and spindle.commanded_rpm:
            spindle.command(0.0)

    def _wait_at_rest(self) -> Ending | None:
        """At rest (Hold, Paused): until a resume (None: the run goes on), a stop or a
        fault (the run's ending). The devices hear from the host at least every
        keep-alive period, so no watchdog trips while the operator waits."""
        keep_alive_s, pinged = self.context.keep_alive_s, self.clock.now()
        taken = self.requests.taken
        while True:
            self._look(at_once=True)
            if taken.stop_now:
                self.machine.stop()
            if self.watch.faults:
                self.states.fire(Event.FAULT)
                return self._stop()
            if taken.stop_reason:
                self.states.fire(Event.STOP, at_rest=True)
                self.context.on_pause(None)
                return Ending(taken.stop_reason)
            if taken.resume:
                break
            now = self.clock.now()
            if keep_alive_s and now - pinged >= keep_alive_s:
                self.context.keep_alive()
                pinged = now
            self.clock.sleep(REQUEST_CHECK_S)
        self.requests.clear_hold()
        self.context.on_pause(None)
        self.states.fire(Event.RESUME, at_rest=True)
        return self._resume()

    def _resume(self) -> Ending | None:
        """The rest of the path planned from rest where the axes stand, every axis
        started on one device tick."""
        self.pause_line = 0
        self._take_feed(streaming=False)
        self.legs.overrides = self._overrides()
        point = self.hold_point
        if point is not None and self.rejoin:
            rejoin(self.machine, self.streams.axes, point, counts_per_mm=self.legs.counts_per_mm,
                   accel_mm_s2=self.accel_mm_s2, period_s=self.legs.period_s,
                   stop_now=self._stop_now)
        self.rejoin = False
        leg = self.legs.plan_rest(point) if point is not None else None
        if leg is None:
            if not self.feeding.complete:
                self.feeding.rest_at(point)
                return None
            if self.outputs is not None and self.streams.sync is not None:
                self.outputs.finish(self.legs.plan, tick=math.ceil(self.streams.device_tick()))
            self.states.fire(Event.DONE)
            return Ending(StopReason.COMPLETED.value)
        self.legs.start(leg)
        self._start(first=False)
        return None

    def _stop(self) -> Ending:
        """Stopping (a stop asked) or Alarm (a fault): every axis still enabled to rest
        along the path; then Idle (a stop) or the run ends in Alarm."""
        taken = self.requests.taken
        faulted = self.states.state is MachineState.ALARM
        asked_s = taken.stop_at_s if taken.stop_reason else self.clock.now()
        self._decelerate(asked_s=asked_s)
        self._spindle_off()
        if self.outputs is not None:  # a stop or an alarm: coolant and laser off
            self.outputs.off_now(tuple(self.outputs.config.pins),
                                 tick=math.ceil(self.streams.device_tick()))
        if faulted:
            return Ending(f"fault: {self.watch.words()}")
        self.states.fire(Event.AT_REST)
        return Ending(taken.stop_reason or StopReason.JOG_CANCELLED.value)

    # --- the live model --------------------------------------------------------------------------

    def publish(self, *, force: bool = False, at_rest: bool | None = None) -> None:
        """The live model from the devices' last lines: the line they execute, progress."""
        if at_rest is not None:
            self.resting = at_rest
        if not self.progress.wanted(force=force):
            return
        state = self.states.state
        self.progress.publish(
            state, force=force, hold_pending=self.requests.taken.hold,
            at_rest=self.resting or self.feeding.dry or state is MachineState.IDLE,
            pause=self.paused[-1].message if state is MachineState.PAUSED else "",
            line=self.pause_line)

    # --- the end ------------------------------------------------------------------------------

    def _finish(self, ending: Ending) -> tuple[RunReport, Trace]:
        """The report, from what every device says at the end; their diagnostics off."""
        feed = self.feeding.feed
        if feed is not None:
            self.prepared = replace(self.prepared, program=feed.program(), plan=self.legs.plan)
            if feed.error is not None and ending.reason == StopReason.COMPLETED.value:
                ending.reason = f"error: {feed.error}"
        if self.watch.faults and not ending.reason.startswith("fault"):
            ending.reason = f"fault: {self.watch.words()}"
        statuses, stats = read_ends(self.machine, self.axes, self.notes)
        self.watch.hear()
        self.notes.extend(self.feeding.notes)
        report = report_of(self.prepared, self.machine, self.legs, self.streams, self.watch,
                           self.live, self.trace, ending, self.stops, homing_s=self.homing_s,
                           skew_s=self.skew_s, notes=self.notes, statuses=statuses,
                           stats=stats, line_at_tick=self.progress.line_at_tick,
                           segments_at_ticks=self.progress.segments_at_ticks)
        report = replace(report, spindle=tuple(
            SpindleRecord(line, rpm, waited_s, measured)
            for line, rpm, waited_s, measured in self.spindle_waits),
            outputs=() if self.outputs is None else self.outputs.records())
        self.faulted_axes = [name for name, status in statuses.items()
                             if status.fault != FaultCode.NONE]
        self.faulted = bool(self.watch.faults or ending.link_error or self.faulted_axes)
        return report, self.trace
