"""The machine session: one object that owns a connected machine and operates it.

It keeps what a real controller keeps for its operator: the machine's state, an explicit
state machine (:mod:`usbmotion.session.state`), the operator's requests in one queue the
machine takes at defined points (:mod:`usbmotion.session.requests`), one live model of the
machine every front reads (:mod:`usbmotion.session.live`), the position it believes in
(machine coordinates, and whether each axis is homed), and the program being run.
``usbmotion run``, the console, the grbl front and the dashboard drive the machine through
it.

- **Taking over** (:meth:`MachineSession.connect`): each link is resynchronised, motion an
  earlier host left running is brought to rest along its deceleration, a fault it left is
  reported and cleared, and the machine file is sent. The devices keep the machine
  coordinates homing gave their counters for as long as they are powered: an axis counts as
  homed when its device carries the homed mark (a RAM flag, gone after a power cycle) and
  no fault disabled its servo since (its position may then be lost).
- **Homing** (:meth:`MachineSession.home`): grbl's cycle on every axis in the configured
  order, machine zero set once from the switch edge the device latched
  (:mod:`usbmotion.session.homing`); from Alarm it resets first, as grbl's ``$H`` does.
- **Running** (:meth:`MachineSession.prepare`, :meth:`MachineSession.run`): a program is
  interpreted and planned from where the machine stands (never from 0), checked against
  every axis's travel (soft limits) before anything moves (:mod:`usbmotion.session.planning`),
  then streamed with every axis started on the same device tick (:mod:`usbmotion.session.run`).
- **Requests** (:meth:`MachineSession.request_stop`, :meth:`request_hold`,
  :meth:`request_resume`, :meth:`request_jog_cancel`, :meth:`set_feed_override`,
  :meth:`set_rapid_override`; safe from another thread or a signal handler): a stop brings
  every axis to rest along the program's path (a second one at once); a hold decelerates
  the same way and keeps the program's place until a resume; an override plans the queued
  future again at the new speed.
- **Leaving** (:meth:`MachineSession.shutdown`): every axis at rest, servos disabled
  without latching a fault, the homed mark kept for the next host.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import replace
from pathlib import Path

from usbmotion.automation.device_io import MachineZero, wrap_int32
from usbmotion.errors import (
    ArgumentError,
    DeviceError,
    MachineStateError,
    SequenceFaultError,
    StopRequestedError,
    UsbMotionError,
)
from usbmotion.host.config import MachineConfig
from usbmotion.host.device import ControlMode
from usbmotion.host.machine import Machine
from usbmotion.motion.dialects import Dialect
from usbmotion.motion.gcode import GCodeProgram, OutputChange, Pause, Pauses, read_gcode_text
from usbmotion.motion.moves import AXIS_ORDER, Point
from usbmotion.motion.offsets import WorkOffsets, read_parameter_file, write_parameter_file
from usbmotion.motion.tools import NO_TOOLS, ToolTable, load_tool_table
from usbmotion.protocol import FaultCode, fault_words
from usbmotion.session.context import RunContext
from usbmotion.session.feed import WINDOW_MOVES, ProgramFeed
from usbmotion.session.feeding import READ_AHEAD_S
from usbmotion.session.homing import HomingCycle, home_position_mm, homed_mark
from usbmotion.session.jog import check_jog, jog_text
from usbmotion.session.live import AxisScale, LiveModel, LiveSnapshot
from usbmotion.session.planning import Prepared, plan_axes, prepare_program, program_axes
from usbmotion.session.probing import (
    ProbeFailedError,
    ProbeMode,
    ProbeResult,
    changed,
    contact_position,
    probe_states,
    probe_touching,
)
from usbmotion.session.report import RunReport, Trace
from usbmotion.session.requests import (
    Request,
    RequestKind,
    RequestQueue,
    check_feed_override,
    check_rapid_override,
)
from usbmotion.session.rest import STOP_LEAD_S, wait_for_rest
from usbmotion.session.run import Run
from usbmotion.session.state import Event, MachineState, StateMachine, StopReason
from usbmotion.session.tool_setter import (
    MeasureAtChange,
    ToolMeasurement,
    measure_tool,
    setter_of,
)

LIVE_IDLE_S = 0.1
"""How often the live model of an idle machine may be refreshed from the devices."""
_NO_PARAMETER_FILE = (0, 0, -1)
"""What :meth:`MachineSession.work_offsets` keys the offsets of a missing parameter file by."""


class MachineSession:
    """A connected machine, operated (see the module docstring).

    Build one with :meth:`connect`. A context manager: leaving it closes the links (call
    :meth:`shutdown` first for a clean exit).

    Parameters:
        machine: the connected machine.
    """

    def __init__(self, machine: Machine) -> None:
        self.machine = machine
        self.config = machine.config
        self.clock = machine.clock
        self.states = StateMachine()
        """The machine's state: changed only through :meth:`StateMachine.fire`."""
        self.requests = RequestQueue()
        """The operator's requests, taken at defined points."""
        self.live = LiveModel({name: AxisScale(axis.config.counts_per_mm)
                               for name, axis in machine.axes.items()},
                              tick_s=self.config.servo_period_s)
        """The live model of the machine every front reads."""
        self.homed: dict[str, bool] = dict.fromkeys(machine.axes, False)
        """Axis -> True when its device's counter holds machine coordinates."""
        self.live_control = False
        """True when something may ask for a hold, a resume or an override while a program
        runs (a console, a front): a run then looks at requests every 10 ms (a hold within
        20 ms) instead of every 50 ms, and feeds the live model 50 times a second or more.
        Requests work either way; only how soon differs."""
        self.notices: list[str] = []
        """What the session found and did that the operator should hear of (a fault an
        earlier host left, motion it stopped, ...), oldest first."""
        self.program: Prepared | None = None
        """The program last prepared (the active program)."""
        self.zeroes: dict[str, MachineZero] = {}
        """Axis -> how the last homing set its machine zero."""
        self.stop_latency_s = 0.0
        """From the last stop request to every axis at rest, seconds."""
        self.faults_found: dict[str, tuple[int, int]] = {}
        """Axis -> (fault code, device tick) of a fault an earlier host left, which the
        take-over cleared."""
        self.optional_stop = False
        """When on, M1 pauses a program as M0 does (the operator's optional stop)."""
        self.on_pause: Callable[[Pause], None] | None = None
        """Called (on the running thread) when a program comes to rest at a pause."""
        self.paused: Pause | None = None
        """The program pause the machine waits at (M0, M1, M6), None when it waits at none."""
        self.last_run: Run | None = None
        """The last run: its holds (:attr:`Run.holds`) and override seams (:attr:`Run.seams`)
        for the figures of a benchmark."""
        self.last_probe: ProbeResult | None = None
        """What the last probing move found (:meth:`probe`), None before any."""
        self._measure_asked: MeasureAtChange | None = None
        self._jogging = False
        self._hold_asked = False
        self._feed: ProgramFeed | None = None
        self._live_read_s = -math.inf
        self._offsets_read: tuple[tuple[int, int, int] | None, WorkOffsets] | None = None

    # --- connecting and taking over ---------------------------------------------------------

    @classmethod
    def connect(
        cls,
        config: MachineConfig,
        *,
        search_ports: bool = True,
        ports: tuple[str, ...] = (),
    ) -> MachineSession:
        """Connect to the machine's devices and take it over.

        Raises:
            DeviceNotFoundError, LinkLostError, DeviceTimeoutError: as
                :meth:`usbmotion.host.machine.Machine.connect`.
            DeviceError: a device refused its configuration.
        """
        return cls.take_over(Machine.connect(config, search_ports=search_ports, ports=ports))

    @classmethod
    def take_over(cls, machine: Machine) -> MachineSession:
        """A session on a connected machine, taken over (the module docstring says how);
        the machine is closed if that fails.

        Raises:
            DeviceError: a device refused its configuration.
        """
        session = cls(machine)
        try:
            session._take_over()
        except BaseException:
            machine.close()
            raise
        return session

    def _take_over(self) -> None:
        machine = self.machine
        statuses = machine.status()
        moving = [name for name, status in statuses.items()
                  if status.enabled and status.queued > 0]
        if moving:
            self._stop_orphan_motion(moving)
            self.notices.append(
                f"axes {', '.join(moving)} were still running what an earlier host queued:"
                " brought to rest along their deceleration")
        for name, axis in machine.axes.items():
            client = axis.client
            code, tick = client.fault()
            if code != FaultCode.NONE:
                self.faults_found[name] = (code, tick)
                self.notices.append(
                    f"axis {name}: fault {code} ({fault_words(code)}) latched at"
                    f" device tick {tick}, left by an earlier host; cleared. The fault"
                    " disabled the servo, so the position may be lost: homing is required")
                client.clear_fault()
                client.set_homed_marker(0)
        machine.configure()  # clears the mark of a device whose drive or stepper changes
        for name, axis in machine.axes.items():
            if name not in self.faults_found:
                self.homed[name] = (axis.client.homed_marker()
                                    == homed_mark(self.config, axis.config))

    def _stop_orphan_motion(self, names: list[str]) -> None:
        """Bring axes running a queue nobody here planned to rest together along their
        present direction, at each axis's acceleration (the slowest sets the time)."""
        machine = self.machine
        first = {name: machine.axis(name).client.status() for name in names}
        self.clock.sleep(0.02)
        second = {name: machine.axis(name).client.status() for name in names}
        tick_s = self.config.servo_period_s
        period = self.config.motion_period_s
        velocity: dict[str, float] = {}
        for name in names:
            ticks = max(1, second[name].clock - first[name].clock)
            velocity[name] = (second[name].desired_counts - first[name].desired_counts) / (
                ticks * tick_s)
        duration = max((abs(velocity[n]) / (machine.axis(n).config.max_accel_mm_s2
                                            * machine.axis(n).config.counts_per_mm)
                        for n in names), default=0.0)
        steps = max(1, math.ceil(duration / period))
        for name in names:
            status = second[name]
            lead = math.ceil(STOP_LEAD_S / tick_s)
            start = status.desired_counts + velocity[name] * lead * tick_s
            values = [round(start + velocity[name] * period * (k - k * k / (2 * steps)))
                      for k in range(1, steps + 1)]
            machine.axis(name).client.stop_from(status.clock + lead, values)
        wait_for_rest(self.machine, names, stop_now=self._stop_now)

    # --- what the machine is and where --------------------------------------------------------

    @property
    def state(self) -> MachineState:
        """What the machine is doing."""
        return self.states.state

    @property
    def is_homed(self) -> bool:
        """True when every axis is homed."""
        return all(self.homed.values())

    @property
    def jogging(self) -> bool:
        """True while a jog runs (or comes to rest after its cancel)."""
        return self._jogging

    @property
    def held(self) -> bool:
        """True while a held (or paused) program waits at rest for a resume."""
        state = self.state
        return state is MachineState.PAUSED or (state is MachineState.HOLD
                                                and self.live.read().at_rest)

    @property
    def hold_requested(self) -> bool:
        """True from a hold request until the resume (or stop) that releases it: a hold
        asked while nothing runs holds the next motion, as grbl latches it."""
        return self._hold_asked or self.requests.taken.hold

    @property
    def stop_requested(self) -> str:
        """Why a stop was asked ("" when none was)."""
        self.requests.take()
        return self.requests.taken.stop_reason

    @property
    def feed_override_percent(self) -> int:
        """Feed moves run at this percentage of their feed (:meth:`set_feed_override`)."""
        return self.requests.taken.feed_override

    @property
    def rapid_override_percent(self) -> int:
        """Rapids run at this percentage of the axes' speed (:meth:`set_rapid_override`)."""
        return self.requests.taken.rapid_override

    def positions_mm(self) -> dict[str, float]:
        """Each axis's commanded position, mm (machine coordinates once homed)."""
        return {name: axis.scale.to_mm(status.desired_counts)
                for (name, axis), status in zip(self.machine.axes.items(),
                                                self.machine.status().values(), strict=True)}

    def start_position_mm(self, *, unhomed: bool = False) -> tuple[Point, bool]:
        """Where the next program starts (a coordinate per program axis), and whether that
        is a homed position: where the machine stands when it is homed (or, with
        ``unhomed``, in the devices' own counts); otherwise where homing will leave it."""
        axes = plan_axes(self.config)
        if self.is_homed or unhomed:
            where = self.positions_mm()
            return tuple(where[axis.name] for axis in axes), self.is_homed
        return tuple(home_position_mm(axis) for axis in axes), True

    def read_live(self, *, moving: bool = False) -> LiveSnapshot:
        """Refresh the live model from every device's status (at rest, or between the
        polls of what moves), the probe input and the spindle, and publish it; the
        snapshot."""
        live = self.live
        for name, status in self.machine.status().items():
            live.take_status(name, clock=status.clock, desired=status.desired_counts,
                             actual=status.actual_counts,
                             limit=bool(status.lower_limit or status.upper_limit),
                             fault=int(status.fault), moving=moving)
        spindle = self.machine.spindle
        if spindle is not None:
            spindle.service()
            spindle.read()
        probe = any(axis.client.probe().closed for axis in self.machine.axes.values())
        self._live_read_s = self.clock.now()
        return self.publish_live(probe=probe, outputs=self.outputs_now())

    def publish_live(self, **fields: object) -> LiveSnapshot:
        """Publish the live model with what the session knows (state, homed, overrides,
        offsets, tool) and ``fields``."""
        taken = self.requests.taken
        state = self.state
        known: dict[str, object] = {
            "state": state, "homed": self.is_homed,
            "at_rest": not self.states.moving or (state is MachineState.HOLD and self.held),
            "feed_override": taken.feed_override, "rapid_override": taken.rapid_override,
            "hold_pending": self.hold_requested, **self.live_fields()}
        return self.live.publish(**{**known, **fields})

    @contextmanager
    def _watching(self, on_progress: Callable[[LiveSnapshot], None] | None) -> Iterator[None]:
        """``on_progress`` called with every snapshot of the live model while inside."""
        if on_progress is None:
            yield
            return
        self.live.on_publish.append(on_progress)
        try:
            yield
        finally:
            self.live.on_publish.remove(on_progress)

    def live_fields(self) -> dict[str, object]:
        """What the live model shows of the session: the work offset in effect, the
        coordinate system and the tool (a fed program's modal state, else the parameter
        file's)."""
        axes = program_axes(self.config)
        spindle = self.machine.spindle
        shown: dict[str, object] = {} if spindle is None else {"spindle": spindle.now}
        run = self.last_run
        if run is not None and run.outputs is not None and self.states.moving:
            ticks = [axis.tick for axis in self.live.read().axes.values()]
            shown["outputs"] = run.outputs.values_at(min(ticks, default=0))
        feed = self._feed
        if feed is not None:
            modes = feed.modes()
            return {"work_offset_mm": dict(zip(axes, modes.offset_mm, strict=True)),
                    "coordinate_system": modes.coordinate_system, "tool": modes.tool, **shown}
        try:
            offsets = self.work_offsets()
        except (UsbMotionError, OSError):
            return shown
        base = offsets.g5x[offsets.coordinate_system - 1]
        g92 = offsets.g92 if offsets.g92_enabled else (0.0,) * len(AXIS_ORDER)
        return {"work_offset_mm": {a: base[AXIS_ORDER.index(a)] + g92[AXIS_ORDER.index(a)]
                                   for a in axes},
                "coordinate_system": offsets.coordinate_system, **shown}

    # --- programs -----------------------------------------------------------------------------

    def pause_rule(self) -> Pauses:
        """Which program pauses stop a program the session runs: M0 and manual tool
        changes, and M1 when :attr:`optional_stop` is on."""
        return Pauses.OPTIONAL if self.optional_stop else Pauses.PROGRAM

    def prepare(self, source: str | Path, *, text: str | None = None,
                unhomed: bool = False, dialect: Dialect | None = None,
                pauses: Pauses = Pauses.NONE, from_line: int | None = None) -> Prepared:
        """Interpret and plan a program from where the machine will start it, and check it
        against every axis's travel; nothing moves.

        The start is where the machine stands when it is homed; where homing will leave it
        when it is not (home, then run it); or, with ``unhomed``, where an unhomed machine
        stands, in the devices' own counts (soft limits cannot be checked then).

        Parameters:
            source: the file (its text is read) or, with ``text``, the name to report.
            text: the program's text, when it is not read from ``source``.
            unhomed: plan an unhomed machine from where it stands.
            dialect: read the program in this dialect instead of the machine file's.
            pauses: which of M0, M1, M6 pause it (:meth:`pause_rule` gives the session's;
                by default none: a run nobody can resume).
            from_line: run it from this line: the lines before it are interpreted without
                moving (modal state, units, offsets, tool), then a safe re-entry joins the
                program there (:func:`usbmotion.session.planning.plan_gcode`); needs a
                homed machine, or one homing will leave homed.

        The program runs with the machine's tool table and the work offsets of its
        parameter file (:attr:`MachineConfig.parameter_path`).

        Raises:
            GCodeError: the program does not parse (names the line).
            SoftLimitError: a move leaves an axis's travel (names the line, the axis, the
                coordinate and the limit).
            PlanningError: a move the machine cannot make.
            ArgumentError: ``from_line`` is not a line of the program, no move follows it,
                or the machine is planned unhomed (the safe height is a machine position).
            ConfigError: the tool table or the parameter file is malformed.
            OSError: the file cannot be read.
        """
        start_mm, homed = self.start_position_mm(unhomed=unhomed)
        if from_line is not None and not homed and unhomed:
            raise ArgumentError(f"from line {from_line}: running from a line needs a homed"
                                " machine (its safe height is a machine position): home it",
                                reason="from_line")
        body = read_gcode_text(source) if text is None else text
        self.program = prepare_program(self.config, body, file=str(source), start_mm=start_mm,
                                       homed=homed, dialect=dialect,
                                       tools=self.tool_table(), offsets=self.work_offsets(),
                                       pauses=pauses, from_line=from_line)
        return self.program

    def open_feed(self, *, file: str = "<stream>", source: Iterator[str] | None = None,
                  dialect: Dialect | None = None, unhomed: bool = False,
                  window: int = WINDOW_MOVES, horizon_s: float | None = None,
                  start_mm: Point | None = None) -> ProgramFeed:
        """A program to be written line by line (:class:`ProgramFeed`) from where the
        machine stands (read from the devices, or ``start_mm``: the caller knows it), with
        the machine's tool table, work offsets and pause rule; run it with
        :meth:`run_feed` while lines are added (or read from ``source``).

        Raises:
            MachineStateError: the machine is not homed (and ``unhomed`` is not given).
            ConfigError: the tool table or the parameter file is malformed.
        """
        if not self.is_homed and not unhomed:
            raise MachineStateError("the machine is not homed: home it first",
                                    state=self.state.value)
        if start_mm is None:
            start_mm, homed = self.start_position_mm(unhomed=unhomed)
        else:
            homed = self.is_homed
        return ProgramFeed(self.config, start_mm=start_mm, homed=homed, file=file,
                           source=source, dialect=dialect, tools=self.tool_table(),
                           offsets=self.work_offsets(), pauses=self.pause_rule(),
                           window=window, horizon_s=horizon_s)

    def run_feed(self, feed: ProgramFeed, *,
                 on_progress: Callable[[LiveSnapshot], None] | None = None,
                 ) -> tuple[RunReport, Trace]:
        """Run a program while it is being written: its moves are planned with look-ahead
        as they come and streamed; the run ends once the feed is complete (closed, its
        source ended, or a line ended the program) and played out, or, for a feed written
        by a front, once the machine has played out all it was given and no line came
        meanwhile (the feed is then closed: a later line needs a new feed). Holds,
        resumes, overrides, stops and faults work as in :meth:`run`.

        Raises:
            MachineStateError: not Idle, or the machine moved since the feed was opened.
        """
        feed.pull()
        snapshot = feed.snapshot()
        plan = feed.plan(snapshot)
        while feed.has_source and not snapshot.complete and plan.duration_s < READ_AHEAD_S:
            if not feed.pull():
                break
            snapshot = feed.snapshot()
            plan = feed.plan(snapshot)
        prepared = Prepared(feed.program(), plan, feed.start_mm, feed.homed, feed.offsets)
        return self.run(prepared, feed=feed, on_progress=on_progress)

    # --- jogging ------------------------------------------------------------------------------

    def jog(self, moves: Mapping[str, float], *, feed_mm_min: float, work: bool = False,
            absolute: bool = False, continuous: bool = False,
            on_progress: Callable[[LiveSnapshot], None] | None = None) -> RunReport:
        """Jog: move axes at a feed, planned with each axis's acceleration, within the soft
        limits, at 100 % whatever the feed override (as grbl jogs); returns the report.
        :meth:`request_jog_cancel` (a hold, or any stop request) brings every axis to rest
        along its deceleration and drops the rest (Idle, homed).

        Parameters:
            moves: axis -> distance, mm (incremental, the default); target (``absolute``);
                or direction (``continuous``: the sign of each value, its size weighting
                the axes, the jog running until it is cancelled or reaches the first soft
                limit on the way).
            feed_mm_min: the path's feed, mm/min (each axis keeps to its own limits).
            work: targets in work coordinates (the parameter file's offsets) instead of
                machine coordinates (G53).

        Raises:
            ArgumentError: an axis the machine does not have, a value or feed that is not
                finite (the feed positive), a continuous jog with no direction.
            MachineStateError: not Idle, or not homed (a jog needs soft limits).
            SoftLimitError: the jog leaves an axis's travel (nothing moves).
        """
        check_jog(moves, feed_mm_min, program_axes(self.config))
        if not self.is_homed:
            raise MachineStateError("a jog needs a homed machine (its soft limits): home it"
                                    " first", state=self.state.value)
        text = jog_text(self.config, self.positions_mm(), moves, feed_mm_min=feed_mm_min,
                        work=work, absolute=absolute, continuous=continuous)
        prepared = self.prepare("<jog>", text=text)
        self._jogging = True
        try:
            report, _ = self.run(prepared, jog=True, on_progress=on_progress)
        finally:
            self._jogging = False
            if self.requests.taken.stop_reason == StopReason.JOG_CANCELLED.value:
                self.clear_stop_request()
        return report

    def probe(self, target_mm: Mapping[str, float], *, feed_mm_min: float,
              mode: ProbeMode) -> ProbeResult:
        """A probing move (G38.2 to G38.5, :mod:`usbmotion.session.probing`): straight toward
        ``target_mm`` (machine mm, the axes it names) at ``feed_mm_min``, within the soft
        limits, stopped along its deceleration once the probe changes as ``mode`` says; the
        position of the change (the devices' latches), kept as :attr:`last_probe`. A probe
        toward contact (G38.2, G38.3) then moves back onto the contact position at the same
        feed, so the machine stands where the probe touched (a sender's ``G10 L20`` after it
        sets the origin there, as cncjs's probe widget does).

        Raises:
            ProbeFailedError: the probe already was as the move was to make it, or a G38.2
                or G38.4 ended without the change (the machine is left Idle where it
                stopped; grbl then alarms).
            as :meth:`jog`: not homed or not idle, a target beyond the travel.
        """
        machine = self.machine
        before = probe_states(machine)
        if probe_touching(before) == mode.toward:
            raise ProbeFailedError(
                f"{mode.code}: the probe already {'touches' if mode.toward else 'is clear'}"
                " before the move: nothing moved", at_start=True)
        start = self.live.read().machine_mm(measured=False)
        seen: list[bool] = []

        def watch(_: LiveSnapshot) -> None:
            if not seen and changed(before, probe_states(machine), mode):
                seen.append(True)
                self.request_jog_cancel()

        self.jog(target_mm, feed_mm_min=feed_mm_min, absolute=True, on_progress=watch)
        after = probe_states(machine)
        latched = changed(before, after, mode)
        if latched:
            where = contact_position(machine, latched, after, start, target_mm)
            if mode.toward:  # back onto the contact: the position now is the contact's
                self.jog({name: where[name] for name in target_mm}, feed_mm_min=feed_mm_min,
                         absolute=True)
        else:
            where = dict(self.live.read().machine_mm(measured=False))
        result = ProbeResult(mode.code, bool(latched), where, latched)
        self.last_probe = result
        if not latched and mode.required:
            raise ProbeFailedError(
                f"{mode.code}: the move ended without the probe"
                f" {'touching' if mode.toward else 'clearing'}", at_start=False)
        return result

    def measure_tool(self, tool: int | None = None, *, write: bool = True) -> ToolMeasurement:
        """Measure tool ``tool`` (default: the one in the spindle) on the machine's tool
        setter and write its length into the tool table (not with ``write`` false)
        (:func:`usbmotion.session.tool_setter.measure_tool`, whose errors it raises)."""
        number = self.live.read().tool if tool is None else tool
        measured = measure_tool(self, number, write=write)
        self.publish_live()
        return measured

    def request_tool_measure(self) -> MeasureAtChange:
        """At a program's ``M6`` pause, measure the new tool (grblHAL's semi-automatic tool
        change): the run ends where it waits (the axes are at rest: nothing moves), and the
        thread that ran it measures the tool and runs the program on from the line after
        the ``M6`` (:meth:`measure_asked`). Safe from another thread (it only queues a
        stop request).

        Raises:
            MachineStateError: no program waits at an ``M6`` pause (a program streamed line
                by line cannot be taken up again: measure once it has ended).
            ConfigError: no ``[tool_setter]``.
        """
        pause, run = self.paused, self.last_run
        state = self.state
        if (pause is None or pause.code != "M6" or state is not MachineState.PAUSED
                or run is None or self._feed is not None):
            raise MachineStateError(
                "a tool is measured at a program's M6 pause, or while the machine is idle;"
                f" the machine is in {state.value}"
                + (f" at an {pause.code} pause" if pause is not None else ""),
                state=state.value)
        setter_of(self.config)
        tool = next((change.tool for change in run.prepared.program.tool_changes
                     if change.line == pause.line), self.live.read().tool)
        asked = self._measure_asked = MeasureAtChange(tool, pause.line)
        self.request_stop(StopReason.TOOL_MEASURE.value)
        return asked

    def measure_asked(self, report: RunReport) -> MeasureAtChange | None:
        """After :meth:`run`: the measurement :meth:`request_tool_measure` asked, when the
        run ended for it at an ``M6`` pause (None after any other ending). The caller then
        measures the tool (:meth:`measure_tool`) and runs the program on from
        :attr:`MeasureAtChange.from_line`, prepared again so its ``G43`` reads the length."""
        asked, self._measure_asked = self._measure_asked, None
        if asked is None or report.stop_reason != StopReason.TOOL_MEASURE.value:
            return None
        self.clear_stop_request()
        return asked

    def request_jog_cancel(self) -> None:
        """Cancel a jog (grbl's 0x85): every axis to rest along its deceleration, the rest
        of the jog dropped, the machine Idle; nothing when no jog runs. Safe from a signal
        handler or another thread."""
        if self._jogging:
            self.requests.put(Request(RequestKind.JOG_CANCEL, self.clock.now(),
                                      reason=StopReason.JOG_CANCELLED.value))

    def _pause_at(self, pause: Pause | None) -> None:
        """The run came to rest at a program pause (or left it)."""
        self.paused = pause
        if pause is not None and self.on_pause is not None:
            self.on_pause(pause)

    def tool_table(self) -> ToolTable:
        """The machine's tool table (none: every tool of zero length).

        Raises:
            ConfigError: the table is malformed (names the file and the line).
        """
        table = self.config.tool_table
        return load_tool_table(table) if table is not None else NO_TOOLS

    def work_offsets(self) -> WorkOffsets:
        """The work offsets and stored positions of the machine's parameter file.

        Raises:
            ConfigError: the file is malformed (names the file and the line).
        """
        path = self.config.parameter_path
        try:
            stat = path.stat()
            key: tuple[int, int, int] | None = (stat.st_ino, stat.st_mtime_ns, stat.st_size)
        except FileNotFoundError:
            key = _NO_PARAMETER_FILE  # every parameter at 0, until a file appears
        except OSError:
            key = None
        if self._offsets_read is None or key is None or self._offsets_read[0] != key:
            # read again only when the file changed (the live model asks 100 times a second)
            self._offsets_read = (key, read_parameter_file(path))
        return self._offsets_read[1]

    def save_work_offsets(self, offsets: WorkOffsets) -> None:
        """Write the parameter file (atomically).

        Raises:
            OSError: it cannot be written.
        """
        write_parameter_file(self.config.parameter_path, offsets)

    def set_work_origin(self, origin_mm: dict[str, float], *, system: int = 1) -> WorkOffsets:
        """Set coordinate system ``system`` (1 = G54) so that its zero is at ``origin_mm``
        (machine coordinates, mm, for the named axes; the others keep their offsets), and
        save it in the parameter file.

        Raises:
            ArgumentError: an axis that is not one of the machine's program axes, or a value
                that is not finite.
            ConfigError: the parameter file is malformed, or the machine has no linear axis.
            OSError: it cannot be written.
        """
        axes = program_axes(self.config)
        offsets = self.work_offsets()
        offset = list(offsets.g5x[system - 1])
        for name, value in origin_mm.items():
            if name not in axes:
                raise ArgumentError(f"origin axis {name!r}: allowed {', '.join(axes)} (the"
                                    " machine's axes)", reason="origin")
            if not math.isfinite(value):
                raise ArgumentError(f"origin {name}{value!r}: not a finite number",
                                    reason="origin")
            offset[AXIS_ORDER.index(name)] = value
        offsets = offsets.with_g5x(system, tuple(offset))
        self.save_work_offsets(offsets)
        return offsets

    # --- a changed machine file ---------------------------------------------------------------

    def reconfigure(self, config: MachineConfig) -> tuple[str, ...]:
        """Take a changed configuration of this machine while it is idle
        (:meth:`Machine.reconfigure`: velocities, accelerations, travel, homing, scale and
        planning take effect for the next motion). An axis whose homed position the change
        moves (its scale, its switch's position) is no longer homed: the axes that need
        homing again, in order.

        Raises:
            MachineStateError: the machine is not idle.
            ConfigError: the change needs a restart (see :meth:`Machine.reconfigure`).
        """
        if self.state is not MachineState.IDLE:
            raise MachineStateError("the machine file can change only while the machine is"
                                    " idle", state=self.state.value)
        old = self.config
        self.machine.reconfigure(config)
        config = self.config = self.machine.config
        unhomed = []
        for name, axis in self.machine.axes.items():
            if self.homed[name] and homed_mark(old, old.axis(name)) != homed_mark(
                    config, axis.config):
                self.homed[name] = False
                axis.client.set_homed_marker(0)
                unhomed.append(name)
        return tuple(unhomed)

    # --- the operator's requests ---------------------------------------------------------------

    def request_stop(self, reason: str = StopReason.USER.value) -> None:
        """Ask whatever runs to stop: the first request stops along the deceleration, a
        second one at once. Safe from a signal handler (it only queues the request)."""
        self._hold_asked = False
        self.requests.put(Request(RequestKind.STOP, self.clock.now(), reason=reason))

    def _stop_now(self) -> bool:
        self.requests.take()
        return self.requests.taken.stop_now

    def clear_stop_request(self) -> None:
        """Forget a stop request (once the stop is done)."""
        self.requests.clear_stop()

    def request_hold(self) -> None:
        """Feed hold (grbl's ``!``): a running program decelerates along the path to rest
        and stays there, enabled (state Hold), until :meth:`request_resume` continues the
        path from there or :meth:`request_stop` abandons the program. Asked while idle, the
        next motion starts held (grbl latches a hold); during a jog it cancels the jog;
        ignored while homing or in Alarm. Safe from a signal handler or another thread."""
        state = self.state
        if state in (MachineState.HOMING, MachineState.ALARM):
            return
        if self._jogging or state is MachineState.JOG:
            self.request_jog_cancel()
            return
        self._hold_asked = True
        self.requests.put(Request(RequestKind.HOLD, self.clock.now()))

    def request_resume(self) -> None:
        """Cycle start (grbl's ``~``): a held or paused program continues (the rest of the
        path planned from rest where the axes stand, streamed from a common device tick),
        and a hold latched while idle is released. Ignored when nothing holds. Safe from a
        signal handler."""
        if not (self.hold_requested or self.state in (MachineState.HOLD, MachineState.PAUSED)):
            return
        self._hold_asked = False
        self.requests.put(Request(RequestKind.RESUME, self.clock.now()))

    def drop_hold(self) -> None:
        """Forget a hold latched while idle (a reset while idle)."""
        self._hold_asked = False
        self.requests.take()
        self.requests.clear_hold()

    def set_feed_override(self, percent: int) -> None:
        """Run feed moves at ``percent`` of their programmed feed (grbl's feed override).

        A running program's queued future is planned again at the new speed from a device
        tick just ahead and replaced there (call 38), the speed changing within the axes'
        acceleration limits; the axes' own velocity limits still apply. Held or idle, the
        next motion uses it; jogs run at 100 % (as grbl's). Safe from another thread.

        Raises:
            ArgumentError: ``percent`` is not a whole number within 10 .. 200.
        """
        self.requests.put(Request(RequestKind.FEED_OVERRIDE, self.clock.now(),
                                  value=check_feed_override(percent)))
        self._take_when_idle()

    def set_spindle_override(self, percent: int) -> None:
        """The spindle speed override, 10..200 % (grbl's 0x99-0x9D), from any thread: the
        spindle follows along its ramp at the next look of whoever drives the machine (a
        machine without a spindle ignores it)."""
        spindle = self.machine.spindle
        if spindle is not None:
            spindle.ask_override(percent)

    def set_rapid_override(self, percent: int) -> None:
        """Run rapids at ``percent`` of the fastest the axes allow (grbl's rapid override:
        100, 50 or 25), taking effect as :meth:`set_feed_override` does.

        Raises:
            ArgumentError: ``percent`` is not one of 25, 50, 100.
        """
        self.requests.put(Request(RequestKind.RAPID_OVERRIDE, self.clock.now(),
                                  value=check_rapid_override(percent)))
        self._take_when_idle()

    def _take_when_idle(self) -> None:
        if self.state is MachineState.IDLE and self.last_run_done():
            self.requests.take()

    def last_run_done(self) -> bool:
        """Whether no run is under way."""
        return not self.states.moving and self.state is not MachineState.PAUSED

    @property
    def override_at_s(self) -> float:
        """When an override last changed (the session's clock)."""
        return self.requests.taken.override_at_s

    # --- homing -------------------------------------------------------------------------------

    def home(self, *, axes: Sequence[str] | None = None,
             on_progress: Callable[[LiveSnapshot], None] | None = None) -> float:
        """Home every axis, or only ``axes`` (grbl's cycle, in the configured order);
        returns the seconds. From Alarm the devices' faults are cleared first (grbl's
        ``$H`` clears an alarm). The live model shows each axis as homing reads it.

        Afterwards every homed axis is in position mode, enabled, at its home position (the
        switch's machine position pulled off), and marked homed on its device.
        ``on_progress`` is called with every snapshot of the live model meanwhile.

        Raises:
            KeyError: an axis the machine does not have (the message lists those it has).
            MachineStateError: the machine is not Idle or in Alarm.
            SequenceFaultError: a switch was not found, did not open, or closed the wrong
                way round (names the axis); every axis was brought to rest; Alarm.
            StopRequestedError: a stop was asked; every axis was brought to rest; Idle, not
                homed.
            DeviceError: a device faulted or refused (Alarm).
        """
        names = list(self.machine.axes) if axes is None else [
            self.machine.axis(name).name for name in axes]
        self.requests.take()
        if self.state is MachineState.ALARM:
            self._clear_faults()
        self.states.fire(Event.HOME)
        self.publish_live()
        started = self.clock.now()
        for name in names:
            self.homed[name] = False
            self.machine.axis(name).client.set_homed_marker(0)
        declared = [name for name in names if self.machine.axis(name).config.homing.declare]
        self._declare_home(declared)
        switched = [name for name in names if name not in declared]
        if not switched:
            return self._homed(names, started)
        cycle = HomingCycle(self.machine, keep_alive_period_s=self.keep_alive_period_s(),
                            stop_now=self._stop_now, axes=switched)
        cycle.enter_velocity_mode()

        def progress(where: dict[str, float]) -> None:
            live = self.live
            for name, mm in where.items():
                counts = round(mm * self.config.axis(name).counts_per_mm)
                live.take_status(name, clock=0, desired=counts, actual=counts)
            if live.due():
                self.publish_live(at_rest=False)

        def should_stop() -> str:
            self.requests.take()
            return self.requests.taken.stop_reason

        try:
            with self._watching(on_progress):
                zeroes = cycle.run(should_stop=should_stop, on_positions=progress)
        except StopRequestedError:
            self.stop_latency_s = self.clock.now() - self.requests.taken.stop_at_s
            self.states.fire(Event.AT_REST)
            self.read_live()
            raise
        except (SequenceFaultError, UsbMotionError) as error:
            self.states.fire(Event.FAULT)
            self.publish_live(alarm=f"homing failed: {error}")
            raise
        self.zeroes.update(zeroes)
        return self._homed(names, started)

    def _declare_home(self, names: list[str]) -> None:
        """Home axes with no switch (``homing.declare``, a wrapped rotary axis): each is
        declared to stand at its ``homing.position_mm`` (one shift of its counter, call 37),
        in position mode and enabled, holding where it stands."""
        for name in names:
            axis = self.machine.axis(name)
            client = axis.client
            self.machine.set_mode(ControlMode.POSITION, axes=[name])
            client.clear_queue()
            here = client.status().actual_counts
            client.shift_position(wrap_int32(
                axis.scale.to_counts(axis.config.homing.position_mm) - here))
            client.set_servo_enable(True)

    def _homed(self, names: list[str], started: float) -> float:
        for name in names:
            axis = self.machine.axis(name)
            axis.client.set_homed_marker(homed_mark(self.config, axis.config))
            self.homed[name] = True
        self.states.fire(Event.HOMED)
        self.read_live()
        return self.clock.now() - started

    # --- running ------------------------------------------------------------------------------

    def run(self, prepared: Prepared, *, homing_s: float = 0.0,
            feed: ProgramFeed | None = None, jog: bool = False,
            on_progress: Callable[[LiveSnapshot], None] | None = None,
            ) -> tuple[RunReport, Trace]:
        """Run a prepared program; returns the report and the trace. The live model follows
        it (its state, the line the devices execute, progress, where each axis is);
        ``on_progress`` is called with every snapshot of it meanwhile.

        The machine must be where the program was prepared from (prepare it again after
        anything moved). A device fault stops every other axis along its deceleration; a
        stop request does so for every axis; the report says why the run ended. A program
        that ran to its end and changed the work offsets or the stored positions (G10, G92,
        G28.1, G30.1) leaves them in the parameter file for the next run. The report's
        notes begin with the program's warnings (``prepared.warnings``: rapids into the
        stock).

        Raises:
            MachineStateError: not Idle, or the machine moved since the program was prepared.
        """
        self.requests.take()
        self._measure_asked = None
        state = self.state.value
        if self.state is not MachineState.IDLE:
            raise MachineStateError(f"the machine is in {state}; a program runs from Idle",
                                    state=state)
        if prepared.homed and not self.is_homed:
            raise MachineStateError("the program was prepared for a homed machine: home it"
                                    " first", state=state)
        where = self.positions_mm()
        here = tuple(where[name] for name in prepared.axes)
        counts = [self.config.axis(name).counts_per_mm for name in prepared.axes]
        if any(abs(a - b) * scale > 1.0 for a, b, scale in zip(here, prepared.start_mm, counts,
                                                               strict=True)):
            raise MachineStateError(
                f"the program was prepared from {prepared.start_mm} but the machine stands"
                f" at {here}: prepare it again", state=state)
        taken = self.requests.taken
        if taken.resume:  # a hold latched while idle, released before the run began
            self.requests.clear_hold()
        if jog:
            taken.jog_cancel = False
        self.states.fire(Event.JOG if jog else Event.START)
        self._feed = feed
        context = RunContext(
            self.machine, self.config, self.states, self.requests, self.live,
            live_control=self.live_control, keep_alive_s=self.keep_alive_period_s(),
            keep_alive=self.keep_alive, on_pause=self._pause_at, live_fields=self.live_fields)
        try:
            run = self.last_run = Run(context, prepared, homing_s=homing_s, feed=feed,
                                      overrides=not jog)
            with self._watching(on_progress):
                report, trace = run.go()
        except BaseException:
            # what the run could not end itself: never left running, the machine in Alarm
            if self.states.state is not MachineState.ALARM:
                self.states.fire(Event.FAULT)
            raise
        finally:
            self._feed = None
            if taken.stop_reason:
                self.requests.clear_hold()
                self._hold_asked = False
        if prepared.warnings:  # what prepare_program found risky (motion.plunges)
            report = replace(report, notes=(*prepared.warnings, *report.notes))
        for name in run.faulted_axes:
            self.homed[name] = False
        if run.faulted and self.states.state is not MachineState.ALARM:
            self.states.fire(Event.FAULT)
        program = run.prepared.program
        if report.completed and program.offsets != prepared.offsets:
            self.save_work_offsets(program.offsets)
        self.publish_live(alarm=_alarm_words(report) if run.faulted else "",
                          tool_changes=tuple(_tool_change_words(program)))
        return report, trace

    # --- after a fault ------------------------------------------------------------------------

    def reset(self) -> None:
        """Alarm -> Idle: every queue cleared, every servo disabled, every fault cleared; an
        axis whose servo a fault disabled needs homing again."""
        self._clear_faults()
        if self.state is MachineState.ALARM:
            self.states.fire(Event.RESET)
        self.read_live()

    def _clear_faults(self) -> None:
        machine = self.machine
        for name, status in machine.status().items():
            if status.fault != FaultCode.NONE:
                self.homed[name] = False
                machine.axis(name).client.set_homed_marker(0)
        machine.stop()
        machine.clear_faults()

    # --- waiting ------------------------------------------------------------------------------

    def outputs_now(self) -> dict[str, int]:
        """Each coolant and laser output's value as its device says (call 43)."""
        outputs = self.config.outputs
        if outputs is None:
            return {}
        read: dict[str, tuple[int, ...]] = {}
        shown = {}
        for name, pin in outputs.pins.items():
            if pin.axis not in read:
                read[pin.axis] = self.machine.axis(pin.axis).client.outputs().values
            shown[name] = read[pin.axis][pin.output]
        return shown

    def coolant_now(self, changes: Sequence[OutputChange]) -> None:
        """The coolant outputs as ``changes`` leave them, at once (an ``M8`` or ``M9`` of a
        line without motion while the machine stands; a laser fires only while it cuts)."""
        outputs = self.config.outputs
        if outputs is None:
            return
        for name, pin in outputs.pins.items():
            if name == "laser":
                continue
            told = [change.value for change in changes if change.output == name]
            if not told:
                continue
            client = self.machine.axis(pin.axis).client
            value = 1000 if told[-1] else 0
            if client.outputs().values[pin.output] != value:
                client.set_output_at(pin.output, value, 0)

    def keep_alive_period_s(self) -> float:
        """How often a front waiting for its operator must call :meth:`keep_alive` so that
        no watchdog trips on an enabled axis (0: the machine has no watchdog)."""
        watchdog_ms = self.config.watchdog_ms
        return watchdog_ms / 1000.0 / 4 if watchdog_ms > 0 else 0.0

    def keep_alive(self) -> None:
        """Feed every device's watchdog (a queue query each: any command does), and the
        spindle's queue."""
        self.machine.ping()
        spindle = self.machine.spindle
        if spindle is not None:
            spindle.service()

    # --- leaving ------------------------------------------------------------------------------

    def shutdown(self) -> None:
        """The clean exit: every queue empty, every servo disabled (the spindle's too: it
        coasts to rest; no fault latches: a disabled servo has no watchdog), diagnostics
        off; the homed mark stays on the devices for the next host.

        Raises:
            DeviceError: a device could not be reached (names it), after trying every axis.
        """
        failures: list[str] = []
        for name, axis in self.machine.axes.items():
            client = axis.client
            try:
                client.set_diagnostics_interval(0)
                client.clear_queue()
                client.set_servo_enable(False)
            except (UsbMotionError, OSError) as error:
                failures.append(f"{name}: {error}")
        spindle = self.machine.spindle
        if spindle is not None:
            try:
                spindle.halt()
            except (UsbMotionError, OSError) as error:
                failures.append(f"spindle: {error}")
        if failures:
            raise DeviceError("shutdown: " + "; ".join(failures))

    def close(self) -> None:
        """Close every link (safe twice)."""
        self.machine.close()

    def __enter__(self) -> MachineSession:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _alarm_words(report: RunReport) -> str:
    """A faulted run's alarm, in words: the axis, the fault, the line."""
    if report.faults:
        first = report.faults[0]
        return f"axis {first.axis}: {first.fault} at line {first.line}"
    return report.stop_reason


def _tool_change_words(program: GCodeProgram) -> Iterator[str]:
    """Each tool change of a program, in words."""
    for change in program.tool_changes:
        pocket = f" (pocket {change.pocket})" if change.pocket else ""
        yield f"line {change.line}: tool {change.tool}{pocket}"


__all__ = ["MachineSession"]
