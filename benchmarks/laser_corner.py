"""A dynamic laser (M4) through corners: its power against the speed the axes execute.

    python benchmarks/laser_corner.py [--plot FILE.png] [--json]

Runs a square (four right-angle corners at F1200, 20 mm/s) with ``M4 S1000`` on the
simulated laser machine of ``examples/laser.toml`` in virtual time. The laser's PWM changes
(PROTOCOL.md call 42) come from the rows the axes are told (their speed over 10 ms, over
the move's nominal speed, in steps of 1 % at most every 5 ms); the encoders then measure
how fast the axes actually go. Figures, over every trace line of the square (the
diagnostics every 2 servo ticks; each line's speed from the counts over 10 ms around it,
the desired positions' for the speed the axes are told, the encoders' for the speed they
execute, as a share of the 20 mm/s of F1200):

- the power's difference from each share: median and worst, in per cent of full power,
  and the worst within a slow-down (below 90 %);
- at each slow-down, the lowest power against the lowest told and executed speed;
- how many power changes the square took.

With ``--plot`` the power and the executed speed (both in % of full) are drawn against time.
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from _common import argument_parser, emit, parse_arguments
from usbmotion.host.config import load_config
from usbmotion.session import watch
from usbmotion.sim.machine import connect_session

ROOT = Path(__file__).resolve().parents[1]
PROGRAM = """G21 G90
G0 X40 Y40
M4 S1000
G1 X120 F1200
G1 Y120
G1 X40
G1 Y40
M5
G0 X5 Y5
"""
WINDOW_TICKS = 10


def measure() -> dict[str, Any]:
    """The square's power and executed speed, tick by tick."""
    with tempfile.TemporaryDirectory(prefix="usbmotion-laser-") as folder:
        machine = Path(folder) / "laser.toml"
        machine.write_text((ROOT / "examples" / "laser.toml").read_text())
        config = load_config(machine)
        shipped = watch.DIAGNOSTICS_PERIOD_S
        watch.DIAGNOSTICS_PERIOD_S = config.servo_period_s  # a trace line every tick
        try:
            with connect_session(config) as session:
                session.home()
                report, trace = session.run(session.prepare("square.ngc", text=PROGRAM))
                run = session.last_run
                assert run is not None and run.outputs is not None and report.completed
                changes = [(c.tick, c.value) for c in run.outputs.applied
                           if c.name == "laser"]
                session.shutdown()
        finally:
            watch.DIAGNOSTICS_PERIOD_S = shipped
    clocks = trace.column(trace.clock, "X")
    period = int(np.median(np.diff(clocks)))
    tick_s = config.servo_period_s
    nominal = 20.0  # F1200 = 20 mm/s, within X's and Y's 20 mm/s
    ticks = np.array([tick for tick, _ in changes])
    values = np.array([value for _, value in changes], dtype=np.float64)
    at = np.searchsorted(ticks, clocks, side="right") - 1
    power = np.where(at >= 0, values[np.maximum(at, 0)], 0.0) / 10.0
    shares = {}
    for name, store in (("told", trace.desired), ("executed", trace.actual)):
        xy = np.stack([trace.column(store, "X"), trace.column(store, "Y")], axis=1)
        half = max(1, WINDOW_TICKS // (2 * period))  # the counts over 10 ms around each line
        index = np.arange(len(clocks))
        ahead, behind = np.minimum(index + half, len(clocks) - 1), np.maximum(index - half, 0)
        moved = np.linalg.norm((xy[ahead] - xy[behind]) / 240.0, axis=1)
        speed = moved / np.maximum((clocks[ahead] - clocks[behind]) * tick_s, 1e-9)
        shares[name] = np.minimum(1.0, speed / nominal) * 100.0
    cutting = power > 0
    slow = cutting & (shares["executed"] < 90.0)
    figures: dict[str, Any] = {
        "program": "a 80 mm square at F1200 with M4 S1000 on examples/laser.toml",
        "ticks_compared": int(cutting.sum()),
        "trace_period_ticks": period,
        "power_changes": len(changes),
    }
    for name, share in shares.items():
        error = np.abs(power - share)
        figures[f"{name}_error_median_pct"] = float(np.median(error[cutting]))
        figures[f"{name}_error_worst_pct"] = float(error[cutting].max())
        figures[f"{name}_error_worst_in_corners_pct"] = float(error[slow].max())
    corners = []
    edges = np.flatnonzero(np.diff(slow.astype(int)) == 1)
    for start in edges:
        rest = ~slow[start + 1:]
        end = start + 1 + int(np.argmax(rest)) if rest.any() else len(slow)
        corners.append({"lowest_power_pct": float(power[start + 1:end].min()),
                        "lowest_told_pct": float(shares["told"][start + 1:end].min()),
                        "lowest_executed_pct": float(shares["executed"][start + 1:end].min()),
                        "time_s": float((clocks[start] - clocks[0]) * tick_s)})
    figures["corners"] = corners
    figures["_series"] = {"time_s": ((clocks - clocks[0]) * tick_s).tolist(),
                          "power_pct": power.tolist(), "told_pct": shares["told"].tolist(),
                          "executed_pct": shares["executed"].tolist()}
    return figures


def _text(figures: dict[str, Any]) -> str:
    lines = [
        f"laser_corner: {figures['program']}",
        f"  {figures['power_changes']} power changes; {figures['ticks_compared']} trace lines"
        f" cutting (every {figures['trace_period_ticks']} servo ticks)",
    ]
    for name, what in (("told", "the speed the axes are told"),
                       ("executed", "the speed the encoders measure")):
        lines.append(
            f"  power against {what}: median {figures[f'{name}_error_median_pct']:.1f} %,"
            f" worst {figures[f'{name}_error_worst_pct']:.1f} %, worst in the corners"
            f" {figures[f'{name}_error_worst_in_corners_pct']:.1f} % (of full)")
    for number, corner in enumerate(figures["corners"], start=1):
        lines.append(f"  slow-down {number} at {corner['time_s']:.2f} s: power down to"
                     f" {corner['lowest_power_pct']:.0f} %, told speed"
                     f" {corner['lowest_told_pct']:.0f} %, executed"
                     f" {corner['lowest_executed_pct']:.0f} %")
    return "\n".join(lines)


def _plot(figures: dict[str, Any], path: Path) -> None:
    import matplotlib  # noqa: PLC0415 - only with --plot

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415 - only with --plot

    series = {key: np.asarray(value) for key, value in figures["_series"].items()}
    corner = figures["corners"][1]["time_s"] if len(figures["corners"]) > 1 else 0.0
    figure, (whole, zoom) = plt.subplots(1, 2, figsize=(11, 3.6),
                                         gridspec_kw={"width_ratios": [2, 1]})
    for axes in (whole, zoom):
        axes.plot(series["time_s"], series["executed_pct"], label="executed speed (encoders)")
        axes.plot(series["time_s"], series["told_pct"], label="told speed", alpha=0.7)
        axes.step(series["time_s"], series["power_pct"], where="post", label="laser power")
        axes.set_xlabel("time, s")
        axes.set_ylabel("% of F / of full power")
    zoom.set_xlim(corner - 0.03, corner + 0.12)
    whole.set_title("M4 S1000 around an 80 mm square at F1200")
    zoom.set_title("the second corner")
    zoom.legend(loc="lower right", fontsize=8)
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)


def main(argv: list[str] | None = None) -> int:
    parser = argument_parser(__doc__, runs=1)
    parser.add_argument("--plot", type=Path, help="draw power and speed into this PNG")
    args = parse_arguments(parser, argv)
    figures = measure()
    if args.plot is not None:
        _plot(figures, args.plot)
    shown = {key: value for key, value in figures.items() if not key.startswith("_")}
    emit(shown, _text, as_json=args.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
