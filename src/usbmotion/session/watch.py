"""What a run hears from the devices while it runs: their diagnostics lines (into the live
model, and every so many into the trace the report and the plot use) and their alarms (the
run's faults), read without a round trip at least every :data:`FAULT_CHECK_S`, and every
device's status every :data:`STATUS_CHECK_S` in case an alarm line was lost.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from contextlib import ExitStack
from functools import partial

import numpy as np

from usbmotion.host.device import Alarm, DiagnosticsBlock
from usbmotion.host.machine import Machine
from usbmotion.protocol import FEW_DIAGNOSTICS, FaultCode, fault_words
from usbmotion.session.live import LiveModel
from usbmotion.session.report import FaultRecord, Trace

DIAGNOSTICS_PERIOD_S = 0.01
"""The shortest period of the diagnostics lines of the trace (plots, end points, settling):
the peak and RMS error come from the devices' own statistics (call 35), so the trace need
not be dense."""
TRACE_POINTS = 10_000
"""The most diagnostics lines per axis the trace aims at: a longer program gets a sparser
trace (10 minutes, one line every 60 ms; an hour, every 0.36 s)."""
LIVE_PERIOD_S = 0.02
"""The longest period of the diagnostics lines while a front shows the machine live (the
live model is updated 50 times a second or more while anything moves)."""
FAULT_CHECK_S = 0.05
"""The longest a run goes without reading the alarms the devices printed (no exchange:
lines that came); it reads them whenever it wakes, at least this often."""
STATUS_CHECK_S = 1.0
"""How often a run also asks every device its status, in case an alarm line was lost."""


def trace_period_s(duration_s: float) -> float:
    """The diagnostics period of the trace of a program lasting ``duration_s``."""
    return max(DIAGNOSTICS_PERIOD_S, duration_s / TRACE_POINTS)


def diagnostics_ticks(duration_s: float, tick_s: float, *, live: bool) -> tuple[int, int]:
    """(servo ticks between diagnostics lines, lines per trace line) for a program lasting
    ``duration_s``: the trace's period, or while live at most :data:`LIVE_PERIOD_S` with
    the trace keeping every so many lines (the same ticks as the trace's own period)."""
    trace_ticks = max(1, round(trace_period_s(duration_s) / tick_s))
    if not live:
        return trace_ticks, 1
    live_ticks = max(1, round(LIVE_PERIOD_S / tick_s))
    if trace_ticks <= live_ticks:
        return trace_ticks, 1
    keep = -(-trace_ticks // live_ticks)
    return max(1, trace_ticks // keep), keep


class Watch:
    """A run's ears (see the module docstring).

    Parameters:
        machine: the machine (every axis is listened to).
        trace: where the kept diagnostics lines go.
        live: the live model every line feeds.
        line_at_tick: the program line the devices execute at a device tick.
    """

    def __init__(self, machine: Machine, trace: Trace, live: LiveModel, *,
                 line_at_tick: Callable[[int], int]) -> None:
        self.machine = machine
        self.trace = trace
        self.live = live
        self.line_at_tick = line_at_tick
        self.faults: list[FaultRecord] = []
        self.keep = 1
        """Diagnostics lines per line the trace keeps."""
        self.read_s = 0.0
        self.status_s = 0.0
        self.check_s = FAULT_CHECK_S

    def listen_diagnostics(self, stack: ExitStack) -> None:
        """Every axis's diagnostics lines to the live model and the trace while ``stack``
        is open: held as they are read, and taken in by :meth:`hear`."""
        for name, axis in self.machine.axes.items():
            stack.enter_context(axis.client.listening(diagnostics_block=self._on_lines(name)))

    def hear(self) -> None:
        """The diagnostics lines every device sent so far into the live model and the trace
        (before they are read: a publication, the report)."""
        for axis in self.machine.axes.values():
            axis.client.deliver_diagnostics()

    def listen_alarms(self, stack: ExitStack) -> None:
        """Every axis's alarm lines to the run's faults while ``stack`` is open."""
        for name, axis in self.machine.axes.items():
            stack.enter_context(axis.client.listening(alarms=partial(self._on_alarm, name)))

    def _on_lines(self, axis: str) -> Callable[[DiagnosticsBlock], None]:
        taken = [0]  # lines so far
        peak = [0]  # the largest magnitude of the lines since the one kept before
        take_line, keep_line = self.live.take_line, self.trace.record(axis)

        def on_lines(lines: DiagnosticsBlock) -> None:
            if len(lines) < FEW_DIAGNOSTICS:  # a front following the live model: every look
                for line in lines.lines():
                    take_line(axis, line.clock, line.desired, line.actual_counts,
                              line.peak_error_counts)
                    peak[0] = max(peak[0], abs(line.peak_error_counts))
                    taken[0] += 1
                    if taken[0] % self.keep == 0:
                        keep_line(line, peak[0])
                        peak[0] = 0
                return
            peaks = lines.peak_error_counts
            self.live.take_lines(axis, lines.clock, lines.desired, lines.actual_counts, peaks)
            count, keep = len(lines), self.keep
            magnitude = np.abs(peaks)
            if keep == 1 and not peak[0]:  # every line kept, each with its own peak
                taken[0] += count
                self.trace.extend(axis, lines, magnitude)
                return
            first = (keep - (taken[0] + 1) % keep) % keep  # the first line kept
            taken[0] += count
            if first >= count:
                peak[0] = max(peak[0], int(magnitude.max()))
                return
            kept = np.arange(first, count, keep)
            starts = np.concatenate(([0], kept[:-1] + 1))
            kept_peaks = np.maximum.reduceat(magnitude[:kept[-1] + 1], starts)
            kept_peaks[0] = max(int(kept_peaks[0]), peak[0])
            rest = magnitude[kept[-1] + 1:]
            peak[0] = int(rest.max()) if rest.size else 0
            self.trace.extend(axis, DiagnosticsBlock(lines.rows[kept]), kept_peaks)

        return on_lines

    def _on_alarm(self, axis: str, alarm: Alarm) -> None:
        self.record(axis, alarm.fault, alarm.tick)

    def record(self, axis: str, code: int, tick: int) -> None:
        """Fault ``code`` of ``axis`` latched at device tick ``tick`` (the first of each
        axis)."""
        self.record_words(axis, fault_words(code), tick=tick, line=self.line_at_tick(tick),
                          code=int(code))

    def record_words(self, axis: str, words: str, *, tick: int, line: int,
                     code: int = 0) -> None:
        """A fault in ``words`` (one the host found, a stalled spindle: ``code`` 0) seen at
        device tick ``tick`` of the program axes' clocks, at program line ``line`` (the
        first of each device)."""
        if any(f.axis == axis for f in self.faults):
            return
        elapsed = max(0, tick - self.trace.start_tick) * self.trace.tick_s
        self.faults.append(FaultRecord(axis, words, elapsed, line, code))

    def begin(self, axes: Sequence[str], duration_s: float, *, live: bool) -> None:
        """A run's first start (the clocks just zeroed): each program axis's statistics
        reset and its diagnostics lines at the trace's period (or the live one, the trace
        keeping every so many)."""
        self.hear()
        self.live.new_clocks()
        ticks, self.keep = diagnostics_ticks(duration_s, self.trace.tick_s, live=live)
        for name in axes:
            client = self.machine.axis(name).client
            client.reset_motion_stats()
            client.set_diagnostics_interval(ticks)

    def start(self, now_s: float, *, check_s: float) -> None:
        """Reads count from ``now_s``; a read at least every ``check_s`` (with the fault
        check's own bound)."""
        self.read_s = self.status_s = now_s
        self.check_s = check_s

    def check(self, now_s: float, *, at_once: bool = False) -> bool:
        """Whether a device faulted: reads the alarm lines that came (every
        :data:`FAULT_CHECK_S`, or ``at_once``) and every :data:`STATUS_CHECK_S` asks every
        device its status."""
        if (not at_once and not self.faults
                and now_s - self.read_s + self.check_s <= FAULT_CHECK_S):
            return False  # the next wake still comes within FAULT_CHECK_S of the last read
        self.read_s = now_s
        for axis in self.machine.axes.values():
            axis.client.read_pending()
        if now_s - self.status_s >= STATUS_CHECK_S:
            self.status_s = now_s
            for name, axis in self.machine.axes.items():
                status = axis.client.status()
                if status.fault != FaultCode.NONE:
                    _, fault_tick = axis.client.fault()
                    self.record(name, status.fault, fault_tick)
        return bool(self.faults)

    def next_status_s(self) -> float:
        """When :meth:`check` next asks the devices their status (sends to them)."""
        return self.status_s + STATUS_CHECK_S

    def words(self) -> str:
        """The faults, in words."""
        return "; ".join(f"axis {f.axis} {f.fault}" for f in self.faults)

    def axes_with(self, names: Sequence[str]) -> list[str]:
        """Which of ``names`` faulted."""
        return [f.axis for f in self.faults if f.axis in names]
