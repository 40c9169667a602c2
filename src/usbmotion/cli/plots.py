"""PNG plots of a run and of a step response (matplotlib, imported only when plotting)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from usbmotion.motion.planner import Plan
    from usbmotion.session import RunReport, Trace
    from usbmotion.tuning import StepResponse


def _pyplot() -> Any:
    import matplotlib  # noqa: PLC0415 - heavy; only when a plot is asked for

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    return plt


def _save(plt: Any, fig: Any, path: Path) -> Path:
    """Lay ``fig`` out, write it to ``path`` (creating its folder) and close it."""
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    plt.close(fig)
    return path


def _path_segments(plan: Plan, rapid: bool, columns: tuple[int, int]) -> Any:
    """(n, 2, 2) line segments of the plan's rapids (or of its feed moves) in two columns."""
    from usbmotion.motion.planner import SegmentKind  # noqa: PLC0415

    vertices = plan.vertices_mm[:, list(columns)]
    chosen = (plan.kind == SegmentKind.RAPID) if rapid else (
        (plan.kind != SegmentKind.RAPID) & (plan.kind != SegmentKind.DWELL))
    index = np.flatnonzero(chosen)
    return np.stack((vertices[index], vertices[index + 1]), axis=1)


def plot_run(path: Path, plan: Plan, trace: Trace, report: RunReport) -> Path:
    """The run in views of the machine's axes: the path in the plane of the first two
    program axes (feed moves coloured by the third when there is one, rapids dashed, the
    actual path over them), a side view of the first and third, and the following error of
    every program axis over time (a one-axis machine: its position over time instead of a
    path); where a fault or a stop ended the run is marked on every view."""
    from matplotlib.collections import LineCollection  # noqa: PLC0415

    from usbmotion.motion.planner import SegmentKind  # noqa: PLC0415

    plt = _pyplot()
    axes = plan.axes
    views = [(0, 1)] if len(axes) >= 2 else []
    if len(axes) >= 3:
        views.append((0, 2))
    ratios = [*[1.2, 1.0][: len(views)], 1.2]
    fig, panels = plt.subplots(1, len(views) + 1, figsize=(6 * (len(views) + 1), 6), dpi=100,
                               gridspec_kw={"width_ratios": ratios}, squeeze=False)
    *view_panels, ax_error = panels[0]
    actual = {name: trace.arrays(name)[2] / trace.counts_per_mm[name] for name in axes}
    n = min(values.size for values in actual.values())
    ended = "" if report.completed else report.stop_reason
    for panel, (first, second) in zip(view_panels, views, strict=True):
        feed = _path_segments(plan, False, (first, second))
        if len(feed):
            if panel is view_panels[0] and len(axes) >= 3:
                third = plan.vertices_mm[:, 2]
                low, high = float(third.min()), float(third.max())
                norm = plt.Normalize(low, high if high > low else low + 1.0)
                feeds = (plan.kind != SegmentKind.RAPID) & (plan.kind != SegmentKind.DWELL)
                middle = (plan.vertices_mm[:-1, 2] + plan.vertices_mm[1:, 2])[feeds] / 2
                lines = LineCollection(feed, cmap="viridis", norm=norm, lw=2.5,
                                       label="commanded feed moves")
                lines.set_array(middle)
                panel.add_collection(lines)
                fig.colorbar(lines, ax=panel, label=f"{axes[2]} (mm)", shrink=0.8)
            else:
                panel.add_collection(LineCollection(feed, colors="0.35", lw=2.0,
                                                    label="commanded feed moves"))
        rapids = _path_segments(plan, True, (first, second))
        if len(rapids):
            panel.add_collection(LineCollection(rapids, colors="0.55", lw=1.0,
                                                linestyles="dashed", label="rapids (G0)"))
        a, b = axes[first], axes[second]
        if n:
            panel.plot(actual[a][:n], actual[b][:n], color="tab:red", lw=0.8,
                       label="actual (device encoder)")
            if ended:
                panel.plot([actual[a][n - 1]], [actual[b][n - 1]], marker="X", color="black",
                           markersize=12, linestyle="none", label=f"ended: {ended}")
        panel.autoscale_view()
        panel.set_aspect("equal", adjustable="datalim")
        panel.set_xlabel(f"{a} (mm)")
        panel.set_ylabel(f"{b} (mm)")
        title = f"{a}{b} path" + (f" (colour: {axes[2]})" if panel is view_panels[0]
                                  and len(axes) >= 3 else "")
        panel.set_title(title if panel is view_panels[0] else f"{a}{b} side view")
        panel.legend(loc="best", fontsize="small")
        panel.grid(True, alpha=0.3)
    colours = ("tab:blue", "tab:orange", "tab:green", "tab:purple", "tab:brown", "tab:pink")
    for name, colour in zip(axes, colours, strict=False):
        times, desired, actual_counts = trace.arrays(name)
        keep = times >= 0
        if np.any(keep):
            error_mm = (desired[keep] - actual_counts[keep]) / trace.counts_per_mm[name]
            ax_error.plot(times[keep], error_mm * 1000.0, color=colour, lw=0.8, label=name)
    for fault in report.faults:
        ax_error.axvline(fault.time_s, color="tab:red", lw=1.2, ls="--",
                         label=f"fault: axis {fault.axis} {fault.fault}")
    if ended and not report.faults:
        ax_error.axvline(report.stopped_at_s, color="black", lw=1.2, ls="--",
                         label=f"stop: {ended}")
    ax_error.set_xlabel("time since start (s)")
    ax_error.set_ylabel("following error (um)")
    ax_error.set_title("following error, desired - actual")
    ax_error.grid(True, alpha=0.3)
    ax_error.legend(loc="best", fontsize="small")
    outcome = "completed" if report.completed else f"ENDED: {report.stop_reason}"
    fig.suptitle(f"{Path(report.program).name} on {report.machine}: planned"
                 f" {report.planned_time_s:.2f} s, executed {report.executed_time_s:.2f} s;"
                 f" {outcome}")
    return _save(plt, fig, path)


def plot_step(path: Path, response: StepResponse) -> Path:
    """Desired and actual position around a step, with the settling band."""
    plt = _pyplot()
    m = response.metrics
    fig, ax = plt.subplots(figsize=(9, 5), dpi=100)
    ax.plot(response.times_s * 1000, response.desired, color="0.5", lw=1.5, label="desired")
    ax.plot(response.times_s * 1000, response.actual, color="tab:red", lw=1.0, label="actual")
    target = response.desired[-1]
    ax.axhspan(target - m.settling_band_counts, target + m.settling_band_counts,
               color="tab:green", alpha=0.15, label="settling band")
    ax.set_xlabel("time since the step (ms)")
    ax.set_ylabel("position (counts)")
    ax.set_title(f"axis {response.axis}: step {m.step_counts} counts, overshoot"
                 f" {m.overshoot_pct:.1f} %, settling {m.settling_time_s * 1000:.0f} ms")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="best")
    return _save(plt, fig, path)
