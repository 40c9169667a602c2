"""A program streamed line by line against the same program planned whole, and jog-cancel
latency, on the default machine in virtual time.

    python benchmarks/streamed_plan.py [--runs 3] [--json] [--conformance DIR]

Streamed vs whole: each G-code program of the LinuxCNC conformance cases (``--conformance``,
by default ``../shared/gcode-conformance`` beside the checkout; the cases LinuxCNC accepts)
and each demo runs twice on the default machine, its axes given 40 m of travel so that
every program fits, with the work origin (G54) put where the program's extent starts 5 mm
from where homing leaves the machine: once
planned whole before the first setpoint (``usbmotion run``), once read line by line as it
runs (a feed: it plans with look-ahead over the moves it has read, joining more as it reads,
3 moves per read so that every program is joined many times). The figure is the ratio of
the executed times (the devices' own statistics) and the largest distance between the two
end points the devices were commanded to; the goal is a ratio within 0.5 % of 1.

Jog-cancel latency: a continuous jog of X at 20 mm/s is cancelled on a servo tick that moves
from run to run; the figure is from the tick of the request to the tick the deceleration
began on (the first setpoint replaced), and the stop distance against v^2/2a.

Virtual time is deterministic: runs repeated give the same figures.
"""

from __future__ import annotations

import dataclasses
import statistics
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

import usbmotion
import usbmotion.session.feed as feed_module
from _common import argument_parser, emit, parse_arguments
from usbmotion.cli.run import default_machine
from usbmotion.errors import UsbMotionError
from usbmotion.host.config import MachineConfig, load_config
from usbmotion.session.planning import plan_gcode
from usbmotion.sim.machine import connect_session
from usbmotion.sim.recording import ExecutedRecorder

DEMOS = sorted((Path(usbmotion.__file__).parent / "data" / "demos").glob("*.ngc"))
CONFORMANCE = Path(__file__).resolve().parents[2] / "shared" / "gcode-conformance"
TRAVEL_MM = 40_000.0
MARGIN_MM = 5.0
"""The program's extent starts this far from where homing leaves the machine (above it on
an axis that homes down, below it on one that homes up: Z)."""
MAX_PROGRAM_S = 600.0
"""Programs with more motion than this (LinuxCNC's big-arc cases: hours) are left out."""
JOG_FIRST_TICK = 1500
JOG_STEP_TICKS = 137


def _wide(config: MachineConfig, directory: Path) -> MachineConfig:
    """The machine with 40 m of travel on every axis, from the end it homes to (Z: down from
    its top), and its own parameter file."""
    axes = tuple(dataclasses.replace(
        axis, travel_mm=(0.0, TRAVEL_MM) if axis.homing.direction < 0 else (-TRAVEL_MM, 0.0))
        for axis in config.axes)
    return dataclasses.replace(config, axes=axes, parameter_file=directory / "bench.var")


def _programs(conformance: Path) -> list[Path]:
    cases = sorted(_case_program(path) for path in conformance.glob("*")
                   if (path / "expected").exists() and (path / "test.ngc").exists())
    return [*cases, *DEMOS]


def _case_program(case: Path) -> Path:
    """A case's program in the words this interpreter reads (``test.basic.ngc``, with
    the expressions written out, when the case has one)."""
    basic = case / "test.basic.ngc"
    return basic if basic.exists() else case / "test.ngc"


def _executed(config: MachineConfig, text: str, name: str, *, streamed: bool,
              ) -> tuple[float, np.ndarray[Any, Any], int]:
    """Executed time (s), the end position (counts) and how many legs were streamed."""
    with connect_session(config) as session:
        session.home()
        here = session.positions_mm()
        _, plan = plan_gcode(config, text, start_mm=tuple(here[a] for a in "XYZ"))
        low, high = plan.vertices_mm.min(axis=0), plan.vertices_mm.max(axis=0)
        origin = {a: here[a] + MARGIN_MM - low[i] if config.axis(a).homing.direction < 0
                  else here[a] - MARGIN_MM - high[i] for i, a in enumerate("XYZ")}
        session.set_work_origin(origin)
        if streamed:
            feed = session.open_feed(file=name, source=iter(text.splitlines()))
            report, _ = session.run_feed(feed)
        else:
            report, _ = session.run(session.prepare(name, text=text))
        assert report.completed, f"{name}: {report.stop_reason}"
        run = session.last_run
        assert run is not None
        end = np.array([session.machine.status()[a].desired_counts for a in "XYZ"])
        session.shutdown()
        return report.executed_time_s, end, len(run.legs.legs)


