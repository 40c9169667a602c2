"""How a run ends: the report, from what every device says at the end (or, of a device
that no longer answers, from what the run last heard of it)."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

from usbmotion.errors import UsbMotionError
from usbmotion.host.device import MotionStats, Status
from usbmotion.host.machine import Machine
from usbmotion.session.legs import Legs
from usbmotion.session.live import LiveModel
from usbmotion.session.planning import Prepared
from usbmotion.session.report import (
    LastHeard,
    RunEnding,
    RunReport,
    SegmentsAt,
    Trace,
    build_report,
)
from usbmotion.session.seams import Decelerated
from usbmotion.session.state import StopReason
from usbmotion.session.streaming import RunStreams
from usbmotion.session.watch import Watch


@dataclass(slots=True)
class Ending:
    """How the streaming ended: the reason in the report's words and, when a link was
    lost, its error and the axis it was (when known)."""

    reason: str
    link_error: str = ""
    lost_axis: str = ""


def link_lost(machine: Machine, axes: Sequence[str], error: UsbMotionError,
              notes: list[str]) -> Ending:
    """A lost link: every axis stopped at once; the ending names the error and the axis."""
    lost = next((n for n in axes if machine.axis(n).client.name
                 == getattr(error, "device", None)), "")
    try:
        machine.stop()
    except UsbMotionError as also:
        notes.append(f"stopping: {also}")
    return Ending(f"{StopReason.LINK.value}: {error}", link_error=str(error), lost_axis=lost)


def internal_error(error: Exception) -> Ending:
    """The ending of a run stopped by a fault of its own or an error it did not expect."""
    return Ending(f"fault: {error}" if isinstance(error, UsbMotionError)
                  else f"fault: internal error of the run: {error!r}")


@dataclass(slots=True)
class Stops:
    """The figures of a run's stops and holds: every hold's request time (s), the device
    tick its deceleration began on, its planned v^2/2a and its distance (mm); the last
    stop's distance, planned distance and latency, the row (of the rows since the last
    start, fractional) it stopped at, where that is on the program (s) and its line, and
    how late it reached the latest device (s)."""

    holds: list[tuple[float, int, float, float]] = field(default_factory=list)
    distance_mm: float = 0.0
    planned_mm: float = 0.0
    latency_s: float = 0.0
    stopped_row: float | None = None
    stopped_at_s: float = 0.0
    stopped_at_line: int = 0
    stop_tick: int = 0
    late_s: float = 0.0

    def take(self, stopped: Decelerated, *, asked_s: float, now_s: float, line: int,
             hold: bool) -> None:
        """A stop's (or, ``hold``, a hold's) figures, asked at ``asked_s``, at rest at
        ``now_s``, ended on program line ``line``."""
        self.latency_s = now_s - asked_s
        self.planned_mm, self.distance_mm = stopped.planned_mm, stopped.distance_mm
        self.stopped_row = stopped.stopped_row
        self.stopped_at_s = stopped.point.program_time_s
        self.stopped_at_line = line
        self.late_s = stopped.late_s
        if hold:
            self.holds.append((asked_s, stopped.tick, stopped.planned_mm, stopped.distance_mm))
        else:
            self.stop_tick = stopped.tick


def read_ends(machine: Machine, axes: str, notes: list[str]
              ) -> tuple[dict[str, Status], dict[str, MotionStats]]:
    """Every program axis's status and statistics, its diagnostics turned off (a device
    that does not answer is left out, with a note)."""
    statuses: dict[str, Status] = {}
    stats: dict[str, MotionStats] = {}
    for name in axes:
        client = machine.axis(name).client
        try:
            statuses[name] = client.status()
            stats[name] = client.motion_stats()
            client.set_diagnostics_interval(0)
        except UsbMotionError as error:
            notes.append(f"axis {name}: {error}")
    return statuses, stats


def report_of(prepared: Prepared, machine: Machine, legs: Legs, streams: RunStreams,
              watch: Watch, live: LiveModel, trace: Trace, ending: Ending, stops: Stops, *,
              homing_s: float, skew_s: float, notes: list[str],
              statuses: dict[str, Status], stats: dict[str, MotionStats],
              line_at_tick: Callable[[int], int],
              segments_at_ticks: SegmentsAt | None = None) -> RunReport:
    """The run's report."""
    completed = ending.reason == StopReason.COMPLETED.value
    if ending.link_error:
        sent = (streams.streams[ending.lost_axis].sent if ending.lost_axis
                else streams.sent)
        executed = sent
        place = legs.place(max(0, min(executed, legs.count) - 1))
        stopped_at_s, stopped_at_line = place.program_time_s, place.line
    elif stops.stopped_row is not None:
        executed = max(0, math.floor(stops.stopped_row) + 1)
        stopped_at_s, stopped_at_line = stops.stopped_at_s, stops.stopped_at_line
    else:
        executed = min((streams.streams[n].sent - statuses[n].queued
                        for n in prepared.axes if n in statuses and n in streams.streams),
                       default=streams.sent)
        place = legs.place(max(0, executed - 1))
        stopped_at_s, stopped_at_line = place.program_time_s, place.line
    heard: dict[str, LastHeard] = {}
    for name in prepared.axes:
        if name not in stats or name not in statuses:
            actual, peak, clock = live.heard(name)
            scale = machine.axis(name).config.counts_per_mm
            heard[name] = LastHeard(actual / scale, peak,
                                    max(0.0, (clock - trace.start_tick) * trace.tick_s))
    run_ending = RunEnding(
        ending.reason, completed, legs.rows_before + min(executed, legs.count),
        legs.rows_before + legs.count, stopped_at_s=stopped_at_s,
        stopped_at_line=stopped_at_line, stop_distance_mm=stops.distance_mm,
        stop_planned_mm=stops.planned_mm, stop_latency_s=stops.latency_s,
        stop_late_s=stops.late_s, skew_s=skew_s,
        link_error=ending.link_error, notes=tuple(notes))
    return build_report(prepared.program, machine, legs.plan, trace, homing_s, statuses, stats,
                        watch.faults, run_ending, line_at_tick=line_at_tick, last_heard=heard,
                        segments_at_ticks=segments_at_ticks)
