"""The main job: run a G-code program on a machine and report how it went.

Parse and plan first (a program that does not parse or plan stops before anything moves),
then connect, configure, home, start every axis on the same device tick, stream the
setpoints with flow control, wait for the end, and measure: planned and executed time,
per-axis following error from the devices' own diagnostics, faults, and the G-code words
that were ignored. A fault on any axis stops every axis.
"""

from __future__ import annotations

from array import array
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from usbmotion.automation.device_io import DeviceHomingIO
from usbmotion.automation.homing import Home, LimitSwitchState, MoveAxisHome
from usbmotion.automation.sequence import run_sequence
from usbmotion.errors import (
    ConfigError,
    DeviceTimeoutError,
    LinkCorruptedError,
    LinkLostError,
    UsbMotionError,
)
from usbmotion.host.config import MachineConfig
from usbmotion.host.device import Alarm, ControlMode, Diagnostics, MotionStats, Status
from usbmotion.host.machine import Machine
from usbmotion.host.stream import SetpointStream, StreamProgress, run_streams, wait_until_drained
from usbmotion.motion.gcode import GCodeProgram
from usbmotion.motion.limits import AxisLimits, PlannerConfig
from usbmotion.motion.planner import Plan, plan_moves
from usbmotion.motion.sampler import sample_plan
from usbmotion.protocol.table import Fault as FaultCode

PLAN_AXES = ("X", "Y", "Z")
HOMING_POLL_HZ = 50.0
DIAGNOSTICS_PERIOD_S = 0.01
"""The shortest period of the diagnostics lines of the trace (plots, end points, settling):
the peak and RMS error come from the devices' own statistics (call 35), so the trace need
not be dense."""
TRACE_POINTS = 10_000
"""The most diagnostics lines per axis the trace aims at (more than a plot can show): a
longer program gets a sparser trace (10 minutes, one line every 60 ms; an hour, every
0.36 s), so its memory and the host's work stay bounded."""
SETTLE_COUNTS = 2
START_MARGIN_S = 0.2
FAULT_CHECK_S = 0.05
"""How often the run reads the alarms the devices printed (no exchange: lines that came)."""
STATUS_CHECK_S = 1.0
"""How often the run also asks every device its status, in case an alarm line was lost."""


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


def plan_program(program: GCodeProgram, config: MachineConfig) -> Plan:
    """Plan a program for a machine, from its home position (every axis at 0).

    Raises:
        PlanningError: a move the machine cannot make (names the line).
        ConfigError: the machine lacks an X, Y or Z axis.
    """
    limits, planner, _ = planner_inputs(config)
    origin = tuple(config.axis(n).homing.position_mm for n in PLAN_AXES)
    return plan_moves(program.moves, limits, planner, start=(origin[0], origin[1], origin[2]))


@dataclass(frozen=True, slots=True)
class AxisResult:
    """How one axis followed the program, from the device's own statistics (call 35).

    The peak and RMS following error (desired - actual) are over every servo tick of the
    run, not over sampled diagnostics lines; ``max_error_time_s`` and ``max_error_line``
    say when, since the start, and at which program line the peak came. ``ticks`` is the
    servo ticks counted; ``samples`` the diagnostics lines recorded for the plots.
    """

    name: str
    max_error_counts: int
    rms_error_counts: float
    max_error_mm: float
    rms_error_mm: float
    final_error_counts: int
    samples: int
    ticks: int = 0
    max_error_time_s: float = 0.0
    max_error_line: int = 0


@dataclass(frozen=True, slots=True)
class FaultRecord:
    """A fault seen during the run: which axis, what, when, and at which program line."""

    axis: str
    fault: str
    time_s: float
    line: int


