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
  order (:mod:`usbmotion.automation.homing`), machine zero set once from the switch edge the
  device latched.
- **Running** (:meth:`MachineSession.prepare`, :meth:`MachineSession.run`): a program is
  interpreted and planned from where the machine stands (never from 0), checked against
  every axis's travel (soft limits) before anything moves, then streamed with every axis
  started on the same device tick.
- **Stopping** (:meth:`MachineSession.request_stop`, safe from a signal handler): the
  first request brings every axis to rest along the program's path at its planned
  deceleration (call 38 replaces the queued future from a device tick just ahead, so there
  is no seam whatever the latency); a second one stops at once (servos off: the axes coast).
- **Leaving** (:meth:`MachineSession.shutdown`): every axis at rest, servos disabled
  without latching a fault, the homed mark kept for the next host.
"""

from __future__ import annotations

import math
import zlib
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import numpy.typing as npt

from usbmotion.automation.device_io import DeviceHomingIO, HomingAxis, MachineZero
from usbmotion.automation.homing import Home, MoveAxisHome
from usbmotion.automation.sequence import run_sequence
from usbmotion.errors import (
    ConfigError,
    DeviceError,
    DeviceTimeoutError,
    LinkCorruptedError,
    LinkLostError,
    MachineStateError,
    SequenceFaultError,
    StopRequestedError,
    UsbMotionError,
)
from usbmotion.host.config import AxisConfig, MachineConfig
from usbmotion.host.device import Alarm, ControlMode, MotionStats, Status
from usbmotion.host.machine import Machine
from usbmotion.host.stream import SetpointStream, StreamProgress, run_streams
from usbmotion.motion.gcode import GCodeProgram, parse_gcode, read_gcode_text
from usbmotion.motion.limits import AxisLimits, PlannerConfig, check_travel
from usbmotion.motion.planner import Plan, plan_moves
from usbmotion.motion.sampler import sample_plan
from usbmotion.motion.stopping import stop_setpoints
from usbmotion.protocol import FaultCode, fault_words
from usbmotion.session.report import (
    PLAN_AXES,
    SETTLE_COUNTS,
    FaultRecord,
    RunReport,
    Trace,
    build_report,
    line_at,
)
from usbmotion.session.state import MachineState, StopReason, check_transition

HOMING_POLL_HZ = 50.0
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
STOP_LEAD_S = 0.005
"""How far ahead of the devices' present tick a stop replaces the queued future: covers
the time the lines take to reach every device (one that arrives late skips what is past)."""
REST_TIMEOUT_S = 5.0
"""The longest a stop waits for every axis's queue to play out its deceleration."""
REST_POLL_S = 0.005
"""How often a stopped homing looks whether every axis is at rest."""
SETTLE_TIMEOUT_S = 1.0
"""How long a stopped axis then has to settle within SETTLE_COUNTS of where it was sent."""


def homed_mark(config: MachineConfig, axis: AxisConfig) -> int:
    """The homed mark (1..255) a device of this machine carries once homed: it names the
    machine and the axis's switch position, so another machine file's homing does not
    pass for this one's."""
    text = f"{config.name}|{axis.name}|{axis.homing.position_mm!r}|{axis.counts_per_mm!r}"
    return 1 + zlib.crc32(text.encode("utf-8")) % 255


def trace_period_s(duration_s: float) -> float:
    """The diagnostics period of the trace of a program lasting ``duration_s``."""
    return max(DIAGNOSTICS_PERIOD_S, duration_s / TRACE_POINTS)


def home_position_mm(axis: AxisConfig) -> float:
    """Where homing leaves an axis: the switch's machine position, pulled off toward the
    travel."""
    return axis.homing.position_mm - axis.homing.direction * axis.homing.pull_off_mm


@dataclass(frozen=True, slots=True)
class Prepared:
    """A program interpreted and planned from a start position, checked against the travel.

    ``start_mm`` is where the plan starts (X, Y, Z); ``homed`` whether that is a homed
    position (soft limits checked) or the devices' own counts (not homed, not checked).
    """

    program: GCodeProgram
    plan: Plan
    start_mm: tuple[float, float, float]
    homed: bool


