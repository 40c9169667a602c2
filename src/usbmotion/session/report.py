"""What a run says about itself: the report (figures, faults, why it stopped, the G-code
words it ignored) and the trace of the devices' own diagnostics, for plots. Its text for a
person is :mod:`usbmotion.session.report_text`'s."""

from __future__ import annotations

from array import array
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from usbmotion.host.device import Diagnostics, DiagnosticsBlock, MotionStats, Status
from usbmotion.host.machine import Machine
from usbmotion.motion.gcode import GCodeProgram, IgnoredWord, distinct_ignored
from usbmotion.motion.planner import Plan

SETTLE_COUNTS = 2

SegmentsAt = Callable[[npt.NDArray[np.int64]], npt.NDArray[np.int64]]
"""Device ticks -> the plan segment the devices execute at each."""


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
class LinePeak:
    """The largest following error of each program axis while a program line executed,
    counts (magnitudes).

    From the devices' diagnostics lines: each carries the peak of every servo tick since
    the line before (call 21's ``peak``), and that peak counts for every program line the
    ticks between the two executed, so a line's figure is exact where a diagnostics period
    falls within it and an upper bound where the period spans the line's ends (the period
    is the trace's: 10 ms for a program under 100 s).
    """

    line: int
    peak_error_counts: Mapping[str, int]


@dataclass(frozen=True, slots=True)
class FaultRecord:
    """A fault seen during the run: which axis, what (in words, and the device's fault
    code), when, and at which program line."""

    axis: str
    fault: str
    time_s: float
    line: int
    code: int = 0


@dataclass(frozen=True, slots=True)
class IgnoredWordRecord:
    """A kind of G-code word the run accepted without acting on it: the word as first
    written, its line, what it is for (spindle, coolant, ...) and how many times the
    program holds one of its kind (every ``E`` word is one kind, each M code another)."""

    word: str
    line: int
    meaning: str
    count: int = 1

    @classmethod
    def of(cls, word: IgnoredWord, count: int = 1) -> IgnoredWordRecord:
        """The record of an interpreter's ignored word."""
        return cls(word.word, word.line, word.meaning, count)

    @classmethod
    def all_of(cls, program: GCodeProgram) -> tuple[IgnoredWordRecord, ...]:
        """One record per kind of word the program ignored, in the order of first use."""
        return tuple(cls.of(word, count) for word, count in distinct_ignored(program.ignored))


@dataclass(frozen=True, slots=True)
class ToolChangeRecord:
    """A tool change the program made: its line, the tool put in the spindle and its pocket
    in the tool table (0: none), and whether it was a manual change (M6) or only said which
    tool is in the spindle (M61)."""

    line: int
    tool: int
    pocket: int
    manual: bool = True

    @classmethod
    def all_of(cls, program: GCodeProgram) -> tuple[ToolChangeRecord, ...]:
        """The program's tool changes, in order."""
        return tuple(cls(c.line, c.tool, c.pocket, c.manual) for c in program.tool_changes)


@dataclass(frozen=True, slots=True)
class OutputRecord:
    """What the run did with one output (``flood``, ``mist``, ``laser``): how many
    changes its device was told, the largest value and the value it was left at (per
    mille of full)."""

    name: str
    changes: int
    max_value: int
    last_value: int


@dataclass(frozen=True, slots=True)
class SpindleRecord:
    """A spindle pause of the run: its line, the speed asked (rpm, signed: - for M4), how
    long the program waited at rest for the spindle to reach it (s), and the speed its
    encoder measured when the program went on (rpm)."""

    line: int
    rpm: float
    waited_s: float
    measured_rpm: float