@dataclass(frozen=True, slots=True)
class RunReport:
    """The figures of one run. ``completed`` is False after a fault or an interruption."""

    program: str
    machine: str
    moves: int
    setpoints_per_axis: int
    planned_time_s: float
    executed_time_s: float
    settle_time_s: float
    homing_time_s: float
    axes: tuple[AxisResult, ...]
    faults: tuple[FaultRecord, ...]
    ignored_words: tuple[str, ...]
    end_position_mm: Mapping[str, float]
    completed: bool
    stopped_at_line: int = 0
    stopped_at_setpoint: int = 0
    skew_estimate_s: float = 0.0
    endpoints_checked: int = 0
    max_endpoint_miss_mm: float = 0.0
    link_error: str = ""
    notes: tuple[str, ...] = ()

    def to_json(self) -> dict[str, Any]:
        """The report as plain JSON-ready data."""
        data = asdict(self)
        data["end_position_mm"] = dict(self.end_position_mm)
        return data


@dataclass(slots=True)
class Trace:
    """What the run recorded, for plots: device diagnostics per axis, in device ticks.

    Each store holds 64-bit integers in an ``array`` (8 bytes a value), so a long program
    costs 32 bytes per diagnostics line and axis.
    """

    tick_s: float
    start_tick: int
    clock: dict[str, array[int]] = field(default_factory=dict)
    desired: dict[str, array[int]] = field(default_factory=dict)
    actual: dict[str, array[int]] = field(default_factory=dict)
    queued: dict[str, array[int]] = field(default_factory=dict)
    counts_per_mm: dict[str, float] = field(default_factory=dict)

    def record(self, axis: str) -> Callable[[Diagnostics], None]:
        """A diagnostics callback that appends to this trace."""
        stores = (self.clock, self.desired, self.actual, self.queued)
        for store in stores:
            store.setdefault(axis, array("q"))
        clock, desired, actual, queued = (store[axis] for store in stores)

        def on_line(line: Diagnostics) -> None:
            clock.append(line.clock)
            desired.append(line.desired)
            actual.append(line.actual_counts)
            queued.append(line.queued)

        return on_line

    def column(self, store: dict[str, array[int]], axis: str) -> npt.NDArray[np.int64]:
        """One store of one axis as a numpy array (a copy)."""
        values = store.get(axis)
        if values is None:
            return np.zeros(0, dtype=np.int64)
        return np.frombuffer(values, dtype=np.int64).copy()

    def arrays(self, axis: str) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.int64],
                                         npt.NDArray[np.int64]]:
        """(time since start s, desired counts, actual counts) of one axis."""
        clock = self.column(self.clock, axis)
        return ((clock - self.start_tick).astype(np.float64) * self.tick_s,
                self.column(self.desired, axis), self.column(self.actual, axis))


class _Mirror:
    """Homing toward the upper switch as if it were the lower one: swap switches, negate moves."""

    def __init__(self, inner: DeviceHomingIO, upward: set[str]) -> None:
        self.inner = inner
        self.upward = upward

    def limit_switches(self, axis: str) -> LimitSwitchState | None:
        state = self.inner.limit_switches(axis)
        if state is None or axis not in self.upward:
            return state
        return LimitSwitchState(state.at_upper_limit, state.at_lower_limit)

    def position_mm(self, axis: str) -> float:
        sign = -1.0 if axis in self.upward else 1.0
        return sign * self.inner.position_mm(axis)

    def set_target_velocity(self, axis: str, velocity_mm_s: float) -> None:
        sign = -1.0 if axis in self.upward else 1.0
        self.inner.set_target_velocity(axis, sign * velocity_mm_s)

    def zero_position(self, axis: str) -> None:
        self.inner.zero_position(axis)


