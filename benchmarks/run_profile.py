"""Where the main job's time goes: ``usbmotion run`` of the benchmark program, end to end.

    python benchmarks/run_profile.py [--minutes 10] [--runs 3] [--json]

Each run is a fresh process that runs the command a user runs (``usbmotion run PROGRAM
--machine benchmarks/machine-10khz.toml --report R.json -q``, with the plot unless
``--no-plot``) on the program of ``run_speed.benchmark_program``, with the compiled kernel.
Inside it, a timer wraps the functions of each part of the job and charges every wall
microsecond to exactly one part: the innermost one running (a part's own time, not what it
calls). The parts:

- interpreter start (the process's wall time before the first line of the command), the
  Python modules imported, loading the compiled kernel (its machine code's file);
- reading the machine file and the program, interpreting G-code, planning, the checks
  (travel, rapids into the stock), sampling the plan into setpoints;
- the host's protocol text: formatting calls, parsing replies and diagnostics lines;
- the devices: core0 parsing calls, core0 executing them and printing, core0 around core1
  (blocks, records to lines), the servo kernel itself; the simulated world (links, clock);
- the host's live model and run loop (streams, watch, the rest of the session), homing's
  sequence, the report (figures, text, JSON) and the plot;
- "other": what no wrapped function claimed (the command line, the rest).

The wrappers cost time themselves (about 0.3 us a call, hundreds of thousands of calls): the
profiled wall is printed beside the plain command's, run in the same sitting.
Figures: the median of the runs for each part.
"""

from __future__ import annotations

import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from _common import argument_parser, command_environment, parse_arguments
from _processes import run
from run_speed import MACHINE, benchmark_program

DRIVER = Path(__file__).with_name("_profile_driver.py")
PART_ORDER = (
    "interpreter start", "imports", "kernel load", "files", "interpretation", "planning",
    "checks", "sampling", "host: formatting calls", "host: parsing replies",
    "core0: parsing calls", "core0: calls and output", "core0: around the kernel", "kernel",
    "sim world", "host: live model", "host: run loop", "homing sequence", "report", "plot",
    "other",
)


def _one(program: Path, report: Path, *, plot: bool) -> dict[str, Any]:
    """One profiled run in a fresh process: the wall seconds of each part, and the total."""
    with tempfile.TemporaryDirectory(prefix="usbmotion-profile-") as folder:
        out = Path(folder) / "parts.json"
        command = [sys.executable, str(DRIVER), str(out), "run", str(program), "--machine",
                   str(MACHINE), "--report", str(report), "-q"]
        if not plot:
            command.append("--no-plot")
        else:
            command += ["--plot", str(Path(folder) / "plot.png")]
        env = command_environment(USBMOTION_KERNEL="1")
        started = time.perf_counter()
        done = run(command, env=env, timeout_s=1800)
        wall = time.perf_counter() - started
        if done.returncode != 0:
            raise RuntimeError(f"profiled run failed ({done.returncode}):\n{done.stderr}")
        parts: dict[str, float] = json.loads(out.read_text(encoding="utf-8"))
    inside = parts.pop("_inside")
    parts["interpreter start"] = max(0.0, wall - inside)
    return {"wall_s": wall, "parts": parts}


def _plain(program: Path, report: Path, *, plot: bool) -> float:
    command = [sys.executable, "-m", "usbmotion", "run", str(program), "--machine",
               str(MACHINE), "--report", str(report), "-q"]
    command += ["--plot", str(report.with_suffix(".png"))] if plot else ["--no-plot"]
    started = time.perf_counter()
    done = run(command, env=command_environment(USBMOTION_KERNEL="1"), timeout_s=1800)
    if done.returncode != 0:
        raise RuntimeError(f"usbmotion run failed ({done.returncode}):\n{done.stderr}")
    return time.perf_counter() - started


def measure(*, minutes: float, runs: int, plot: bool, seed: int = 2026) -> dict[str, Any]:
    """Profiled and plain runs taking turns; the median of each part."""
    with tempfile.TemporaryDirectory(prefix="usbmotion-run-profile-") as folder:
        program = Path(folder) / "benchmark.ngc"
        program.write_text(benchmark_program(minutes=minutes, seed=seed), encoding="ascii")
        report = Path(folder) / "report.json"
        profiled: list[dict[str, Any]] = []
        plain: list[float] = []
        for _ in range(runs):
            profiled.append(_one(program, report, plot=plot))
            plain.append(_plain(program, report, plot=plot))
        figures = json.loads(report.read_text(encoding="utf-8"))
    names = [p for p in PART_ORDER if any(p in r["parts"] for r in profiled)]
    names += sorted({p for r in profiled for p in r["parts"]} - set(names))
    parts = {name: statistics.median(r["parts"].get(name, 0.0) for r in profiled)
             for name in names}
    machine_s = float(figures["homing_time_s"]) + float(figures["planned_time_s"])
    return {
        "benchmark": "run_profile", "minutes": minutes, "runs": runs, "plot": plot,
        "machine_s": machine_s, "parts_s": parts,
        "profiled_wall_s": statistics.median(r["wall_s"] for r in profiled),
        "plain_wall_s": statistics.median(plain), "plain_walls_s": plain,
    }


def report(figures: dict[str, Any]) -> str:
    """The figures as a table."""
    parts: dict[str, float] = figures["parts_s"]
    total = sum(parts.values())
    lines = [
        f"run_profile: usbmotion run of the {figures['minutes']:g}-minute benchmark program"
        f" ({figures['machine_s']:.1f} s of machine time), {'with' if figures['plot'] else 'no'}"
        f" plot, median of {figures['runs']} runs",
        f"  {'part':<28}{'wall s':>8}{'share':>8}",
    ]
    lines += [f"  {name:<28}{seconds:8.3f}{seconds / total:8.1%}"
              for name, seconds in parts.items()]
    lines += [
        f"  {'sum of the parts':<28}{total:8.3f}",
        f"  profiled run {figures['profiled_wall_s']:.2f} s wall; the plain command"
        f" {figures['plain_wall_s']:.2f} s (median of {figures['runs']}) ="
        f" {figures['machine_s'] / figures['plain_wall_s']:.0f}x real time",
    ]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> dict[str, Any]:
    """Run the profile, print the table (or JSON with ``--json``) and return the figures."""
    parser = argument_parser(__doc__, runs=3)
    parser.add_argument("--minutes", type=float, default=10.0, help="program length, minutes")
    parser.add_argument("--no-plot", action="store_true", help="profile without the plot")
    args = parse_arguments(parser, argv)
    figures = measure(minutes=args.minutes, runs=args.runs, plot=not args.no_plot)
    print(json.dumps(figures, indent=2) if args.json else report(figures))
    return figures


if __name__ == "__main__":
    try:
        main(sys.argv[1:])
    except subprocess.CalledProcessError as error:
        sys.exit(f"run_profile: {error}")