@dataclass(frozen=True, slots=True)
class RunReport:
    """The figures of one run.

    ``stop_reason`` says why the run ended, in words: ``completed``, ``interrupted by the
    user``, ``terminated (SIGTERM)``, ``fault: axis X following error``, ``link lost: ...``;
    ``completed`` is True only for the first. ``stopped_at_s`` is the program time at which
    motion ended (the planned time for a completed run). A stopped run says how it
    stopped: ``stop_distance_mm`` from the commanded position where the stop began to where
    the axes came to rest (measured: their encoders), ``stop_planned_mm`` the planned
    deceleration's ``v^2 / 2a`` from the speed there, and ``stop_latency_s`` from the stop
    request (or the fault seen) to every axis at rest (0 when the run completed).
    ``stop_late_s`` is how long after its planned device tick the stop reached the latest
    device (the host or the link held up; 0 on time): the axes ran on along the path that
    long, then decelerated in full, and ``stop_distance_mm`` includes the run-on.
    """

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
    ignored_words: tuple[IgnoredWordRecord, ...]
    end_position_mm: Mapping[str, float]
    completed: bool
    stop_reason: str = "completed"
    stopped_at_s: float = 0.0
    stopped_at_line: int = 0
    stopped_at_setpoint: int = 0
    stop_distance_mm: float = 0.0
    stop_planned_mm: float = 0.0
    stop_latency_s: float = 0.0
    stop_late_s: float = 0.0
    skew_estimate_s: float = 0.0
    endpoints_checked: int = 0
    max_endpoint_miss_mm: float = 0.0
    link_error: str = ""
    notes: tuple[str, ...] = ()
    tool_changes: tuple[ToolChangeRecord, ...] = ()
    line_peaks: tuple[LinePeak, ...] = ()
    spindle: tuple[SpindleRecord, ...] = ()
    outputs: tuple[OutputRecord, ...] = ()

    def to_json(self) -> dict[str, Any]:
        """The report as plain JSON-ready data."""
        data = asdict(self)
        data["end_position_mm"] = dict(self.end_position_mm)
        data["line_peaks"] = [{"line": peak.line,
                               "peak_error_counts": dict(peak.peak_error_counts)}
                              for peak in self.line_peaks]
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
    peak: dict[str, array[int]] = field(default_factory=dict)
    """The magnitude of the largest following error of the ticks since the line kept before
    (the devices' own peak, over every tick their statistics counted), counts."""
    counts_per_mm: dict[str, float] = field(default_factory=dict)

    def record(self, axis: str) -> Callable[[Diagnostics, int], None]:
        """A callback that appends one diagnostics line of ``axis`` to this trace, with the
        largest following error magnitude since the line kept before."""
        stores = (self.clock, self.desired, self.actual, self.queued, self.peak)
        for store in stores:
            store.setdefault(axis, array("q"))
        clock, desired, actual, queued, peak = (store[axis] for store in stores)

        def on_line(line: Diagnostics, peak_counts: int) -> None:
            clock.append(line.clock)
            desired.append(line.desired)
            actual.append(line.actual_counts)
            queued.append(line.queued)
            peak.append(peak_counts)

        return on_line

    def extend(self, axis: str, lines: DiagnosticsBlock, peak: npt.NDArray[np.int64]) -> None:
        """Append diagnostics lines of ``axis`` to this trace, with the largest following
        error magnitude since the line kept before each (``peak``, one per line)."""
        for store, values in ((self.clock, lines.clock), (self.desired, lines.desired),
                              (self.actual, lines.actual_counts), (self.queued, lines.queued),
                              (self.peak, peak)):
            store.setdefault(axis, array("q")).frombytes(
                np.ascontiguousarray(values, dtype=np.int64).tobytes())

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


def line_peaks(plan: Plan, trace: Trace,
               segments_at_ticks: SegmentsAt) -> tuple[LinePeak, ...]:
    """Each program line's largest following error per axis (:class:`LinePeak`), in line
    order, from the trace's diagnostics lines; ``segments_at_ticks`` gives the plan segment
    the devices execute at each of an array of device ticks."""
    if not len(plan):
        return ()
    peaks: dict[str, npt.NDArray[np.int64]] = {}
    touched = np.zeros(len(plan), dtype=bool)
    for name in plan.axes:
        clock = trace.column(trace.clock, name)
        peak = trace.column(trace.peak, name)
        if not clock.size:
            continue
        low = segments_at_ticks(np.concatenate((clock[:1], clock[:-1] + 1)))
        high = segments_at_ticks(clock)
        lengths = np.maximum(high, low) - low + 1
        begins = np.cumsum(lengths) - lengths
        index = (np.arange(int(lengths.sum()), dtype=np.int64) - np.repeat(begins, lengths)
                 + np.repeat(low, lengths))
        by_segment = np.zeros(len(plan), dtype=np.int64)
        np.maximum.at(by_segment, index, np.repeat(np.abs(peak), lengths))
        touched[index] = True
        peaks[name] = by_segment
    if not peaks:
        return ()
    lines, inverse = _unique(plan.line[touched])
    by_line: dict[str, list[int]] = {}
    for name, by_segment in peaks.items():
        most = np.zeros(lines.size, dtype=np.int64)
        np.maximum.at(most, inverse, by_segment[touched])
        by_line[name] = most.tolist()
    return tuple(LinePeak(int(line), {name: values[i] for name, values in by_line.items()})
                 for i, line in enumerate(lines.tolist()))