def home_machine(machine: Machine) -> float:
    """Home every axis in the configured order; returns the time it took, seconds.

    Every axis ends in position mode, servo enabled, at its configured home position.

    Raises:
        SequenceFaultError: a switch closed the wrong way round, or homing timed out
            (the axis and the reason are in the error); every axis is stopped first.
    """
    config = machine.config
    clock = machine.clock
    started = clock.now()
    io = DeviceHomingIO(
        {name: axis.client for name, axis in machine.axes.items()},
        {name: axis.scale for name, axis in machine.axes.items()},
        poll_period_s=1.0 / HOMING_POLL_HZ,
        motion_period_s=dict.fromkeys(machine.axes, config.motion_period_s),
        velocity_gains={name: (axis.config.velocity_gains.kp, axis.config.velocity_gains.ki,
                               axis.config.velocity_gains.kd)
                        for name, axis in machine.axes.items()},
        keep_alive_polls=_keep_alive_polls(config.watchdog_ms),
    )
    upward = {name for name, axis in machine.axes.items() if axis.config.homing.direction > 0}
    outputs = _Mirror(io, upward)

    def make(name: str) -> MoveAxisHome:
        homing = machine.axis(name).config.homing
        return MoveAxisHome(name, homing.speed_mm_s, slow_speed_mm_s=homing.slow_speed_mm_s,
                            backoff_mm=homing.backoff_mm)

    order = [list(group) for group in config.homing_order] or None
    sequence = Home(list(machine.axes), make, order=order)
    io.enter_velocity_mode()
    try:
        run_sequence(sequence, outputs, outputs, clock=clock, rate_hz=HOMING_POLL_HZ,
                     timeout_s=300.0, on_poll=lambda _: io.keep_alive())
    except UsbMotionError:
        machine.stop()
        raise
    for axis in machine.axes.values():
        client = axis.client
        client.set_control_mode(ControlMode.POSITION)
        gains = axis.config.gains
        client.set_gains(kp=gains.kp, ki=gains.ki, kd=gains.kd)
        client.set_position(axis.scale.to_counts(axis.config.homing.position_mm))
        client.set_servo_enable(True)
    return clock.now() - started


def trace_period_s(duration_s: float) -> float:
    """The diagnostics period of the trace of a program lasting ``duration_s``."""
    return max(DIAGNOSTICS_PERIOD_S, duration_s / TRACE_POINTS)


def _keep_alive_polls(watchdog_ms: int) -> int:
    """Homing polls between keep-alive queries: four within the watchdog, or one a second."""
    window_s = watchdog_ms / 1000.0 / 4 if watchdog_ms > 0 else 1.0
    return max(1, int(window_s * HOMING_POLL_HZ))


