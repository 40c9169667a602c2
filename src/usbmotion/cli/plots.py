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
    """The run in three views: the XY path (feed moves coloured by Z, rapids dashed, the
    actual path over them), the XZ side view, and the following error over time; where a
    fault or a stop ended the run is marked on all three."""
    from matplotlib.collections import LineCollection  # noqa: PLC0415

    plt = _pyplot()
    fig, (ax_path, ax_side, ax_error) = plt.subplots(
        1, 3, figsize=(18, 6), dpi=100, gridspec_kw={"width_ratios": [1.2, 1.0, 1.2]})
    z_all = plan.vertices_mm[:, 2]
    z_low, z_high = float(z_all.min()), float(z_all.max())
    norm = plt.Normalize(z_low, z_high if z_high > z_low else z_low + 1.0)
    feed_xy = _path_segments(plan, False, (0, 1))
    if len(feed_xy):
        from usbmotion.motion.planner import SegmentKind  # noqa: PLC0415

        feeds = (plan.kind != SegmentKind.RAPID) & (plan.kind != SegmentKind.DWELL)
        z_mid = (plan.vertices_mm[:-1, 2] + plan.vertices_mm[1:, 2])[feeds] / 2
        lines = LineCollection(feed_xy, cmap="viridis", norm=norm, lw=2.5,
                               label="commanded feed moves")
        lines.set_array(z_mid)
        ax_path.add_collection(lines)
        fig.colorbar(lines, ax=ax_path, label="Z (mm)", shrink=0.8)
    for axis, columns in ((ax_path, (0, 1)), (ax_side, (0, 2))):
        rapids = _path_segments(plan, True, columns)
        if len(rapids):
            axis.add_collection(LineCollection(rapids, colors="0.55", lw=1.0,
                                               linestyles="dashed", label="rapids (G0)"))
    side_feed = _path_segments(plan, False, (0, 2))
    if len(side_feed):
        ax_side.add_collection(LineCollection(side_feed, colors="0.35", lw=2.0,
                                              label="commanded feed moves"))
    actual = {name: trace.arrays(name)[2] / trace.counts_per_mm[name] for name in "XYZ"}
    n = min(values.size for values in actual.values())
    if n:
        ax_path.plot(actual["X"][:n], actual["Y"][:n], color="tab:red", lw=0.8,
                     label="actual (device encoder)")
        ax_side.plot(actual["X"][:n], actual["Z"][:n], color="tab:red", lw=0.8,
                     label="actual (device encoder)")
    ended = "" if report.completed else report.stop_reason
    if ended and n:
        for axis, second in ((ax_path, "Y"), (ax_side, "Z")):
            axis.plot([actual["X"][n - 1]], [actual[second][n - 1]], marker="X",
                      color="black", markersize=12, linestyle="none",
                      label=f"ended: {ended}")
    for axis, (xlabel, ylabel, title) in (
        (ax_path, ("X (mm)", "Y (mm)", "XY path (colour: Z)")),
        (ax_side, ("X (mm)", "Z (mm)", "XZ side view")),
    ):
        axis.autoscale_view()
        axis.set_aspect("equal", adjustable="datalim")
        axis.set_xlabel(xlabel)
        axis.set_ylabel(ylabel)
        axis.set_title(title)
        axis.legend(loc="best", fontsize="small")
        axis.grid(True, alpha=0.3)
    for name, colour in zip(("X", "Y", "Z"), ("tab:blue", "tab:orange", "tab:green"), strict=True):
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