def _unique(values: npt.NDArray[np.int64]) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.intp]]:
    """``numpy.unique(values, return_inverse=True)`` of a 1-D integer array, without
    ``numpy.unique``'s import of ``numpy.ma`` (10 ms of a command's start)."""
    order = np.argsort(values, kind="stable")
    ordered = values[order]
    first = np.empty(ordered.size, dtype=bool)
    first[:1] = True
    np.not_equal(ordered[1:], ordered[:-1], out=first[1:])
    inverse = np.empty(values.size, dtype=np.intp)
    inverse[order] = np.cumsum(first) - 1
    return ordered[first], inverse


def _intersection(first: npt.NDArray[np.int64],
                  second: npt.NDArray[np.int64]) -> npt.NDArray[np.int64]:
    """``numpy.intersect1d(first, second)`` of 1-D integer arrays (the sorted values in
    both), without importing ``numpy.ma`` (:func:`_unique`)."""
    ours, theirs = _unique(first)[0], _unique(second)[0]
    if not theirs.size:
        return theirs
    at = np.minimum(np.searchsorted(theirs, ours), theirs.size - 1)
    both: npt.NDArray[np.int64] = ours[theirs[at] == ours]
    return both


def line_at(plan: Plan, time_s: float) -> int:
    """The G-code line being executed at ``time_s`` into the plan."""
    if len(plan) == 0:
        return 0
    index = int(np.searchsorted(plan.start_time_s, time_s, side="right")) - 1
    return int(plan.line[min(max(index, 0), len(plan) - 1)])


@dataclass(frozen=True, slots=True)
class RunEnding:
    """How a run ended, for its report.

    Fields:
        reason: why, in the report's words (``completed``, ``fault: ...``, ...).
        completed: it ran to its end.
        rows_executed: setpoints of every axis the devices are known to have executed
            (every leg since the start); ``rows_total`` those streamed.
        stopped_at_s: where on the program it stopped (program time, s); ``stopped_at_line``
            the line there.
        stop_distance_mm, stop_planned_mm, stop_latency_s, stop_late_s: a stop's figures.
        skew_s: the start's estimated skew between axes.
        link_error: the lost link's error ("" none).
        notes: what else the report says.
    """

    reason: str
    completed: bool
    rows_executed: int
    rows_total: int
    stopped_at_s: float = 0.0
    stopped_at_line: int = 0
    stop_distance_mm: float = 0.0
    stop_planned_mm: float = 0.0
    stop_latency_s: float = 0.0
    stop_late_s: float = 0.0
    skew_s: float = 0.0
    link_error: str = ""
    notes: tuple[str, ...] = ()


@dataclass(frozen=True, slots=True)
class LastHeard:
    """What the run last heard of an axis whose device no longer answers: its encoder's
    position (mm) and the largest following error its diagnostics lines carried (counts)
    and when (s since the start)."""

    position_mm: float
    peak_error_counts: int
    peak_s: float