def run_program(
    machine: Machine,
    program: GCodeProgram,
    plan: Plan,
    *,
    home: bool = True,
    configure: bool = True,
    on_progress: Callable[[float, float], None] | None = None,
    should_stop: Callable[[], bool] | None = None,
) -> tuple[RunReport, Trace]:
    """Run a planned program on a connected machine; returns the report and the trace.

    ``on_progress(done_s, total_s)`` is called as setpoints are confirmed. With
    ``configure`` the machine's configuration is sent first; with ``home`` it is homed.
    A device fault stops every axis and is reported (``completed`` False, ``faults`` set);
    so is a ``should_stop`` that answers True (Ctrl-C): the report then says where the
    program was.
    """
    config = machine.config
    _, _, counts_per_mm = planner_inputs(config)
    period_s = config.motion_period_s
    setpoints = sample_plan(plan, period_s=period_s, counts_per_mm=counts_per_mm)
    if configure:
        machine.configure()
    homing_s = home_machine(machine) if home else 0.0
    if not home:
        for axis in machine.axes.values():
            axis.client.set_servo_enable(True)
    tick_s = config.servo_period_s
    diag_ticks = max(1, round(trace_period_s(plan.duration_s) / tick_s))
    trace = Trace(tick_s=tick_s, start_tick=0,
                  counts_per_mm={n: machine.axis(n).config.counts_per_mm for n in machine.axes})
    for name, axis in machine.axes.items():
        axis.client.on_diagnostics = trace.record(name)
    sync = machine.synchronise(margin_s=START_MARGIN_S, axes=PLAN_AXES)
    trace.start_tick = sync.devices[0].start_tick
    for name in PLAN_AXES:
        client = machine.axis(name).client
        client.reset_motion_stats()
        client.set_diagnostics_interval(diag_ticks)
    streams: dict[str, SetpointStream] = {}

    def progress(update: StreamProgress) -> None:
        if on_progress is not None:
            done = min(s.consumed_estimate for s in streams.values())
            on_progress(min(done * period_s, plan.duration_s), plan.duration_s)

    for index, name in enumerate(PLAN_AXES):
        streams[name] = SetpointStream(machine.axis(name).client, setpoints[:, index],
                                       period_s=period_s, verify=True, on_progress=progress)
    faults: list[FaultRecord] = []
    clock = machine.clock
    last_check = [clock.now(), clock.now()]

    def record(axis: str, fault: str, tick: int) -> None:
        if any(f.axis == axis for f in faults):
            return
        elapsed = (tick - trace.start_tick) * tick_s
        faults.append(FaultRecord(axis, fault, elapsed, _line_at(plan, elapsed)))

    def on_alarm(axis: str) -> Callable[[Alarm], None]:
        return lambda alarm: record(axis, alarm.fault_name, alarm.tick)

    for name, axis in machine.axes.items():
        axis.client.on_alarm = on_alarm(name)

    def check() -> bool:
        if should_stop is not None and should_stop():
            return True
        now = clock.now()
        if now - last_check[0] < FAULT_CHECK_S:
            return bool(faults)
        last_check[0] = now
        for axis in machine.axes.values():
            axis.client.read_pending()
        if now - last_check[1] >= STATUS_CHECK_S:
            last_check[1] = now
            for name, axis in machine.axes.items():
                status = axis.client.status()
                if status.fault != FaultCode.NONE:
                    _, fault_tick = axis.client.fault()
                    record(name, status.fault_name, fault_tick)
        return bool(faults)

    stopped = False
    link_error = ""
    lost_axis = ""
    try:
        run_streams(list(streams.values()), should_stop=check, max_wait_s=FAULT_CHECK_S)
        stopped = bool(faults) or (should_stop is not None and should_stop())
        if not stopped:
            wait_until_drained([machine.axis(n).client for n in PLAN_AXES], period_s=period_s,
                               should_stop=check)
            stopped = bool(faults) or (should_stop is not None and should_stop())
        if not stopped:
            _settle(machine, counts=SETTLE_COUNTS, timeout_s=1.0)
    except KeyboardInterrupt:
        stopped = True
    except (LinkLostError, LinkCorruptedError, DeviceTimeoutError) as error:
        stopped = True
        link_error = str(error)
        lost_axis = next((n for n in PLAN_AXES if machine.axis(n).client.name
                          == getattr(error, "device", None)), "")
    notes: list[str] = []
    if stopped:
        try:
            machine.stop()
        except UsbMotionError as error:
            notes.append(f"stopping: {error}")
    statuses: dict[str, Status] = {}
    stats: dict[str, MotionStats] = {}
    for name in PLAN_AXES:
        client = machine.axis(name).client
        try:
            statuses[name] = client.status()
            stats[name] = client.motion_stats()
            client.set_diagnostics_interval(0)
        except UsbMotionError as error:
            notes.append(f"axis {name}: {error}")
    for axis in machine.axes.values():
        axis.client.on_alarm = None
    if link_error:
        confirmed = streams[lost_axis].sent if lost_axis else min(
            s.sent for s in streams.values())
    else:
        confirmed = min(streams[n].sent - statuses[n].queued for n in PLAN_AXES)
    report = _report(
        program, machine, plan, setpoints.shape[0], trace, homing_s, statuses, stats,
        faults, completed=not stopped, consumed=confirmed, skew_s=sync.estimated_skew_s,
        link_error=link_error, notes=tuple(notes),
    )
    return report, trace


def _settle(machine: Machine, *, counts: int, timeout_s: float) -> None:
    clock = machine.clock
    deadline = clock.now() + timeout_s
    while clock.now() < deadline:
        statuses = machine.status()
        if all(abs(s.desired_counts - s.actual_counts) <= counts for s in statuses.values()):
            return
        clock.sleep(0.005)


