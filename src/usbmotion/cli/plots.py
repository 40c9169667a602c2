"""PNG plots of a run and of a step response (matplotlib, imported only when plotting)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from usbmotion.job import RunReport, Trace
    from usbmotion.motion.planner import Plan
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


def plot_run(path: Path, plan: Plan, trace: Trace, report: RunReport) -> Path:
    """Commanded against actual XY path, and following error over time per axis."""
    from usbmotion.motion.sampler import sample_positions_mm  # noqa: PLC0415

    plt = _pyplot()
    fig, (ax_path, ax_error) = plt.subplots(1, 2, figsize=(13, 6), dpi=100)
    step = max(plan.duration_s / 20000, 0.001)
    commanded = sample_positions_mm(plan, period_s=step)
    ax_path.plot(commanded[:, 0], commanded[:, 1], color="0.6", lw=2.5, label="commanded")
    _, _, actual_x = trace.arrays("X")
    _, _, actual_y = trace.arrays("Y")
    n = min(actual_x.size, actual_y.size)
    if n:
        ax_path.plot(actual_x[:n] / trace.counts_per_mm["X"],
                     actual_y[:n] / trace.counts_per_mm["Y"],
                     color="tab:red", lw=0.9, label="actual (device encoder)")
    ax_path.set_aspect("equal", adjustable="datalim")
    ax_path.set_xlabel("X (mm)")
    ax_path.set_ylabel("Y (mm)")
    ax_path.set_title("XY path")
    ax_path.legend(loc="best")
    ax_path.grid(True, alpha=0.3)
    for name, colour in zip(("X", "Y", "Z"), ("tab:blue", "tab:orange", "tab:green"), strict=True):
        times, desired, actual = trace.arrays(name)
        keep = times >= 0
        if np.any(keep):
            error_mm = (desired[keep] - actual[keep]) / trace.counts_per_mm[name]
            ax_error.plot(times[keep], error_mm * 1000.0, color=colour, lw=0.8, label=name)
    ax_error.set_xlabel("time since start (s)")
    ax_error.set_ylabel("following error (um)")
    ax_error.set_title("following error, desired - actual")
    ax_error.grid(True, alpha=0.3)
    ax_error.legend(loc="best")
    fig.suptitle(f"{Path(report.program).name} on {report.machine}: planned"
                 f" {report.planned_time_s:.2f} s, executed {report.executed_time_s:.2f} s")
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