def build_report(
    program: GCodeProgram,
    machine: Machine,
    plan: Plan,
    trace: Trace,
    homing_s: float,
    statuses: Mapping[str, Status],
    stats: Mapping[str, MotionStats],
    faults: list[FaultRecord],
    ending: RunEnding,
    *,
    line_at_tick: Callable[[int], int],
    last_heard: Mapping[str, LastHeard] | None = None,
    segments_at_ticks: SegmentsAt | None = None,
) -> RunReport:
    """The report of a run from what the devices said at its end (an axis that said
    nothing more: from what was last heard of it, and a note says so); with
    ``segment_at_tick`` (the plan segment executing at a device tick), each line's peak
    following error (:func:`line_peaks`)."""
    config = machine.config
    period_s = config.motion_period_s
    heard = last_heard or {}
    results: list[AxisResult] = []
    notes = list(ending.notes)
    executed_s = 0.0
    settle_s = 0.0
    axes = plan.axes
    for name in axes:
        times, desired, actual = trace.arrays(name)
        in_run = times >= 0
        error = (desired - actual)[in_run]
        t_run = times[in_run]
        if error.size:
            late = np.nonzero(np.abs(error) > SETTLE_COUNTS)[0]
            settle_s = max(settle_s, float(t_run[late[-1]]) if late.size else 0.0)
        scale = machine.axis(name).config.counts_per_mm
        status = statuses.get(name)
        final = status.desired_counts - status.actual_counts if status is not None else 0
        axis_stats = stats.get(name)
        if axis_stats is None:
            last = heard.get(name)
            peak = abs(last.peak_error_counts) if last is not None else 0
            rms = float(np.sqrt(np.mean(error.astype(np.float64) ** 2))) if error.size else 0.0
            peak_s = last.peak_s if last is not None else 0.0
            notes.append(f"axis {name}: its device's statistics could not be read: its"
                         f" following error is from its diagnostics lines ({error.size}"
                         " kept), as last heard")
            results.append(AxisResult(
                name, peak, rms, peak / scale, rms / scale, final, int(error.size),
                ticks=0, max_error_time_s=peak_s,
                max_error_line=line_at_tick(trace.start_tick + round(peak_s / trace.tick_s))))
            continue
        if axis_stats.last_take_tick >= 0:
            executed_s = max(executed_s,
                             (axis_stats.last_take_tick - trace.start_tick) * trace.tick_s)
        peak_s = max(0.0, (axis_stats.max_error_tick - trace.start_tick) * trace.tick_s)
        results.append(AxisResult(
            name, axis_stats.max_error_counts, axis_stats.rms_error_counts,
            axis_stats.max_error_counts / scale, axis_stats.rms_error_counts / scale,
            final, int(error.size), ticks=axis_stats.ticks, max_error_time_s=peak_s,
            max_error_line=line_at_tick(axis_stats.max_error_tick) if axis_stats.ticks else 0,
        ))
    for name in axes:
        stepper = machine.axis(name).config.stepper
        if stepper is not None:
            notes.append(
                f"axis {name}: a stepper, counting microsteps; " + (
                    "closed loop: its following error is its encoder's" if stepper.closed
                    else "open loop: its position is the steps issued, so its following error"
                    " is only what the step rate could not follow (a step the motor lost shows"
                    " at the next homing)"))
    end_positions = {name: machine.axis(name).scale.to_mm(status.actual_counts)
                     for name, status in statuses.items()}
    for name, last in heard.items():
        if name not in end_positions:
            end_positions[name] = last.position_mm
    completed = ending.completed
    executed_rows_s = ending.rows_executed * period_s
    checked, miss = _endpoint_misses(program, trace, axes) if completed else (0, 0.0)
    return RunReport(
        program=program.file,
        machine=config.name,
        moves=len(program.moves),
        setpoints_per_axis=ending.rows_total,
        planned_time_s=plan.duration_s,
        executed_time_s=executed_s if completed else executed_rows_s,
        settle_time_s=max(settle_s, executed_s) if completed else executed_rows_s,
        homing_time_s=homing_s,
        axes=tuple(results),
        faults=tuple(faults),
        ignored_words=IgnoredWordRecord.all_of(program),
        end_position_mm=end_positions,
        completed=completed and not faults,
        stop_reason=ending.reason,
        stopped_at_s=plan.duration_s if completed else ending.stopped_at_s,
        stop_distance_mm=ending.stop_distance_mm,
        stop_planned_mm=ending.stop_planned_mm,
        stop_latency_s=ending.stop_latency_s,
        stop_late_s=ending.stop_late_s,
        stopped_at_line=0 if completed else ending.stopped_at_line,
        stopped_at_setpoint=0 if completed else ending.rows_executed,
        skew_estimate_s=ending.skew_s,
        endpoints_checked=checked,
        max_endpoint_miss_mm=miss,
        link_error=ending.link_error,
        notes=tuple(notes),
        tool_changes=ToolChangeRecord.all_of(program),
        line_peaks=(line_peaks(plan, trace, segments_at_ticks)
                    if segments_at_ticks is not None else ()),
    )