def _line_at(plan: Plan, time_s: float) -> int:
    if len(plan) == 0:
        return 0
    index = int(np.searchsorted(plan.start_time_s, time_s, side="right")) - 1
    return int(plan.line[min(max(index, 0), len(plan) - 1)])


def _report(
    program: GCodeProgram,
    machine: Machine,
    plan: Plan,
    setpoint_count: int,
    trace: Trace,
    homing_s: float,
    statuses: Mapping[str, Status],
    stats: Mapping[str, MotionStats],
    faults: list[FaultRecord],
    *,
    completed: bool,
    consumed: int,
    skew_s: float,
    link_error: str = "",
    notes: tuple[str, ...] = (),
) -> RunReport:
    config = machine.config
    period_s = config.motion_period_s
    results: list[AxisResult] = []
    executed_s = 0.0
    settle_s = 0.0
    for name in PLAN_AXES:
        times, desired, actual = trace.arrays(name)
        in_run = times >= 0
        error = (desired - actual)[in_run]
        t_run = times[in_run]
        if error.size:
            late = np.nonzero(np.abs(error) > SETTLE_COUNTS)[0]
            settle_s = max(settle_s, float(t_run[late[-1]]) if late.size else 0.0)
        scale = machine.axis(name).config.counts_per_mm
        axis_stats = stats.get(name, MotionStats(0, 0, 0, 0, -1))
        if axis_stats.last_take_tick >= 0:
            executed_s = max(executed_s,
                             (axis_stats.last_take_tick - trace.start_tick) * trace.tick_s)
        peak_s = max(0.0, (axis_stats.max_error_tick - trace.start_tick) * trace.tick_s)
        status = statuses.get(name)
        results.append(AxisResult(
            name, axis_stats.max_error_counts, axis_stats.rms_error_counts,
            axis_stats.max_error_counts / scale, axis_stats.rms_error_counts / scale,
            status.desired_counts - status.actual_counts if status is not None else 0,
            int(error.size), ticks=axis_stats.ticks, max_error_time_s=peak_s,
            max_error_line=_line_at(plan, peak_s) if axis_stats.ticks else 0,
        ))
    end_positions = {
        name: machine.axis(name).scale.to_mm(status.actual_counts)
        for name, status in statuses.items()
    }
    stopped_time = consumed * period_s
    checked, miss = _endpoint_misses(program, trace) if completed else (0, 0.0)
    return RunReport(
        program=program.file,
        machine=config.name,
        moves=len(program.moves),
        setpoints_per_axis=setpoint_count,
        planned_time_s=plan.duration_s,
        executed_time_s=executed_s if completed else stopped_time,
        settle_time_s=max(settle_s, executed_s) if completed else stopped_time,
        homing_time_s=homing_s,
        axes=tuple(results),
        faults=tuple(faults),
        ignored_words=tuple(f"{w.word} (line {w.line})" for w in program.ignored),
        end_position_mm=end_positions,
        completed=completed and not faults,
        stopped_at_line=0 if completed else _line_at(plan, stopped_time),
        stopped_at_setpoint=0 if completed else consumed,
        skew_estimate_s=skew_s,
        endpoints_checked=checked,
        max_endpoint_miss_mm=miss,
        link_error=link_error,
        notes=notes,
    )


def _actual_path_mm(trace: Trace) -> npt.NDArray[np.float64]:
    """The actual XYZ positions (mm) at the diagnostics ticks all three axes reported."""
    clocks = [trace.column(trace.clock, n) for n in PLAN_AXES]
    common = clocks[0]
    for other in clocks[1:]:
        common = np.intersect1d(common, other)
    columns = []
    for name, clock in zip(PLAN_AXES, clocks, strict=True):
        actual = trace.column(trace.actual, name).astype(np.float64)
        index = np.searchsorted(clock, common)
        columns.append(actual[index] / trace.counts_per_mm[name])
    return np.stack(columns, axis=1) if common.size else np.empty((0, 3))


