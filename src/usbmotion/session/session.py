"""The machine session: one object that owns a connected machine and operates it.

It keeps what a real controller keeps for its operator: the machine's state (see
:mod:`usbmotion.session.state`), the position it believes in (machine coordinates, and
whether each axis is homed), and the program being run. ``usbmotion run``, the console and
every later front drive the machine through it.

- **Taking over** (:meth:`MachineSession.connect`): each link is resynchronised, motion an
  earlier host left running is brought to rest along its deceleration, a fault it left is
  reported and cleared, and the machine file is sent. The devices keep the machine
  coordinates homing gave their counters for as long as they are powered: an axis counts as
  homed when its device carries the homed mark (a RAM flag, gone after a power cycle) and
  no fault disabled its servo since (its position may then be lost).
- **Homing** (:meth:`MachineSession.home`): grbl's cycle on every axis in the configured
  order, machine zero set once from the switch edge the device latched
  (:mod:`usbmotion.session.homing`).
- **Running** (:meth:`MachineSession.prepare`, :meth:`MachineSession.run`): a program is
  interpreted and planned from where the machine stands (never from 0), checked against
  every axis's travel (soft limits) before anything moves (:mod:`usbmotion.session.planning`),
  then streamed with every axis started on the same device tick (:mod:`usbmotion.session.run`;
  the report's figures are :mod:`usbmotion.session.report`'s, its text
  :mod:`usbmotion.session.report_text`'s).
- **Stopping** (:meth:`MachineSession.request_stop`, safe from a signal handler): the
  first request brings every axis to rest along the program's path at its planned
  deceleration (call 38 replaces the queued future from a device tick just ahead, so there
  is no seam whatever the latency); a second one stops at once (servos off: the axes coast).
- **Feed hold, resume, overrides** (:meth:`MachineSession.request_hold`,
  :meth:`MachineSession.request_resume`, :meth:`MachineSession.set_feed_override`,
  :meth:`MachineSession.set_rapid_override`, safe from another thread or a signal
  handler): a hold decelerates along the path as a stop does and keeps the program's
  place; a resume plans the rest of the path from rest there and starts every axis on
  one device tick; an override plans the queued future again at the new speed and
  replaces it from a device tick just ahead (:mod:`usbmotion.motion.replanning`).
- **Leaving** (:meth:`MachineSession.shutdown`): every axis at rest, servos disabled
  without latching a fault, the homed mark kept for the next host.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

from usbmotion.automation.device_io import MachineZero
from usbmotion.errors import (
    ArgumentError,
    DeviceError,
    MachineStateError,
    SequenceFaultError,
    StopRequestedError,
    UsbMotionError,
)
from usbmotion.host.config import MachineConfig
from usbmotion.host.machine import Machine
from usbmotion.motion.dialects import Dialect
from usbmotion.motion.gcode import Pause, Pauses, read_gcode_text
from usbmotion.motion.moves import AXIS_ORDER, Point
from usbmotion.motion.offsets import WorkOffsets, read_parameter_file, write_parameter_file
from usbmotion.motion.tools import NO_TOOLS, ToolTable, load_tool_table
from usbmotion.protocol import FaultCode, fault_words
from usbmotion.session.feed import WINDOW_MOVES, ProgramFeed
from usbmotion.session.homing import HomingCycle, home_position_mm, homed_mark
from usbmotion.session.planning import Prepared, plan_axes, prepare_program, program_axes
from usbmotion.session.progress import Progress
from usbmotion.session.report import RunReport, Trace
from usbmotion.session.rest import STOP_LEAD_S, wait_for_rest
from usbmotion.session.run import READ_AHEAD_S, Run
from usbmotion.session.state import MachineState, StopReason, check_transition

FEED_OVERRIDE_RANGE = (10, 200)
"""The feed override's range, percent (grbl's)."""
RAPID_OVERRIDES = (25, 50, 100)
"""The rapid override's values, percent (grbl's)."""


@dataclass(slots=True)
class _Requests:
    """Stop, hold and resume requests, set from a signal handler: plain fields only."""

    reason: str = ""
    count: int = 0
    at_s: float = 0.0
    """When the first stop request came (the session's clock)."""
    hold: bool = False
    hold_at_s: float = 0.0
    resume: bool = False


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
        self._state = MachineState.IDLE
        self.homed: dict[str, bool] = dict.fromkeys(machine.axes, False)
        """Axis -> True when its device's counter holds machine coordinates."""
        self.live_control = False
        """True when something may ask for a hold, a resume or an override while a program
        runs (a console, a front): the run then looks at requests every
        :data:`~usbmotion.session.run.REQUEST_CHECK_S` (a hold within 20 ms) instead of
        every :data:`~usbmotion.session.run.FAULT_CHECK_S` (a batch run: fewer wake-ups,
        faster in virtual time). Requests work either way; only how soon differs."""
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
        self._requests = _Requests()
        self.feed_override_percent = 100
        """Feed moves run at this percentage of their feed (:meth:`set_feed_override`)."""
        self.rapid_override_percent = 100
        """Rapids run at this percentage of the axes' speed (:meth:`set_rapid_override`)."""
        self.override_at_s = 0.0
        """When an override last changed (the session's clock)."""
        self.held = False
        """True while a held (or paused) program waits at rest for a resume."""
        self.jogging = False
        """True while a jog runs (:meth:`jog`)."""
        self.optional_stop = False
        """When on, M1 pauses a program as M0 does (the operator's optional stop)."""
        self.on_pause: Callable[[Pause], None] | None = None
        """Called (on the running thread) when a program comes to rest at a pause."""
        self.paused: Pause | None = None
        """The program pause the machine waits at (M0, M1, M6), None when it waits at none."""
        self.last_run: Run | None = None
        """The last run: its holds (:attr:`Run.holds`) and override seams (:attr:`Run.seams`)
        for the figures of a benchmark."""

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
                continue
            self.homed[name] = client.homed_marker() == homed_mark(self.config, axis.config)
        machine.configure()

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
            machine.axis(name).client.replace_from(status.clock + lead, values)
        wait_for_rest(self.machine, names, stop_now=self._stop_now_requested)

    # --- what the machine is and where --------------------------------------------------------

    @property
    def state(self) -> MachineState:
        """What the machine is doing."""
        return self._state

    def _enter(self, state: MachineState) -> None:
        check_transition(self._state, state)
        self._state = state

    @property
    def is_homed(self) -> bool:
        """True when every axis is homed."""
        return all(self.homed.values())

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

    # --- programs -----------------------------------------------------------------------------

    def pause_rule(self) -> Pauses:
        """Which program pauses stop a program the session runs: M0 and manual tool
        changes, and M1 when :attr:`optional_stop` is on."""
        return Pauses.OPTIONAL if self.optional_stop else Pauses.PROGRAM

    def prepare(self, source: str | Path, *, text: str | None = None,
                unhomed: bool = False, dialect: Dialect | None = None,
                pauses: Pauses = Pauses.NONE) -> Prepared:
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

        The program runs with the machine's tool table and the work offsets of its
        parameter file (:attr:`MachineConfig.parameter_path`).

        Raises:
            GCodeError: the program does not parse (names the line).
            SoftLimitError: a move leaves an axis's travel (names the line, the axis, the
                coordinate and the limit).
            PlanningError: a move the machine cannot make.
            ConfigError: the tool table or the parameter file is malformed.
            OSError: the file cannot be read.
        """
        start_mm, homed = self.start_position_mm(unhomed=unhomed)
        body = read_gcode_text(source) if text is None else text
        self.program = prepare_program(self.config, body, file=str(source), start_mm=start_mm,
                                       homed=homed, dialect=dialect,
                                       tools=self.tool_table(), offsets=self.work_offsets(),
                                       pauses=pauses)
        return self.program

    def open_feed(self, *, file: str = "<stream>", source: Iterator[str] | None = None,
                  dialect: Dialect | None = None, unhomed: bool = False,
                  window: int = WINDOW_MOVES) -> ProgramFeed:
        """A program to be written line by line (:class:`ProgramFeed`) from where the
        machine stands, with the machine's tool table, work offsets and pause rule; run it
        with :meth:`run_feed` while lines are added (or read from ``source``).

        Raises:
            MachineStateError: the machine is not homed (and ``unhomed`` is not given).
            ConfigError: the tool table or the parameter file is malformed.
        """
        if not self.is_homed and not unhomed:
            raise MachineStateError("the machine is not homed: home it first",
                                    state=self._state.value)
        start_mm, homed = self.start_position_mm(unhomed=unhomed)
        return ProgramFeed(self.config, start_mm=start_mm, homed=homed, file=file,
                           source=source, dialect=dialect, tools=self.tool_table(),
                           offsets=self.work_offsets(), pauses=self.pause_rule(),
                           window=window)

    def run_feed(self, feed: ProgramFeed, *,
                 on_progress: Callable[[Progress], None] | None = None,
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
        return self.run(prepared, on_progress=on_progress, feed=feed)

    # --- jogging ------------------------------------------------------------------------------

    def jog(self, moves: Mapping[str, float], *, feed_mm_min: float, work: bool = False,
            absolute: bool = False, continuous: bool = False,
            on_progress: Callable[[Progress], None] | None = None) -> RunReport:
        """Jog: move axes at a feed, planned with each axis's acceleration, within the soft
        limits; returns the report. :meth:`request_jog_cancel` (or any stop request)
        brings every axis to rest along its deceleration and drops the rest (Idle,
        homed); a hold holds it.

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
        axes = program_axes(self.config)
        for name, value in moves.items():
            if name not in axes:
                raise ArgumentError(f"jog axis {name!r}: allowed {', '.join(axes)}",
                                    reason="jog")
            if not math.isfinite(value):
                raise ArgumentError(f"jog {name}{value!r}: not a finite number", reason="jog")
        if not moves:
            raise ArgumentError("a jog names at least one axis", reason="jog")
        if isinstance(feed_mm_min, bool) or not (math.isfinite(feed_mm_min)
                                                 and feed_mm_min > 0):
            raise ArgumentError(f"jog feed {feed_mm_min!r} mm/min: a speed > 0",
                                reason="feed")
        if not self.is_homed:
            raise MachineStateError("a jog needs a homed machine (its soft limits): home it"
                                    " first", state=self._state.value)
        words = moves
        if continuous:
            words = self._continuous_targets(moves)
            work, absolute = False, True
        mode = ("G90" if absolute else "G91") + ("" if work else " G53")
        if not absolute and not work:
            here = self.positions_mm()
            words = {name: here[name] + value for name, value in moves.items()}
            mode = "G90 G53"
        text = (f"{mode} G1 " + " ".join(f"{name}{value:.6f}" for name, value in words.items())
                + f" F{feed_mm_min:.6f}\nM2\n")
        prepared = self.prepare("<jog>", text=text)
        self.jogging = True
        try:
            report, _ = self.run(prepared, on_progress=on_progress)
        finally:
            self.jogging = False
            if self._requests.reason == StopReason.JOG_CANCELLED.value:
                self.clear_stop_request()
        return report

    def _continuous_targets(self, directions: Mapping[str, float]) -> dict[str, float]:
        """Where a continuous jog along ``directions`` meets the first soft limit."""
        here = self.positions_mm()
        length = math.sqrt(sum(v * v for v in directions.values()))
        if length == 0.0:
            raise ArgumentError("a continuous jog needs a direction: a value other than 0",
                                reason="jog")
        reach = math.inf
        for name, value in directions.items():
            if value:
                lower, upper = self.config.axis(name).travel_mm
                room = (upper - here[name]) if value > 0 else (here[name] - lower)
                reach = min(reach, max(0.0, room) / (abs(value) / length))
        return {name: here[name] + value / length * reach for name, value in directions.items()}

    def request_jog_cancel(self) -> None:
        """Cancel a jog (grbl's 0x85): every axis to rest along its deceleration, the rest
        of the jog dropped, the machine Idle; nothing when no jog runs. Safe from a signal
        handler or another thread."""
        if self.jogging:
            self.request_stop(StopReason.JOG_CANCELLED.value)

    def _pause_at(self, pause: Pause | None) -> None:
        """The run came to rest at a program pause (or left it): a resume continues."""
        self.paused = pause
        if pause is not None:
            self._requests.resume = False
            self._requests.hold = True
            if self.on_pause is not None:
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
        return read_parameter_file(self.config.parameter_path)

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
        if self._state is not MachineState.IDLE:
            raise MachineStateError("the machine file can change only while the machine is"
                                    " idle", state=self._state.value)
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

    # --- stop requests ------------------------------------------------------------------------

    def request_stop(self, reason: str = StopReason.USER.value) -> None:
        """Ask whatever runs to stop: the first request stops along the deceleration, a
        second one at once. Safe to call from a signal handler (it only sets fields)."""
        requests = self._requests
        requests.count += 1
        if not requests.reason:
            requests.at_s = self.clock.now()
            requests.reason = reason

    @property
    def stop_requested(self) -> str:
        """Why a stop was asked ("" when none was)."""
        return self._requests.reason

    def _stop_now_requested(self) -> bool:
        return self._requests.count >= 2

    def clear_stop_request(self) -> None:
        """Forget a stop request (a console does, once the stop is done)."""
        self._requests = _Requests()

    # --- feed hold, resume and overrides --------------------------------------------------

    def request_hold(self) -> None:
        """Ask a running program to hold (grbl's ``!``): every axis decelerates along the
        path at its acceleration limit to rest and stays there, enabled (state Hold), until
        :meth:`request_resume` continues the path from there or :meth:`request_stop`
        abandons the program. Ignored when no program runs or it already holds. Safe to
        call from a signal handler or another thread (it only sets fields)."""
        requests = self._requests
        if self._state is MachineState.RUN and not requests.hold:
            requests.hold_at_s = self.clock.now()
            requests.resume = False
            requests.hold = True

    def request_resume(self) -> None:
        """Ask a held program to continue (grbl's ``~``, cycle start): the rest of the path
        is planned from rest where the axes stand and streamed from a common device tick.
        Ignored unless the program holds or is holding. Safe from a signal handler."""
        if self._requests.hold:
            self._requests.resume = True

    @property
    def hold_requested(self) -> bool:
        """True from a hold request until the run resumes."""
        return self._requests.hold

    def set_feed_override(self, percent: int) -> None:
        """Run feed moves at ``percent`` of their programmed feed (grbl's feed override).

        A running program's queued future is planned again at the new speed from a device
        tick just ahead and replaced there (call 38), the speed changing within the axes'
        acceleration limits; the axes' own velocity limits still apply. Held or idle, the
        next motion uses it. Safe from another thread.

        Raises:
            ArgumentError: ``percent`` is not a whole number within 10 .. 200.
        """
        low, high = FEED_OVERRIDE_RANGE
        if isinstance(percent, bool) or not isinstance(percent, int) or not (
                low <= percent <= high):
            raise ArgumentError(f"feed override {percent!r} %: a whole percentage within"
                                f" {low} .. {high}", reason="feed_override")
        self.override_at_s = self.clock.now()
        self.feed_override_percent = percent

    def set_rapid_override(self, percent: int) -> None:
        """Run rapids at ``percent`` of the fastest the axes allow (grbl's rapid override:
        100, 50 or 25), taking effect as :meth:`set_feed_override` does.

        Raises:
            ArgumentError: ``percent`` is not one of 25, 50, 100.
        """
        if isinstance(percent, bool) or percent not in RAPID_OVERRIDES:
            allowed = ", ".join(map(str, RAPID_OVERRIDES))
            raise ArgumentError(f"rapid override {percent!r} %: one of {allowed}",
                                reason="rapid_override")
        self.override_at_s = self.clock.now()
        self.rapid_override_percent = percent

    def _take_hold_request(self) -> tuple[bool, bool]:
        """(hold asked, resume asked); a resume clears both."""
        requests = self._requests
        if requests.resume:
            requests.hold = requests.resume = False
            return True, True
        return requests.hold, False

    # --- homing -------------------------------------------------------------------------------

    def home(self, *, axes: Sequence[str] | None = None,
             on_progress: Callable[[Progress], None] | None = None) -> float:
        """Home every axis, or only ``axes`` (grbl's cycle, in the configured order);
        returns the seconds.

        Afterwards every homed axis is in position mode, enabled, at its home position (the
        switch's machine position pulled off), and marked homed on its device.

        Parameters:
            axes: the axes to home (default: every axis), in any order.
            on_progress: called with the homing's progress at every poll.

        Raises:
            KeyError: an axis the machine does not have (the message lists those it has).
            MachineStateError: the machine is not Idle.
            SequenceFaultError: a switch was not found, did not open, or closed the wrong
                way round (names the axis); every axis was brought to rest; Alarm.
            StopRequestedError: a stop was asked; every axis was brought to rest; Idle, not
                homed.
            DeviceError: a device faulted or refused (Alarm).
        """
        names = list(self.machine.axes) if axes is None else [
            self.machine.axis(name).name for name in axes]
        self._enter(MachineState.HOMING)
        started = self.clock.now()
        for name in names:
            self.homed[name] = False
            self.machine.axis(name).client.set_homed_marker(0)
        cycle = HomingCycle(self.machine, keep_alive_period_s=self.keep_alive_period_s(),
                            stop_now=self._stop_now_requested, axes=names)
        cycle.enter_velocity_mode()

        def progress(where: dict[str, float]) -> None:
            if on_progress is not None:
                on_progress(Progress(MachineState.HOMING, where))

        try:
            zeroes = cycle.run(should_stop=lambda: self._requests.reason, on_positions=progress)
        except StopRequestedError:
            self.stop_latency_s = self.clock.now() - self._requests.at_s
            self._state = MachineState.IDLE
            raise
        except (SequenceFaultError, UsbMotionError):
            self._state = MachineState.ALARM
            raise
        self.zeroes.update(zeroes)
        for name in names:
            axis = self.machine.axis(name)
            axis.client.set_homed_marker(homed_mark(self.config, axis.config))
            self.homed[name] = True
        self._state = MachineState.IDLE
        return self.clock.now() - started

    # --- running ------------------------------------------------------------------------------

    def run(
        self,
        prepared: Prepared,
        *,
        on_progress: Callable[[Progress], None] | None = None,
        homing_s: float = 0.0,
        feed: ProgramFeed | None = None,
    ) -> tuple[RunReport, Trace]:
        """Run a prepared program; returns the report and the trace.

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
        state = self._state.value
        if self._state is not MachineState.IDLE:
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
        self._enter(MachineState.RUN)
        run = self.last_run = Run(self, prepared, on_progress, homing_s, feed)
        try:
            report, trace = run.go()
        finally:
            self._requests.hold = self._requests.resume = False
        if prepared.warnings:  # what prepare_program found risky (motion.plunges)
            report = replace(report, notes=(*prepared.warnings, *report.notes))
        self._state = MachineState.ALARM if run.faulted else MachineState.IDLE
        for name in run.faulted_axes:
            self.homed[name] = False
        program = run.prepared.program
        if report.completed and program.offsets != prepared.offsets:
            self.save_work_offsets(program.offsets)
        return report, trace

    # --- after a fault ------------------------------------------------------------------------

    def reset(self) -> None:
        """Alarm -> Idle: every queue cleared, every servo disabled, every fault cleared; an
        axis whose servo a fault disabled needs homing again."""
        machine = self.machine
        for name, status in machine.status().items():
            if status.fault != FaultCode.NONE:
                self.homed[name] = False
                machine.axis(name).client.set_homed_marker(0)
        machine.stop()
        machine.clear_faults()
        self._state = MachineState.IDLE

    # --- waiting ------------------------------------------------------------------------------

    def keep_alive_period_s(self) -> float:
        """How often a front waiting for its operator must call :meth:`keep_alive` so that
        no watchdog trips on an enabled axis (0: the machine has no watchdog)."""
        watchdog_ms = self.config.watchdog_ms
        return watchdog_ms / 1000.0 / 4 if watchdog_ms > 0 else 0.0

    def keep_alive(self) -> None:
        """Feed every device's watchdog (a queue query each: any command does)."""
        self.machine.ping()

    # --- leaving ------------------------------------------------------------------------------

    def shutdown(self) -> None:
        """The clean exit: every queue empty, every servo disabled (no fault latches: a
        disabled servo has no watchdog), diagnostics off; the homed mark stays on the
        devices for the next host.

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
        if failures:
            raise DeviceError("shutdown: " + "; ".join(failures))

    def close(self) -> None:
        """Close every link (safe twice)."""
        self.machine.close()

    def __enter__(self) -> MachineSession:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


__all__ = ["MachineSession"]