def _actual_path_mm(trace: Trace, axes: str) -> npt.NDArray[np.float64]:
    """The actual positions (mm) of the program axes at the diagnostics ticks all of them
    reported."""
    clocks = [trace.column(trace.clock, n) for n in axes]
    common = clocks[0]
    for other in clocks[1:]:
        common = _intersection(common, other)
    columns = []
    for name, clock in zip(axes, clocks, strict=True):
        actual = trace.column(trace.actual, name).astype(np.float64)
        index = np.searchsorted(clock, common)
        columns.append(actual[index] / trace.counts_per_mm[name])
    return np.stack(columns, axis=1) if common.size else np.empty((0, len(axes)))


_ENDS_AT_ONCE = 8
"""End points measured against every sample in one product of matrices (their number
times the samples: kept within the processor's cache)."""


def _endpoint_misses(program: GCodeProgram, trace: Trace, axes: str) -> tuple[int, float]:
    """How many programmed end points, and how far the actual path passed from the worst.

    The path is the polyline through the recorded positions: the distance to an end point
    is to the nearest point of a segment, not of a sample.
    """
    path = _actual_path_mm(trace, axes)
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
    # The path passes no farther from an end point than its nearest sample. Those distances,
    # squared, come for every end point at once from |p|^2 - 2 p.e + |e|^2 (a product of
    # matrices; its rounding is far below ``slack``): the end points are measured farthest
    # sample first, and one whose nearest sample is closer than the worst miss found so far
    # cannot be the worst.
    path_sq = np.einsum("ij,ij->i", path, path)
    ends_sq = np.einsum("ij,ij->i", ends, ends)
    across = np.ascontiguousarray(path.T)
    nearest_sq = np.empty(len(ends))
    for first in range(0, len(ends), _ENDS_AT_ONCE):
        product = ends[first : first + _ENDS_AT_ONCE] @ across
        product *= -2.0
        product += path_sq
        nearest_sq[first : first + _ENDS_AT_ONCE] = product.min(axis=1)
    nearest_sq += ends_sq
    slack = 1e-9 * (float(path_sq.max()) + float(ends_sq.max()) + 1.0)
    worst = 0.0
    for index_of_end in np.argsort(-nearest_sq, kind="stable"):
        if nearest_sq[index_of_end] + slack < worst * worst:
            break
        end = ends[index_of_end]
        offsets = path - end
        dist_sq = np.einsum("ij,ij->i", offsets, offsets)
        # A segment can pass closer than its ends only if an end is within the nearest
        # sample's distance plus the longest segment: only those segments are measured.
        reach = float(np.sqrt(dist_sq.min())) + longest
        near = np.nonzero(dist_sq <= reach * reach)[0]
        index = _unique(np.clip(np.concatenate((near - 1, near)), 0, last))[0]
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


def unstarted_report(program: GCodeProgram, machine_name: str, plan: Plan, *,
                     setpoints_per_axis: int, homing_s: float, stop_reason: str,
                     end_position_mm: Mapping[str, float], stop_latency_s: float = 0.0,
                     notes: tuple[str, ...] = ()) -> RunReport:
    """The report of a run that ended before its program started (homing stopped or
    failed): nothing of the program ran."""
    return RunReport(
        program=program.file, machine=machine_name, moves=len(program.moves),
        setpoints_per_axis=setpoints_per_axis, planned_time_s=plan.duration_s,
        executed_time_s=0.0, settle_time_s=0.0, homing_time_s=homing_s, axes=(), faults=(),
        ignored_words=IgnoredWordRecord.all_of(program),
        end_position_mm=dict(end_position_mm), completed=False, stop_reason=stop_reason,
        stopped_at_s=0.0, stopped_at_line=0, stopped_at_setpoint=0,
        stop_latency_s=stop_latency_s, notes=notes,
        tool_changes=ToolChangeRecord.all_of(program))