def _endpoint_misses(program: GCodeProgram, trace: Trace) -> tuple[int, float]:
    """How many programmed end points, and how far the actual path passed from the worst.

    The path is the polyline through the recorded positions: the distance to an end point
    is to the nearest point of a segment, not of a sample.
    """
    path = _actual_path_mm(trace)
    ends = np.array([m.end for m in program.moves if hasattr(m, "end")], dtype=np.float64)
    if not path.size or not ends.size:
        return 0, 0.0
    if path.shape[0] == 1:
        return int(ends.shape[0]), float(np.max(np.linalg.norm(ends - path[0], axis=1)))
    starts = path[:-1]
    spans = path[1:] - starts
    lengths_sq = np.einsum("ij,ij->i", spans, spans)
    longest = float(np.sqrt(lengths_sq.max()))
    last = len(starts) - 1
    worst = 0.0
    for end in ends:
        offsets = path - end
        dist_sq = np.einsum("ij,ij->i", offsets, offsets)
        # A segment can pass closer than its ends only if an end is within the nearest
        # sample's distance plus the longest segment: only those segments are measured.
        reach = float(np.sqrt(dist_sq.min())) + longest
        near = np.nonzero(dist_sq <= reach * reach)[0]
        index = np.unique(np.clip(np.concatenate((near - 1, near)), 0, last))
        seg_offsets = offsets[index]
        seg_spans = spans[index]
        seg_lengths = lengths_sq[index]
        along = np.zeros(len(index))
        moving = seg_lengths > 0
        along[moving] = np.clip(
            -np.einsum("ij,ij->i", seg_offsets[moving], seg_spans[moving]) / seg_lengths[moving],
            0.0, 1.0,
        )
        gaps = seg_offsets + along[:, None] * seg_spans
        worst = max(worst, float(np.sqrt(np.min(np.einsum("ij,ij->i", gaps, gaps)))))
    return int(ends.shape[0]), worst


def describe(report: RunReport) -> str:
    """The report as a few lines of text for a person."""
    lines = [
        f"program        {Path(report.program).name} ({report.moves} moves,"
        f" {report.setpoints_per_axis} setpoints per axis)",
        f"machine        {report.machine}",
        f"homing         {report.homing_time_s:.3f} s",
        f"planned time   {report.planned_time_s:.3f} s",
        f"executed time  {report.executed_time_s:.3f} s (settled at {report.settle_time_s:.3f} s)",
        "following error (every servo tick, desired - actual):",
    ]
    for axis in report.axes:
        lines.append(
            f"  {axis.name}  max {axis.max_error_mm:8.4f} mm ({axis.max_error_counts:5d} counts)"
            f" at {axis.max_error_time_s:.3f} s, line {axis.max_error_line}"
            f"   rms {axis.rms_error_mm:8.4f} mm ({axis.rms_error_counts:8.2f} counts)"
        )
    position = "  ".join(f"{k} {v:.3f}" for k, v in report.end_position_mm.items())
    lines.append(f"end position   {position} mm")
    if report.endpoints_checked:
        lines.append(f"end points     {report.endpoints_checked} programmed, the actual path passed"
                     f" within {report.max_endpoint_miss_mm:.4f} mm of each")
    lines.append("faults         " + ("; ".join(
        f"axis {f.axis}: {f.fault} at {f.time_s:.3f} s, line {f.line}" for f in report.faults
    ) or "none"))
    lines.append("ignored words  " + (", ".join(report.ignored_words) or "none"))
    if report.link_error:
        lines.append(f"LINK LOST      {report.link_error}")
    for note in report.notes:
        lines.append(f"note           {note}")
    if not report.completed:
        what = "last setpoint the device confirmed" if report.link_error else "setpoint"
        lines.append(f"STOPPED at program line {report.stopped_at_line}, {what}"
                     f" {report.stopped_at_setpoint} of {report.setpoints_per_axis}")
    return "\n".join(lines)