@dataclass(slots=True)
class _Requests:
    """Stop requests, set from a signal handler: plain fields only."""

    reason: str = ""
    count: int = 0
    at_s: float = 0.0
    """When the first request came (the session's clock)."""
    notes: list[str] = field(default_factory=list)


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
        self._wait_for_rest(names)

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

    def _plan_axes(self) -> list[AxisConfig]:
        planner_inputs(self.config)
        return [self.config.axis(name) for name in PLAN_AXES]

    def start_position_mm(self, *, unhomed: bool = False) -> tuple[
            tuple[float, float, float], bool]:
        """Where the next program starts, and whether that is a homed position: where the
        machine stands when it is homed (or, with ``unhomed``, in the devices' own counts);
        otherwise where homing will leave it."""
        axes = self._plan_axes()
        if self.is_homed or unhomed:
            where = self.positions_mm()
            return (where["X"], where["Y"], where["Z"]), self.is_homed
        x, y, z = (home_position_mm(axis) for axis in axes)
        return (x, y, z), True

    # --- programs -----------------------------------------------------------------------------

    def prepare(self, source: str | Path, *, text: str | None = None,
                unhomed: bool = False) -> Prepared:
        """Interpret and plan a program from where the machine will start it, and check it
        against every axis's travel; nothing moves.

        The start is where the machine stands when it is homed; where homing will leave it
        when it is not (home, then run it); or, with ``unhomed``, where an unhomed machine
        stands, in the devices' own counts (soft limits cannot be checked then).

        Parameters:
            source: the file (its text is read) or, with ``text``, the name to report.
            text: the program's text, when it is not read from ``source``.
            unhomed: plan an unhomed machine from where it stands.

        Raises:
            GCodeError: the program does not parse (names the line).
            SoftLimitError: a move leaves an axis's travel (names the line, the axis, the
                coordinate and the limit).
            PlanningError: a move the machine cannot make.
            OSError: the file cannot be read.
        """
        start_mm, homed = self.start_position_mm(unhomed=unhomed)
        axes = self._plan_axes()
        body = read_gcode_text(source) if text is None else text
        program, plan = plan_gcode(self.config, body, file=str(source), start_mm=start_mm)
        if homed:
            check_travel(plan.vertices_mm, plan.line, [a.travel_mm for a in axes],
                         axes=PLAN_AXES)
        prepared = Prepared(program, plan, start_mm, homed)
        self.program = prepared
        return prepared

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

    # --- homing -------------------------------------------------------------------------------

    def home(self) -> float:
        """Home every axis (grbl's cycle, in the configured order); returns the seconds.

        Afterwards every axis is in position mode, enabled, at its home position (the
        switch's machine position pulled off), and marked homed on its device.

        Raises:
            MachineStateError: the machine is not Idle.
            SequenceFaultError: a switch was not found, did not open, or closed the wrong
                way round (names the axis); every axis was brought to rest; Alarm.
            StopRequestedError: a stop was asked; every axis was brought to rest; Idle, not
                homed.
            DeviceError: a device faulted or refused (Alarm).
        """
        self._enter(MachineState.HOMING)
        started = self.clock.now()
        config = self.config
        machine = self.machine
        for name, axis in machine.axes.items():
            self.homed[name] = False
            axis.client.set_homed_marker(0)
        io = DeviceHomingIO(
            {name: HomingAxis(
                client=axis.client, scale=axis.scale, direction=axis.config.homing.direction,
                accel_mm_s2=axis.config.max_accel_mm_s2, switch_mm=axis.config.homing.position_mm,
                pull_off_speed_mm_s=axis.config.homing.speed_mm_s,
                velocity_gains=(axis.config.velocity_gains.kp, axis.config.velocity_gains.ki,
                                axis.config.velocity_gains.kd),
                gains=(axis.config.gains.kp, axis.config.gains.ki, axis.config.gains.kd),
            ) for name, axis in machine.axes.items()},
            clock=self.clock, poll_period_s=1.0 / HOMING_POLL_HZ,
            tick_s=config.servo_period_s, motion_scalar=config.motion_scalar,
            keep_alive_polls=max(1, int((self.keep_alive_period_s() or 1.0) * HOMING_POLL_HZ)),
        )

        def make(name: str) -> MoveAxisHome:
            axis = machine.axis(name).config
            homing = axis.homing
            return MoveAxisHome(name, homing.speed_mm_s, slow_speed_mm_s=homing.slow_speed_mm_s,
                                backoff_mm=homing.backoff_mm, search_mm=homing.search_mm,
                                pull_off_mm=homing.pull_off_mm)

        order = [list(group) for group in config.homing_order] or None
        sequence = Home(list(machine.axes), make, order=order)
        io.enter_velocity_mode()
        try:
            run_sequence(sequence, io, io, clock=self.clock, rate_hz=HOMING_POLL_HZ,
                         timeout_s=self._homing_timeout_s(), on_poll=lambda _: io.after_poll(),
                         should_stop=lambda: self._requests.reason)
        except StopRequestedError:
            self._settle_homing(io)
            self.stop_latency_s = self.clock.now() - self._requests.at_s
            self._state = MachineState.IDLE
            raise
        except (SequenceFaultError, UsbMotionError):
            sequence.stop(io)
            try:
                self._settle_homing(io)
            except UsbMotionError:
                machine.stop()
            self._state = MachineState.ALARM
            raise
        self.zeroes = {}
        for name, zero in io.zeroes.items():
            seen_mm = sequence.axes[name].seen_closed_mm
            seen = zero.edge_counts if seen_mm is None else machine.axis(name).scale.to_counts(
                -machine.axis(name).config.homing.direction * seen_mm)
            self.zeroes[name] = replace(zero, seen_counts=seen)
        for name, axis in machine.axes.items():
            axis.client.set_homed_marker(homed_mark(config, axis.config))
            self.homed[name] = True
        self._state = MachineState.IDLE
        return self.clock.now() - started

    def _homing_timeout_s(self) -> float:
        """The longest homing may take: every group's worst axis, seek to pull-off, twice."""
        total = 0.0
        for group in self.config.homing_order or (self.config.axis_names,):
            worst = 0.0
            for name in group:
                axis = self.config.axis(name)
                homing = axis.homing
                locate = 2 * (5 * homing.backoff_mm + 1.0) / homing.slow_speed_mm_s
                worst = max(worst, homing.search_mm / homing.speed_mm_s + locate
                            + homing.pull_off_mm / homing.speed_mm_s)
            total += worst
        return 2 * total + 10.0

    def _settle_homing(self, io: DeviceHomingIO) -> None:
        """After a stopped homing: wait until every axis has ramped to rest."""
        deadline = self.clock.now() + REST_TIMEOUT_S
        names = list(self.machine.axes)
        while True:
            if self._stop_now_requested():
                self.machine.stop()
                return
            if all(io.at_rest(name) for name in names):
                return
            if self.clock.now() > deadline:
                raise DeviceError("the axes did not come to rest after homing stopped",
                                  device=", ".join(names))
            io.after_poll()
            self.clock.sleep(REST_POLL_S)

    # --- running ------------------------------------------------------------------------------

    def run(
        self,
        prepared: Prepared,
        *,
        on_progress: Callable[[float, float], None] | None = None,
        homing_s: float = 0.0,
    ) -> tuple[RunReport, Trace]:
        """Run a prepared program; returns the report and the trace.

        The machine must be where the program was prepared from (prepare it again after
        anything moved). A device fault stops every other axis along its deceleration; a
        stop request does so for every axis; the report says why the run ended.

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
        here = (where["X"], where["Y"], where["Z"])
        counts = [self.config.axis(name).counts_per_mm for name in PLAN_AXES]
        if any(abs(a - b) * scale > 1.0 for a, b, scale in zip(here, prepared.start_mm, counts,
                                                               strict=True)):
            raise MachineStateError(
                f"the program was prepared from {prepared.start_mm} but the machine stands"
                f" at {here}: prepare it again", state=state)
        self._enter(MachineState.RUN)
        return _Run(self, prepared, on_progress, homing_s).go()

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

    # --- shared waits -------------------------------------------------------------------------

    def _wait_for_rest(self, names: list[str], *, poll_s: float = 0.01) -> None:
        """Wait until every named axis that is enabled has played out its queue and settled
        (within :data:`SETTLE_COUNTS` of its commanded position, not moving); an axis that
        keeps a larger error is accepted after :data:`SETTLE_TIMEOUT_S`: its servo holds it.

        Raises:
            DeviceError: a queue did not play out within :data:`REST_TIMEOUT_S`.
        """
        clock = self.clock
        deadline = clock.now() + REST_TIMEOUT_S
        settle_by: float | None = None
        last: dict[str, int] = {}
        while True:
            if self._stop_now_requested():
                self.machine.stop()
                return
            playing = settling = False
            for name in names:
                status = self.machine.axis(name).client.status()
                if not status.enabled:
                    continue
                moved = abs(status.actual_counts - last.get(name, 2**40)) > 1
                last[name] = status.actual_counts
                if status.queued:
                    playing = True
                elif moved or abs(status.desired_counts - status.actual_counts) > SETTLE_COUNTS:
                    settling = True
            now = clock.now()
            if not playing:
                settle_by = now + SETTLE_TIMEOUT_S if settle_by is None else settle_by
                if not settling or now > settle_by:
                    return
            elif now > deadline:
                raise DeviceError(f"axes {', '.join(names)} did not come to rest",
                                  device=", ".join(names))
            clock.sleep(poll_s)


class _Run:
    """One run of a prepared program (:meth:`MachineSession.run`)."""

    def __init__(self, session: MachineSession, prepared: Prepared,
                 on_progress: Callable[[float, float], None] | None, homing_s: float) -> None:
        self.session = session
        self.machine = session.machine
        self.config = session.config
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
        counts_per_mm = [self.config.axis(n).counts_per_mm for n in PLAN_AXES]
        self.counts_per_mm = np.array(counts_per_mm)
        self.setpoints: npt.NDArray[np.int32] = sample_plan(
            self.plan, period_s=self.period_s, counts_per_mm=counts_per_mm)
        self.trace = Trace(tick_s=self.tick_s, start_tick=0,
                           counts_per_mm={n: self.machine.axis(n).config.counts_per_mm
                                          for n in self.machine.axes})
        self.streams: dict[str, SetpointStream] = {}
        self.start_tick = 0
        self.stop_distance_mm = 0.0
        self.stop_planned_mm = 0.0
        self.stop_latency_s = 0.0
        self.stopped_index: float | None = None

    # the devices' view of time -----------------------------------------------------------------

    def _record(self, axis: str, fault: str, tick: int) -> None:
        if any(f.axis == axis for f in self.faults):
            return
        elapsed = (tick - self.trace.start_tick) * self.tick_s
        self.faults.append(FaultRecord(axis, fault, elapsed, line_at(self.plan, elapsed)))

    def go(self) -> tuple[RunReport, Trace]:
        session, machine = self.session, self.machine
        for name in PLAN_AXES:
            client = machine.axis(name).client
            client.clear_queue()
            client.set_servo_enable(True)
        diag_ticks = max(1, round(trace_period_s(self.plan.duration_s) / self.tick_s))
        for name, axis in machine.axes.items():
            axis.client.on_diagnostics = self.trace.record(name)
        sync = machine.synchronise(margin_s=START_MARGIN_S, axes=PLAN_AXES)
        self.sync = sync
        self.start_tick = self.trace.start_tick = sync.devices[0].start_tick
        for name in PLAN_AXES:
            client = machine.axis(name).client
            client.reset_motion_stats()
            client.set_diagnostics_interval(diag_ticks)

        def progress(update: StreamProgress) -> None:
            if self.on_progress is not None:
                done = min(s.consumed_estimate for s in self.streams.values())
                self.on_progress(min(done * self.period_s, self.plan.duration_s),
                                 self.plan.duration_s)

        for index, name in enumerate(PLAN_AXES):
            self.streams[name] = SetpointStream(
                machine.axis(name).client, self.setpoints[:, index], period_s=self.period_s,
                verify=True, on_progress=progress)

        def on_alarm(axis: str) -> Callable[[Alarm], None]:
            return lambda alarm: self._record(axis, alarm.fault_name, alarm.tick)

        for name, axis in machine.axes.items():
            axis.client.on_alarm = on_alarm(name)
        clock = session.clock
        last_check = [clock.now()]

        def check() -> bool:
            if session.stop_requested:
                return True
            now = clock.now()
            for axis in machine.axes.values():
                axis.client.read_pending()
            if now - last_check[0] >= STATUS_CHECK_S:
                last_check[0] = now
                for name, axis in machine.axes.items():
                    status = axis.client.status()
                    if status.fault != FaultCode.NONE:
                        _, fault_tick = axis.client.fault()
                        self._record(name, status.fault_name, fault_tick)
            return bool(self.faults)

        reason = StopReason.COMPLETED.value
        link_error = ""
        lost_axis = ""
        try:
            run_streams(list(self.streams.values()), should_stop=check,
                        max_wait_s=FAULT_CHECK_S)
            if not (self.faults or session.stop_requested):
                self._wait_drained(check)
            if not (self.faults or session.stop_requested):
                self._settle()
            if self.faults or session.stop_requested:
                reason = (f"fault: {self._fault_words()}" if self.faults
                          else session.stop_requested)
                session._enter(MachineState.HOLD)
                self._decelerate()
        except (LinkLostError, LinkCorruptedError, DeviceTimeoutError) as error:
            link_error = str(error)
            reason = f"{StopReason.LINK.value}: {error}"
            lost_axis = next((n for n in PLAN_AXES if machine.axis(n).client.name
                              == getattr(error, "device", None)), "")
            try:
                machine.stop()
            except UsbMotionError as also:
                self.notes.append(f"stopping: {also}")
        if self.faults and not reason.startswith("fault"):
            reason = f"fault: {self._fault_words()}"
        return self._finish(reason, link_error, lost_axis)

    def _fault_words(self) -> str:
        return "; ".join(f"axis {f.axis} {f.fault}" for f in self.faults)

    def _wait_drained(self, check: Callable[[], bool]) -> None:
        """Until every queue is empty (the last setpoint being executed), or a stop."""
        clients = [self.machine.axis(n).client for n in PLAN_AXES]
        clock = self.session.clock
        while True:
            if check():
                return
            queued = max(client.queue_status()[0] for client in clients)
            if not queued:
                return
            clock.sleep(min(FAULT_CHECK_S, max(self.period_s, queued * self.period_s)))

    def _settle(self) -> None:
        """After the last setpoint: until every axis is within SETTLE_COUNTS of it, for at
        most SETTLE_TIMEOUT_S."""
        clock = self.session.clock
        deadline = clock.now() + SETTLE_TIMEOUT_S
        while clock.now() < deadline:
            statuses = self.machine.status()
            if all(abs(s.desired_counts - s.actual_counts) <= SETTLE_COUNTS
                   for s in statuses.values()):
                return
            clock.sleep(REST_POLL_S)

    def _decelerate(self) -> None:
        """Every axis still enabled to rest along the path at its planned deceleration:
        the queued future replaced from a device tick just ahead (call 38)."""
        session, machine = self.session, self.machine
        clock = session.clock
        estimate = self.sync.devices[0].estimate
        tick = math.ceil(estimate.ticks_at(clock.now()) + STOP_LEAD_S / self.tick_s)
        scalar = self.config.motion_scalar
        sent = min(stream.sent for stream in self.streams.values())
        index = min(max(0, -(-(tick - self.start_tick) // scalar)), sent)
        tick = max(tick, self.start_tick + index * scalar)
        accel = [self.config.axis(n).max_accel_mm_s2 * self.config.axis(n).counts_per_mm
                 for n in PLAN_AXES]
        asked_s = session._requests.at_s if session.stop_requested else clock.now()
        if index == 0 or index >= self.setpoints.shape[0]:
            stop_rows = np.zeros((0, 3), dtype=np.int64)
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
        for column, name in enumerate(PLAN_AXES):
            client = machine.axis(name).client
            try:
                client.replace_from(tick, stop_rows[:, column].tolist())
            except UsbMotionError as error:
                self.notes.append(f"axis {name}: could not replace its queue ({error})")
        self.stopped_index = end
        try:
            session._wait_for_rest(list(PLAN_AXES))
        except DeviceError as error:
            self.notes.append(f"stop: {error}")
            machine.stop()
        self.stop_latency_s = clock.now() - asked_s
        if index > 0:
            statuses = machine.status()
            rest = np.array([statuses[n].actual_counts for n in PLAN_AXES], dtype=np.float64)
            began = self.setpoints[index - 1].astype(np.float64)
            self.stop_distance_mm = float(np.linalg.norm((rest - began) / self.counts_per_mm))
        if session._stop_now_requested():
            self.notes.append("a second stop request stopped every axis at once (servos off:"
                              " the axes coasted)")

    def _finish(self, reason: str, link_error: str, lost_axis: str) -> tuple[RunReport, Trace]:
        session, machine = self.session, self.machine
        statuses: dict[str, Status] = {}
        stats: dict[str, MotionStats] = {}
        for name in PLAN_AXES:
            client = machine.axis(name).client
            try:
                statuses[name] = client.status()
                stats[name] = client.motion_stats()
                client.set_diagnostics_interval(0)
            except UsbMotionError as error:
                self.notes.append(f"axis {name}: {error}")
        for axis in machine.axes.values():
            axis.client.on_alarm = None
        completed = reason == StopReason.COMPLETED.value
        if link_error:
            confirmed = self.streams[lost_axis].sent if lost_axis else min(
                s.sent for s in self.streams.values())
        elif self.stopped_index is not None:
            confirmed = max(0, math.floor(self.stopped_index) + 1)
        else:
            confirmed = min(self.streams[n].sent - statuses[n].queued for n in PLAN_AXES
                            if n in statuses)
        report = build_report(
            self.prepared.program, machine, self.plan, self.setpoints.shape[0], self.trace,
            self.homing_s, statuses, stats, self.faults, completed=completed,
            consumed=confirmed, skew_s=self.sync.estimated_skew_s, stop_reason=reason,
            stop_distance_mm=self.stop_distance_mm, stop_planned_mm=self.stop_planned_mm,
            stop_latency_s=self.stop_latency_s, link_error=link_error,
            notes=tuple(session._requests.notes + self.notes))
        faulted = bool(self.faults) or bool(link_error) or any(
            s.fault != FaultCode.NONE for s in statuses.values())
        session._state = MachineState.ALARM if faulted else MachineState.IDLE
        for name, status in statuses.items():
            if status.fault != FaultCode.NONE:
                session.homed[name] = False
        return report, self.trace


def plan_gcode(config: MachineConfig, text: str, *, file: str = "<string>",
               start_mm: tuple[float, float, float] = (0.0, 0.0, 0.0)
               ) -> tuple[GCodeProgram, Plan]:
    """Interpret and plan a program for a machine from ``start_mm`` (pure: no machine is
    needed; :meth:`MachineSession.prepare` adds where the machine stands and soft limits).

    Raises:
        GCodeError, PlanningError: as :meth:`MachineSession.prepare`.
        ConfigError: the machine lacks an X, Y or Z axis.
    """
    limits, planner, _ = planner_inputs(config)
    program = parse_gcode(text, file=file, start=start_mm)
    return program, plan_moves(program.moves, limits, planner, start=start_mm)


def planner_inputs(config: MachineConfig) -> tuple[list[AxisLimits], PlannerConfig, list[float]]:
    """Per-axis limits, planner settings and counts per mm of X, Y, Z from a machine config.

    Raises:
        ConfigError: the machine lacks an X, Y or Z axis.
    """
    missing = [name for name in PLAN_AXES if name not in config.axis_names]
    if missing:
        raise ConfigError(
            f"{config.path}: G-code programs need axes X, Y and Z; missing {', '.join(missing)}",
            path=str(config.path), key="axes",
        )
    axes = [config.axis(name) for name in PLAN_AXES]
    limits = [AxisLimits(a.max_velocity_mm_s, a.max_accel_mm_s2) for a in axes]
    planner = PlannerConfig(
        junction_deviation_mm=config.junction_deviation_mm,
        arc_tolerance_mm=config.arc_tolerance_mm,
    )
    return limits, planner, [a.counts_per_mm for a in axes]


__all__ = [
    "ControlMode",
    "MachineSession",
    "Prepared",
    "home_position_mm",
    "homed_mark",
    "plan_gcode",
    "planner_inputs",
    "trace_period_s",
]
