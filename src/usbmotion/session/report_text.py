"""The report of a run as text for a person: the lines ``usbmotion run`` and the console
print."""

from __future__ import annotations

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
                         f" at rest {report.stop_latency_s * 1000:.0f} ms after it was asked")
    return "\n".join(lines)
