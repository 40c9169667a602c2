"""The report of a run as text for a person: the lines ``usbmotion run`` and the console
print."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

from usbmotion.motion.gcode import ignored_kind_label
from usbmotion.motion.moves import ROTARY_AXES
from usbmotion.session.report import RunReport


def _unit(axis: str) -> str:
    """mm, or deg for a rotary axis (A, B, C)."""
    return "deg" if axis in ROTARY_AXES else "mm"


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
        unit = _unit(axis.name)
        lines.append(
            f"  {axis.name}  max {axis.max_error_mm:8.4f} {unit} ({axis.max_error_counts:5d}"
            f" counts) at {axis.max_error_time_s:.3f} s, line {axis.max_error_line}"
            f"   rms {axis.rms_error_mm:8.4f} {unit} ({axis.rms_error_counts:8.2f} counts)"
        )
    linear = "  ".join(f"{k} {v:.3f}" for k, v in report.end_position_mm.items()
                       if k not in ROTARY_AXES)
    rotary = "  ".join(f"{k} {v:.3f}" for k, v in report.end_position_mm.items()
                       if k in ROTARY_AXES)
    lines.append(f"end position   {linear} mm" + (f", {rotary} deg" if rotary else ""))
    if report.endpoints_checked:
        lines.append(f"end points     {report.endpoints_checked} programmed, the actual path passed"
                     f" within {report.max_endpoint_miss_mm:.4f} mm of each")
    lines.append(f"result         {report.stop_reason}")
    lines.append("faults         " + ("; ".join(
        f"axis {f.axis}: {f.fault} at {f.time_s:.3f} s, line {f.line}" for f in report.faults
    ) or "none"))
    lines.append("ignored words  " + (", ".join(
        f"{ignored_kind_label(w.word, w.count)} (line {w.line}: {w.meaning}"
        f"{f'; {w.count} times' if w.count > 1 else ''})"
        for w in report.ignored_words) or "none"))
    for change in report.tool_changes:
        pocket = f" (pocket {change.pocket})" if change.pocket else ""
        what = "put in the spindle (M6)" if change.manual else "said to be in the spindle (M61)"
        lines.append(f"tool change    line {change.line}: tool {change.tool}{pocket} {what}")
    for output in (output for output in report.outputs if output.changes):
        lines.append(f"output         {output.name}: {output.changes} change"
                     f"{'' if output.changes == 1 else 's'}, up to {output.max_value / 10:g} %,"
                     f" left at {output.last_value / 10:g} %")
    for wait in report.spindle:
        turn = " counter-clockwise" if wait.rpm < 0 else ""
        lines.append(f"spindle        line {wait.line}: {abs(wait.rpm):g} rpm{turn}, at speed"
                     f" after {wait.waited_s:.2f} s (measured {abs(wait.measured_rpm):.0f} rpm)"
                     if wait.rpm else f"spindle        line {wait.line}: stopped after"
                     f" {wait.waited_s:.2f} s")
    if report.link_error:
        lines.append(f"LINK LOST      {report.link_error}")
    for note in report.notes:
        lines.append(f"note           {note}")
    if not report.completed:
        what = "last setpoint the device confirmed" if report.link_error else "setpoint"
        lines.append(f"STOPPED ({report.stop_reason}) at program line {report.stopped_at_line},"
                     f" {what} {report.stopped_at_setpoint} of {report.setpoints_per_axis},"
                     f" {report.stopped_at_s:.3f} s into the program")
        if report.stopped_at_line:
            lines.append(f"resume         from line {report.stopped_at_line}: usbmotion run"
                         f" {report.program} --from-line {report.stopped_at_line}")
        if report.stop_latency_s and not (report.stop_planned_mm or report.stop_distance_mm):
            lines.append(f"stop           every axis at rest {report.stop_latency_s * 1000:.0f} ms"
                         " after it was asked")
        if report.stop_planned_mm or report.stop_distance_mm:
            lines.append(f"stop           along the path to rest in {report.stop_distance_mm:.3f}"
                         f" mm (planned deceleration v^2/2a {report.stop_planned_mm:.3f} mm),"
                         f" at rest {report.stop_latency_s * 1000:.0f} ms after it was asked"
                         + (f"; it reached the devices {report.stop_late_s * 1000:.0f} ms late,"
                            " the axes running on along the path until then"
                            if report.stop_late_s else ""))
    return "\n".join(lines)


LINES_SHOWN = 10
"""The most program lines the prediction's comparison lists."""