def streamed_against_whole(conformance: Path) -> list[dict[str, Any]]:
    """Per program: executed times whole and streamed, their ratio, the end points' gap."""
    feed_module.PULL_MOVES = 3
    rows: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory() as directory:
        config = _wide(load_config(default_machine()), Path(directory))
        counts = config.axis("X").counts_per_mm
        for path in _programs(conformance):
            text = path.read_text()
            name = path.parent.name if path.parent.parent == conformance else path.name
            try:
                _, plan = plan_gcode(config, text)
            except UsbMotionError as error:
                rows.append({"program": name, "refused": str(error)})
                continue
            if plan.duration_s > MAX_PROGRAM_S:
                rows.append({"program": name, "refused": f"{plan.duration_s:.0f} s of motion"
                             f" (longer than the {MAX_PROGRAM_S:.0f} s this benchmark runs)"})
                continue
            try:
                whole_s, whole_end, _ = _executed(config, text, name, streamed=False)
                fed_s, fed_end, legs = _executed(config, text, name, streamed=True)
            except (UsbMotionError, AssertionError) as error:
                rows.append({"program": name, "refused": str(error)})
                continue
            rows.append({"program": name, "whole_s": whole_s, "streamed_s": fed_s,
                         "ratio": fed_s / whole_s if whole_s else 1.0, "legs": legs,
                         "end_gap_mm": float(np.abs(fed_end - whole_end).max() / counts)})
    return rows


def jog_cancel(config: MachineConfig, request_tick: int) -> tuple[float, float, float]:
    """Latency (ms), stop distance and v^2/2a (mm) of one jog cancel."""
    asked = [0]
    with connect_session(config) as session:
        session.live_control = True
        session.home()
        world = session.machine.world
        assert world is not None
        count = [0]

        def on_tick(clock: int) -> None:
            count[0] += 1
            if count[0] == request_tick:
                asked[0] = clock
                session.request_jog_cancel()

        with ExecutedRecorder(world, ["X", "Y", "Z"], on_tick=on_tick):
            report = session.jog({"X": 1.0}, feed_mm_min=1200, continuous=True)
        run = session.last_run
        assert run is not None and report.stop_reason == "jog cancelled"
        session.shutdown()
        latency_ms = (run.stops.stop_tick - asked[0]) * config.servo_period_s * 1000
        return latency_ms, report.stop_distance_mm, report.stop_planned_mm


def measure(*, runs: int, conformance: Path) -> dict[str, Any]:
    config = load_config(default_machine())
    cancels = [jog_cancel(config, JOG_FIRST_TICK + run * JOG_STEP_TICKS) for run in range(runs)]
    latency = [c[0] for c in cancels]
    rows = streamed_against_whole(conformance)
    ratios = [row["ratio"] for row in rows if "ratio" in row]
    return {
        "runs": runs,
        "jog_cancel_latency_ms": {"median": statistics.median(latency), "worst": max(latency)},
        "jog_cancel_stop_mm": statistics.median(c[1] for c in cancels),
        "jog_cancel_v2_2a_mm": statistics.median(c[2] for c in cancels),
        "programs": rows,
        "worst_ratio_deviation": max((abs(r - 1.0) for r in ratios), default=0.0),
    }


def report(figures: dict[str, Any]) -> str:
    latency = figures["jog_cancel_latency_ms"]
    lines = [
        "jog cancel on the default machine (continuous X jog at 20 mm/s), virtual time,"
        f" median of {figures['runs']} request times",
        f"  latency        {latency['median']:6.1f} ms (worst {latency['worst']:.1f} ms),"
        " request to the first decelerating setpoint",
        f"  stop distance  {figures['jog_cancel_stop_mm']:6.3f} mm against v^2/2a"
        f" {figures['jog_cancel_v2_2a_mm']:.3f} mm",
        "",
        "streamed line by line against planned whole (executed time, the devices' own)",
        f"  {'program':28s} {'whole s':>9s} {'streamed s':>11s} {'ratio':>8s} {'legs':>5s}"
        f" {'end gap mm':>11s}",
    ]
    for row in figures["programs"]:
        if "refused" in row:
            lines.append(f"  {row['program']:28s} refused: {row['refused']}")
            continue
        lines.append(f"  {row['program']:28s} {row['whole_s']:9.3f} {row['streamed_s']:11.3f}"
                     f" {row['ratio']:8.5f} {row['legs']:5d} {row['end_gap_mm']:11.4f}")
    lines.append(f"  worst |ratio - 1|: {figures['worst_ratio_deviation'] * 100:.3f} %"
                 " (goal <= 0.5 %)")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> dict[str, Any]:
    """Run the benchmark, print the figures (or JSON with ``--json``) and return them."""
    parser = argument_parser(__doc__, runs=3)
    parser.add_argument("--conformance", type=Path, default=CONFORMANCE,
                        help="the conformance cases' directory")
    args = parse_arguments(parser, argv)
    return emit(measure(runs=args.runs, conformance=args.conformance), report,
                as_json=args.json)


if __name__ == "__main__":
    main(sys.argv[1:])
