"""One live model of the machine, fed by the devices, read by every front.

While anything moves the model is fed by every device's diagnostics lines (each carries the
device's clock, its commanded and measured position, and the peak following error of every
servo tick since the line before), at 50 lines a second or more; while homing by the
homing's status polls; at rest by the operator's idle reads. From the devices' clocks the
run says which program line the devices are executing now, how far the program is and what
is left. The console's ``?``, the progress line, the grbl status report, the reports and the
web dashboard all read this one model; none keeps its own copy of where the machine is.

One thread writes (whoever drives the machine); any thread reads, without waiting on the
writer: :meth:`LiveModel.read` returns the last published :class:`LiveSnapshot`, an
immutable value. A :class:`LiveReader` also keeps, per axis, the peak following error of
every servo tick between two of its reads.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace

import numpy as np
import numpy.typing as npt

from usbmotion.host.spindle import SpindleNow
from usbmotion.session.state import MachineState

PEAK_LINES = 4096
"""Diagnostics lines per axis whose peak following error a reader can still see (about 80 s
at 50 lines a second); a reader that reads less often gets the peak of these."""
PUBLISH_S = 0.01
"""The shortest wall-clock time between two snapshots a run publishes on its own."""


@dataclass(frozen=True, slots=True)
class AxisNow:
    """One axis now.

    Fields:
        commanded_mm: where the device is told to be (machine coordinates once homed).
        measured_mm: where its encoder is.
        commanded_velocity_mm_s, measured_velocity_mm_s: between its last two diagnostics
            lines (0 at rest).
        following_error_mm: commanded minus measured, the device's sign.
        peak_error_mm: the following error of the largest size over every servo tick since
            the reader's last read (:class:`LiveReader`), or at the last line.
        limit: a limit switch reads closed.
        fault: the device's fault code (0: none).
        tick: the device clock of the values.
    """

    commanded_mm: float = 0.0
    measured_mm: float = 0.0
    commanded_velocity_mm_s: float = 0.0
    measured_velocity_mm_s: float = 0.0
    following_error_mm: float = 0.0
    peak_error_mm: float = 0.0
    limit: bool = False
    fault: int = 0
    tick: int = 0


@dataclass(frozen=True, slots=True)
class LiveSnapshot:
    """The machine at one moment (see the module docstring).

    Fields:
        state: the machine's state; ``at_rest``: every axis at rest (Hold:0 against Hold:1);
            ``hold_pending``: a feed hold was asked and no resume released it yet (asked
            while idle, it holds the next motion, as grbl latches it).
        axes: axis -> :class:`AxisNow`.
        homed: every axis is homed.
        program: the program running or last run ("" none); ``line`` the line its devices
            are executing now (0: none), ``lines_done`` / ``lines_total`` progress by
            executed line: the lines before the one executing, every line once the
            devices executed the last setpoint (a fed program's total grows as its lines
            come).
        done_s, total_s: program time done and planned (at the overrides now), s;
            ``eta_s`` what is left, s (0 at rest).
        feed_mm_min: the path speed the encoders measure, mm/min.
        feed_override, rapid_override: percent.
        work_offset_mm: axis -> the work offset in effect (work = machine - offset).
        coordinate_system: 1 (G54) .. 9 (G59.3).
        tool: the tool in the spindle (0: none); ``tool_length_mm`` its offset along Z.
        pause: the message of the program pause the machine waits at ("" none).
        alarm: what the last fault was, in words, with its axis and line ("" none).
        tool_changes: every tool change the program made so far, in words.
        spindle: the spindle as its encoder last said (None: the machine has none).
        probe: the probe input read closed (any device's: the probe line is one), as last
            read at rest.
        outputs: each coolant and laser output's value (``flood``, ``mist``, ``laser``; per
            mille of full), on the devices' last tick.
        sequence: counts the snapshots published; ``updated_s`` when (monotonic wall time).
    """

    state: MachineState = MachineState.IDLE
    at_rest: bool = True
    hold_pending: bool = False
    axes: Mapping[str, AxisNow] = field(default_factory=dict)
    homed: bool = False
    program: str = ""
    line: int = 0
    lines_done: int = 0
    lines_total: int = 0
    done_s: float = 0.0
    total_s: float = 0.0
    eta_s: float = 0.0
    feed_mm_min: float = 0.0
    feed_override: int = 100
    rapid_override: int = 100
    work_offset_mm: Mapping[str, float] = field(default_factory=dict)
    coordinate_system: int = 1
    tool: int = 0
    tool_length_mm: float = 0.0
    pause: str = ""
    alarm: str = ""
    tool_changes: tuple[str, ...] = ()
    spindle: SpindleNow | None = None
    probe: bool = False
    outputs: Mapping[str, int] = field(default_factory=dict)
    sequence: int = 0
    updated_s: float = 0.0

    def machine_mm(self, *, measured: bool = True) -> dict[str, float]:
        """Axis -> machine position (the encoders', or the commanded), mm."""
        return {name: axis.measured_mm if measured else axis.commanded_mm
                for name, axis in self.axes.items()}

    def work_mm(self, *, measured: bool = True) -> dict[str, float]:
        """Axis -> work position (machine minus the work offset), mm."""
        return {name: value - self.work_offset_mm.get(name, 0.0)
                for name, value in self.machine_mm(measured=measured).items()}

    def describe(self) -> str:
        """One line: ``Run  line 12 of 40  X 10.000  Y 5.000  Z 1.000 mm`` (the encoders)."""
        parts = [self.state.value]
        if self.line:
            total = f" of {self.lines_total}" if self.lines_total else ""
            parts.append(f"line {self.line}{total}")
        if self.axes:
            parts.append("  ".join(f"{name} {axis.measured_mm:.3f}"
                                   for name, axis in self.axes.items()) + " mm")
        return "  ".join(parts)


@dataclass(frozen=True, slots=True)
class AxisScale:
    """How an axis's counts read in mm (and whether it moves the tool along the path)."""

    counts_per_mm: float
    linear: bool = True


class _Axis:
    """What the writer keeps of one axis between snapshots."""

    __slots__ = ("actual", "clock", "desired", "fault", "limit", "peak", "peaks",
                 "run_peak", "run_peak_clock", "v_actual", "v_desired")

    def __init__(self) -> None:
        self.clock = -1
        self.desired = 0
        self.actual = 0
        self.peak = 0
        self.v_desired = 0.0
        self.v_actual = 0.0
        self.limit = False
        self.fault = 0
        self.peaks: npt.NDArray[np.int64] = np.zeros(PEAK_LINES, dtype=np.int64)
        self.run_peak = 0
        self.run_peak_clock = 0


class LiveModel:
    """The live model (see the module docstring).

    Parameters:
        axes: axis -> its scale, in the machine's order.
        tick_s: the devices' servo period, s.
    """

    def __init__(self, axes: Mapping[str, AxisScale], *, tick_s: float) -> None:
        self.scales = dict(axes)
        self.tick_s = tick_s
        self._axes = {name: _Axis() for name in axes}
        self._lines = 0
        """Diagnostics lines taken (the peaks' ring counts by it)."""
        self._counts = dict.fromkeys(axes, 0)
        self._lock = threading.Lock()
        self._snapshot = LiveSnapshot(axes={name: AxisNow() for name in axes})
        self._published_s = 0.0
        self.on_publish: list[Callable[[LiveSnapshot], None]] = []
        """Called with every snapshot published, on the writer's thread."""

    # --- reading (any thread) -------------------------------------------------------------

    def read(self) -> LiveSnapshot:
        """The last snapshot published (never waits on the writer)."""
        return self._snapshot

    def reader(self) -> LiveReader:
        """A reader that keeps each axis's peak following error between its reads."""
        return LiveReader(self)

    def peaks_since(self, counts: Mapping[str, int]) -> tuple[dict[str, int], dict[str, int]]:
        """Per axis, the peak (signed, counts) of the lines taken since ``counts``, and the
        counts now (lines per axis)."""
        peaks: dict[str, int] = {}
        with self._lock:
            now = dict(self._counts)
            for name, axis in self._axes.items():
                new = now[name] - counts.get(name, now[name])
                if new <= 0:
                    peaks[name] = axis.peak
                    continue
                new = min(new, PEAK_LINES)
                end = now[name] % PEAK_LINES
                start = end - new
                values = (np.concatenate((axis.peaks[start:], axis.peaks[:end])) if start < 0
                          else axis.peaks[start:end])
                peaks[name] = int(values[int(np.argmax(np.abs(values)))])
        return peaks, now

    # --- writing (the thread that drives the machine) -------------------------------------

    def take_line(self, axis: str, clock: int, desired: int, actual: int,
                  peak: int | None = None) -> None:
        """One diagnostics line of ``axis``: its device clock, commanded and measured
        position (counts) and the peak following error since its line before (counts;
        None: the line carries none, the error at this tick stands for it)."""
        state = self._axes[axis]
        if peak is None:
            peak = desired - actual
        if state.clock >= 0 and clock > state.clock:
            span_s = (clock - state.clock) * self.tick_s
            state.v_desired = (desired - state.desired) / span_s
            state.v_actual = (actual - state.actual) / span_s
        state.clock, state.desired, state.actual, state.peak = clock, desired, actual, peak
        if abs(peak) > abs(state.run_peak):
            state.run_peak, state.run_peak_clock = peak, clock
        with self._lock:
            count = self._counts[axis]
            state.peaks[count % PEAK_LINES] = peak
            self._counts[axis] = count + 1

    def take_lines(self, axis: str, clock: npt.NDArray[np.int64],
                   desired: npt.NDArray[np.int64], actual: npt.NDArray[np.int64],
                   peak: npt.NDArray[np.int64]) -> None:
        """Diagnostics lines of ``axis``, oldest first, one value per line in each array:
        what :meth:`take_line` on each line in turn leaves."""
        count = int(clock.size)
        if not count:
            return
        state = self._axes[axis]
        before = np.empty(count, dtype=np.int64)
        before[0] = state.clock
        before[1:] = clock[:-1]
        moved = np.flatnonzero((before >= 0) & (clock > before))
        if moved.size:  # the velocities of the last line that came after the one before it
            last = int(moved[-1])
            span_s = (int(clock[last]) - int(before[last])) * self.tick_s
            was_desired = int(desired[last - 1]) if last else state.desired
            was_actual = int(actual[last - 1]) if last else state.actual
            state.v_desired = (int(desired[last]) - was_desired) / span_s
            state.v_actual = (int(actual[last]) - was_actual) / span_s
        state.clock, state.desired = int(clock[-1]), int(desired[-1])
        state.actual, state.peak = int(actual[-1]), int(peak[-1])
        magnitude = np.abs(peak)
        top = int(np.argmax(magnitude))
        if int(magnitude[top]) > abs(state.run_peak):
            state.run_peak, state.run_peak_clock = int(peak[top]), int(clock[top])
        kept = min(count, PEAK_LINES)
        with self._lock:
            taken = self._counts[axis]
            first = (taken + count - kept) % PEAK_LINES
            end = min(first + kept, PEAK_LINES)  # the ring's end, and its start after it
            state.peaks[first:end] = peak[count - kept:count - kept + end - first]
            state.peaks[:kept - (end - first)] = peak[count - kept + end - first:]
            self._counts[axis] = taken + count

    def take_status(self, axis: str, *, clock: int, desired: int, actual: int,
                    limit: bool = False, fault: int = 0, moving: bool = False) -> None:
        """An axis's status as read (homing's polls, reads at rest); at rest its velocity
        is 0 unless ``moving``."""
        state = self._axes[axis]
        if moving and state.clock >= 0 and clock > state.clock:
            span_s = (clock - state.clock) * self.tick_s
            state.v_desired = (desired - state.desired) / span_s
            state.v_actual = (actual - state.actual) / span_s
        elif not moving:
            state.v_desired = state.v_actual = 0.0
        state.clock, state.desired, state.actual = clock, desired, actual
        state.peak = desired - actual
        state.limit, state.fault = limit, fault

    def new_clocks(self) -> None:
        """The devices' clocks were zeroed (a run's start): the lines before count no
        more for velocities and ticks."""
        for state in self._axes.values():
            state.clock = -1
            state.run_peak = state.run_peak_clock = 0

    def ticks(self, names: Sequence[str]) -> list[int]:
        """The device clock of each named axis's last line (those with one since the
        clocks were zeroed)."""
        return [self._axes[name].clock for name in names if self._axes[name].clock >= 0]

    def heard(self, name: str) -> tuple[int, int, int]:
        """An axis as last heard since the clocks were zeroed: its measured position
        (counts), the largest following error its lines carried and that line's clock."""
        state = self._axes[name]
        return state.actual, state.run_peak, state.run_peak_clock

    def due(self) -> bool:
        """Whether :data:`PUBLISH_S` has passed since the last snapshot."""
        return time.monotonic() - self._published_s >= PUBLISH_S

    def publish(self, **fields: object) -> LiveSnapshot:
        """A new snapshot: the axes as taken, and ``fields`` (any of
        :class:`LiveSnapshot`'s) changed from the last one."""
        axes: dict[str, AxisNow] = {}
        path_sq = 0.0
        for name, state in self._axes.items():
            scale = self.scales[name].counts_per_mm
            measured_v = state.v_actual / scale
            axes[name] = AxisNow(
                commanded_mm=state.desired / scale, measured_mm=state.actual / scale,
                commanded_velocity_mm_s=state.v_desired / scale,
                measured_velocity_mm_s=measured_v,
                following_error_mm=(state.desired - state.actual) / scale,
                peak_error_mm=state.peak / scale, limit=state.limit, fault=state.fault,
                tick=max(state.clock, 0))
            if self.scales[name].linear:
                path_sq += measured_v * measured_v
        old = self._snapshot
        now = time.monotonic()
        snapshot = replace(old, axes=axes, feed_mm_min=math.sqrt(path_sq) * 60.0,
                           sequence=old.sequence + 1, updated_s=now, **fields)  # type: ignore[arg-type]
        self._snapshot = snapshot
        self._published_s = now
        for listener in list(self.on_publish):
            listener(snapshot)
        return snapshot


class LiveReader:
    """Reads a :class:`LiveModel`, each read's ``peak_error_mm`` the peak of every servo
    tick since this reader's read before (the first read: since the model began)."""

    def __init__(self, model: LiveModel) -> None:
        self.model = model
        self._counts: dict[str, int] = dict.fromkeys(model.scales, 0)

    def read(self) -> LiveSnapshot:
        """The last snapshot, each axis's peak error since this reader's last read."""
        snapshot = self.model.read()
        peaks, self._counts = self.model.peaks_since(self._counts)
        axes = {name: replace(axis, peak_error_mm=peaks[name]
                              / self.model.scales[name].counts_per_mm)
                for name, axis in snapshot.axes.items() if name in peaks}
        return replace(snapshot, axes=axes)


def scales_of(names: Sequence[str], counts_per_mm: Callable[[str], float]) -> dict[str, AxisScale]:
    """The scales of the named axes."""
    return {name: AxisScale(counts_per_mm(name)) for name in names}