def lines_over(report: RunReport, tolerance_mm: float,
               scales: Mapping[str, float]) -> list[tuple[int, str, float]]:
    """(line, axis, peak mm) of every program line whose peak following error on an axis
    exceeds ``tolerance_mm`` (``scales``: counts per mm of each axis), the worst axis of
    each line, in line order."""
    over: list[tuple[int, str, float]] = []
    for peak in report.line_peaks:
        worst = max(((peak.peak_error_counts[name] / scales[name], name)
                     for name in peak.peak_error_counts), default=(0.0, ""))
        if worst[0] > tolerance_mm:
            over.append((peak.line, worst[1], worst[0]))
    return over


def describe_prediction(predicted: RunReport, motors: Mapping[str, str], wall_s: float, *,
                        scales: Mapping[str, float], tolerance_mm: float | None) -> str:
    """The prediction before a run: where each motor came from, each axis's predicted peak
    and RMS following error, and (with a tolerance) the lines predicted beyond it."""
    speed = predicted.planned_time_s / wall_s if wall_s > 0 else 0.0
    lines = [f"prediction     {Path(predicted.program).name} played on the axes' models in"
             f" {wall_s:.2f} s ({speed:.0f} x the program's {predicted.planned_time_s:.3f} s)"]
    sources: dict[str, list[str]] = {}
    for name, source in motors.items():
        sources.setdefault(source, []).append(name)
    for source, names in sources.items():
        lines.append(f"  motors       {', '.join(names)}: {source}")
    lines.append("predicted following error (every servo tick, desired - actual):")
    for axis in predicted.axes:
        unit = _unit(axis.name)
        lines.append(
            f"  {axis.name}  max {axis.max_error_mm:8.4f} {unit} ({axis.max_error_counts:5d}"
            f" counts) at {axis.max_error_time_s:.3f} s, line {axis.max_error_line}"
            f"   rms {axis.rms_error_mm:8.4f} {unit} ({axis.rms_error_counts:8.2f} counts)")
    if not predicted.completed:
        lines.append(f"  the predicted run did not complete: {predicted.stop_reason}")
    if tolerance_mm is not None:
        over = lines_over(predicted, tolerance_mm, scales)
        if not over:
            lines.append(f"tolerance      {tolerance_mm:g} mm: every line within it")
        else:
            shown = ", ".join(f"{line} ({axis} {mm:.4f} {_unit(axis)})"
                              for line, axis, mm in over[:LINES_SHOWN])
            more = f" and {len(over) - LINES_SHOWN} more" if len(over) > LINES_SHOWN else ""
            lines.append(f"tolerance      {tolerance_mm:g} mm: {len(over)} line(s) predicted"
                         f" beyond it: {shown}{more}")
    return "\n".join(lines)


def describe_comparison(predicted: RunReport, measured: RunReport, *,
                        scales: Mapping[str, float]) -> str:
    """Predicted beside measured: each axis's peak and RMS following error, then the
    program lines of the largest peaks (either's), each axis's peak in counts."""
    lines = ["predicted vs measured following error (counts):",
             "  axis     peak predicted  measured      rms predicted  measured"]
    measured_axes = {axis.name: axis for axis in measured.axes}
    for axis in predicted.axes:
        got = measured_axes.get(axis.name)
        if got is None:
            continue
        lines.append(f"  {axis.name:<4}{axis.max_error_counts:20d}{got.max_error_counts:10d}"
                     f"{axis.rms_error_counts:19.2f}{got.rms_error_counts:10.2f}")
    measured_lines = {peak.line: peak.peak_error_counts for peak in measured.line_peaks}
    rows: list[tuple[float, int, str]] = []
    for peak in predicted.line_peaks:
        got_line = measured_lines.get(peak.line)
        if got_line is None:
            continue
        worst = max(max(peak.peak_error_counts[n], got_line.get(n, 0)) / scales[n]
                    for n in peak.peak_error_counts)
        cells = "  ".join(f"{n} {peak.peak_error_counts[n]:4d} |{got_line.get(n, 0):4d}"
                          for n in peak.peak_error_counts)
        rows.append((worst, peak.line, cells))
    if rows:
        rows.sort(key=lambda row: (-row[0], row[1]))
        lines.append(f"lines of the largest peaks (predicted | measured; {len(rows)} lines"
                     " in --report's JSON):")
        lines.extend(f"  line {line:<6}{cells}" for _, line, cells in rows[:LINES_SHOWN])
    return "\n".join(lines)
