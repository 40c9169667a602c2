"""End to end: ``usbmotion run`` of a long program on the 3-axis machine at 10 kHz.

    python benchmarks/run_speed.py [--minutes 10] [--runs 3] [--reference-runs 3] [--json]

A seeded benchmark program (``benchmark_program``: G1 lines, G2/G3 arcs in the I/J and R
forms, full circles and helices, plunges and rapids, all within X 0..200, Y 0..200,
Z -100..0 mm and at least 1 mm off 0; Z homes up, so the figures go down from the top of its
travel, the mirror image of the program of the machine whose Z homed down, with the same
machine time) is run by the command a user runs::

    usbmotion run PROGRAM --machine benchmarks/machine-10khz.toml --report R.json --no-plot -q

on the simulated machine of ``machine-10khz.toml`` (servo loops at 10 kHz, setpoints at
1 kHz), once per run with the compiled kernel (``USBMOTION_KERNEL=1``) and with the
reference core1 (``USBMOTION_KERNEL=0``), each in a fresh process, taking turns, with
Python's bytecode cache on as an installed package has it (``_common.command_environment``).

Figures, medians of the runs:

- wall seconds of the whole command (interpreter start, imports, kernel load, planning,
  homing, the program, the report), and machine seconds: the homing time plus the
  program's planned time (``homing_time_s`` + ``planned_time_s`` of the report; a real
  machine takes at least that long); the multiple of real time is machine over wall;
- the kernel's speed-up over the reference, measured in the same run;
- whether every report of every run is identical, kernel and reference alike (following
  error to the count, executed time, end positions, everything in the JSON).

One more kernel run compiles the kernel afresh (``NUMBA_CACHE_DIR`` pointing at an empty
folder): the first run's cost with a cold cache (its report is compared too).

The fixed cost of a run (interpreter start, imports, loading the kernel, connecting,
configuring and homing) is measured on a one-figure program (median of the kernel runs):
the marginal multiple of real time is the extra machine time of the long program over its
extra wall time, the speed at which a longer program goes by.

Then one more kernel run in-process counts what the devices did: servo ticks, kernel
blocks, the lines the devices interpreted, and the diagnostics and alarm lines they
printed: the anatomy of where the time goes, with the kernel's seconds on the job's own
thread and on the world's helper thread (``sim.world``: it runs one device's blocks while
the job's thread runs another's, the kernel letting go of the interpreter's lock). Without
the kernel's seconds on the job's own thread, the command's wall is the most that running
every kernel block beside the interpreter's work could give: the interpreter's part alone,
printed as a bound. And what-if runs with the diagnostics every 10 ms and every 2 ms
whatever the program's length.
The bare kernel of the same machine, measured in the same run after each kernel run:
``servo_block`` alone on three axes at 10 kHz with setpoints at 1 kHz
(``kernel_speed.kernel_seconds``: full queues, nothing around it), as a multiple of real
time; the end-to-end multiple over it is how
much of the kernel's ceiling the whole command keeps.

Targets: at least 100x real time with the kernel; end to end at least half the bare
kernel's multiple.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import random
import statistics
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

from _common import command_environment
from _processes import run
from kernel_speed import kernel_seconds

MACHINE = Path(__file__).with_name("machine-10khz.toml")
TARGET_MULTIPLE = 100.0
TARGET_SHARE_OF_KERNEL = 0.5
BARE_KERNEL_SECONDS = 20.0
"""Device seconds the bare kernel runs for each of its runs."""
TRAVEL_MM = (200.0, 200.0, 100.0)
MARGIN_MM = 5.0
SAFE_Z_MM = -30.0
"""The height the program moves between figures at: 30 mm below the top of Z's travel."""
WHAT_IF_PERIODS = ((0.01, "10 ms"), (0.002, "2 ms"))
"""Diagnostics periods the anatomy also tries, beside the job's own (10 ms, or sparser for a
program longer than 200 s: ``usbmotion.session.trace_period_s``)."""
SHORT_MINUTES = 0.3
"""The one-figure program that measures the fixed cost of a run."""


def _figure(rng: random.Random, x: float, y: float) -> tuple[list[str], float, float]:
    """One cutting figure near (x, y): plunge, lines and arcs, a helix, a full circle."""
    r = rng.uniform(4.0, 15.0)
    low = MARGIN_MM + 2 * r
    cx = min(max(x + rng.uniform(-30.0, 30.0), low), TRAVEL_MM[0] - low)
    cy = min(max(y + rng.uniform(-30.0, 30.0), low), TRAVEL_MM[1] - low)
    z = rng.uniform(5.0, 20.0)
    w = rng.uniform(5.0, 2 * r)
    feed = rng.choice((600, 900, 1200, 1500))
    out = [
        f"G0 X{cx - r:.3f} Y{cy:.3f}",
        f"G1 Z{-z:.3f} F300",
        f"G2 X{cx - r:.3f} Y{cy:.3f} I{r:.3f} J0 F{feed}",
        f"G3 X{cx + r:.3f} Y{cy:.3f} Z{-z - 1.5:.3f} I{r:.3f} J0",
        f"G1 X{cx + r:.3f} Y{cy + w:.3f}",
        f"G3 X{cx + r - w:.3f} Y{cy + 2 * w:.3f} R{w:.3f}",
        f"G1 X{cx - r:.3f}",
        f"G2 X{cx - r - w / 2:.3f} Y{cy + 1.5 * w:.3f} I0 J{-w / 2:.3f}",
        f"G1 X{cx - r:.3f} Y{cy:.3f} Z{-z:.3f}",
        f"G0 Z{SAFE_Z_MM:.3f}",
    ]
    return out, cx, cy


def benchmark_program(*, minutes: float, seed: int = 2026) -> str:
    """A G-code program of about ``minutes`` minutes on the benchmark machine."""
    rng = random.Random(seed)
    out = ["%", "(usbmotion run benchmark program: lines, arcs, helices, plunges)",
           "G21 G90 G17", f"G0 Z{SAFE_Z_MM:.3f}"]
    x, y = 100.0, 100.0
    figures = max(1, round(minutes * 60 / 18.0))
    for _ in range(figures):
        lines, x, y = _figure(rng, x, y)
        out += lines
    out += ["G0 X5 Y5", "G0 Z-5", "M2", "%"]
    return "\n".join(out) + "\n"


def _run_command(
    program: Path, machine: Path, report: Path, *, kernel: bool, numba_cache: Path | None = None
) -> float:
    """Wall seconds of one ``usbmotion run`` in a fresh process.

    ``numba_cache``: a folder for numba's cache instead of the usual one (an empty folder
    makes the run compile the kernel afresh).
    """
    env = command_environment(USBMOTION_KERNEL="1" if kernel else "0")
    if numba_cache is not None:
        env["NUMBA_CACHE_DIR"] = str(numba_cache)
    command = [sys.executable, "-m", "usbmotion", "run", str(program), "--machine",
               str(machine), "--report", str(report), "--no-plot", "-q"]
    started = time.perf_counter()
    done = run(command, env=env, timeout_s=1800)
    elapsed = time.perf_counter() - started
    if done.returncode != 0:
        raise RuntimeError(f"usbmotion run failed ({done.returncode}):\n{done.stderr}"
                           f"{done.stdout}")
    return elapsed


def _machine_s(report: dict[str, Any]) -> float:
    return float(report["homing_time_s"]) + float(report["planned_time_s"])


def anatomy(
    program: Path, machine_file: Path, *, diagnostics_period_s: float | None = None
) -> dict[str, Any]:
    """One in-process kernel run of the job, counting blocks, ticks and lines.

    ``diagnostics_period_s`` replaces the job's diagnostics period for this run (a what-if:
    how the diagnostics lines bound the speed); None keeps the job's own.
    """
    from usbmotion.device import core0, core1, kernel  # noqa: PLC0415
    from usbmotion.host.config import load_config  # noqa: PLC0415
    from usbmotion.host.device import DeviceClient  # noqa: PLC0415
    from usbmotion.session import watch as job  # noqa: PLC0415 - the job in-process
    from usbmotion.session.live import LiveModel  # noqa: PLC0415
    from usbmotion.sim.machine import connect_session  # noqa: PLC0415
    from usbmotion.sim.world import SimWorld  # noqa: PLC0415

    compiled = kernel.block_function()
    counts = {"blocks": 0, "ticks": 0, "blocks_ended_by_full_records": 0, "lines_in": 0,
              "diagnostics_lines": 0, "alarm_lines": 0}
    kernel_s = {"main": 0.0, "helper": 0.0}
    """Wall seconds in the kernel on the job's own thread and on the world's helper."""
    main_thread = threading.main_thread()

    def counting(state: Any, params: Any, queue: Any, curve: Any, n: int) -> int:
        started = time.perf_counter()
        done = compiled(state, params, queue, curve, n)
        kernel_s["main" if threading.current_thread() is main_thread else "helper"] += (
            time.perf_counter() - started)
        counts["blocks"] += 1
        counts["ticks"] += done
        if state[core1.S_EVENTS] & core1.EVENT_DIAGNOSTICS:
            counts["blocks_ended_by_full_records"] += 1
        return done

    rounds = {"count": 0, "wall_s": 0.0}
    """The world's rounds of devices run ahead together (``SimWorld._catch_up_together``)."""
    original_together = SimWorld._catch_up_together

    def together(self: SimWorld, *args: Any) -> None:
        started = time.perf_counter()
        original_together(self, *args)
        rounds["count"] += 1
        rounds["wall_s"] += time.perf_counter() - started

    original_kernel = core0.block_function
    original_aside = DeviceClient.take_aside
    original_interpret = core0.Device._interpret

    def take_aside(self: DeviceClient, reply: Any) -> bool:
        counts["alarm_lines"] += reply.kind.name == "ALARM"
        return original_aside(self, reply)

    original_take_lines = LiveModel.take_lines

    def take_lines(self: LiveModel, axis: str, clock: Any, *columns: Any) -> None:
        """Every diagnostics line the job hears reaches the live model, in blocks."""
        counts["diagnostics_lines"] += len(clock)
        original_take_lines(self, axis, clock, *columns)

    def interpret(self: core0.Device, line: bytes) -> None:
        counts["lines_in"] += 1
        original_interpret(self, line)

    shipped_period_s, shipped_points = job.DIAGNOSTICS_PERIOD_S, job.TRACE_POINTS
    core0.block_function = lambda: counting
    DeviceClient.take_aside = take_aside  # type: ignore[method-assign]
    LiveModel.take_lines = take_lines  # type: ignore[method-assign]
    core0.Device._interpret = interpret  # type: ignore[method-assign]
    SimWorld._catch_up_together = together  # type: ignore[method-assign]
    if diagnostics_period_s is not None:
        job.DIAGNOSTICS_PERIOD_S = diagnostics_period_s
        job.TRACE_POINTS = 1 << 62
    try:
        config = load_config(machine_file)
        started = time.perf_counter()
        with connect_session(config, world=SimWorld()) as session:
            homing_s = session.home()
            prepared = session.prepare(program)
            plan = prepared.plan
            report, _ = session.run(prepared, homing_s=homing_s)
        elapsed = time.perf_counter() - started
    finally:
        job.DIAGNOSTICS_PERIOD_S, job.TRACE_POINTS = shipped_period_s, shipped_points
        core0.block_function = original_kernel
        DeviceClient.take_aside = original_aside  # type: ignore[method-assign]
        LiveModel.take_lines = original_take_lines  # type: ignore[method-assign]
        core0.Device._interpret = original_interpret  # type: ignore[method-assign]
        SimWorld._catch_up_together = original_together  # type: ignore[method-assign]
    machine_s = report.homing_time_s + report.planned_time_s
    return {
        **counts,
        "kernel_main_s": kernel_s["main"],
        "kernel_helper_s": kernel_s["helper"],
        "rounds_together": rounds["count"],
        "rounds_together_wall_s": rounds["wall_s"],
        "diagnostics_period_s": diagnostics_period_s or job.trace_period_s(plan.duration_s),
        "job_wall_s": elapsed,
        "real_time_multiple": machine_s / elapsed,
        "machine_s": machine_s,
        "ticks_per_block": counts["ticks"] / max(1, counts["blocks"]),
        "job_wall_us_per_machine_s": elapsed / machine_s * 1e6,
    }


def measure(
    *, minutes: float, runs: int, reference_runs: int, seed: int, machine: Path = MACHINE
) -> dict[str, Any]:
    """Run the benchmark: kernel and reference runs taking turns, then the anatomy."""
    from usbmotion.device import kernel  # noqa: PLC0415

    kernel.block_function()  # the bare kernel's figures time running, not loading
    with tempfile.TemporaryDirectory(prefix="usbmotion-run-speed-") as folder:
        program = Path(folder) / "benchmark.ngc"
        program.write_text(benchmark_program(minutes=minutes, seed=seed), encoding="ascii")
        walls: dict[str, list[float]] = {"kernel": [], "reference": []}
        bare_s: list[float] = []  # the bare kernel, after each kernel run (the same load)
        reports: dict[str, list[dict[str, Any]]] = {"kernel": [], "reference": []}
        for index in range(max(runs, reference_runs)):
            for path, wanted in (("kernel", runs), ("reference", reference_runs)):
                if index >= wanted:
                    continue
                report_path = Path(folder) / f"{path}-{index}.json"
                walls[path].append(
                    _run_command(program, machine, report_path, kernel=path == "kernel")
                )
                reports[path].append(json.loads(report_path.read_text(encoding="utf-8")))
                if path == "kernel":
                    bare_s.append(kernel_seconds(True, 3, BARE_KERNEL_SECONDS))
        short = Path(folder) / "short.ngc"
        short.write_text(benchmark_program(minutes=SHORT_MINUTES, seed=seed), encoding="ascii")
        short_walls: list[float] = []
        for index in range(runs):
            short_report = Path(folder) / f"short-{index}.json"
            short_walls.append(_run_command(short, machine, short_report, kernel=True))
        short_machine_s = _machine_s(json.loads(short_report.read_text(encoding="utf-8")))
        cold_report = Path(folder) / "kernel-cold.json"
        cold_s = _run_command(program, machine, cold_report, kernel=True,
                              numba_cache=Path(folder) / "numba-cache")
        reports["kernel"].append(json.loads(cold_report.read_text(encoding="utf-8")))
        parts = anatomy(program, machine)
        parts["what_if"] = [
            {**anatomy(program, machine, diagnostics_period_s=period), "label": label}
            for period, label in WHAT_IF_PERIODS
        ]
        lines = len(program.read_text(encoding="ascii").splitlines())
    first = reports["kernel"][0]
    identical = all(r == first for path in reports for r in reports[path])
    figures: dict[str, Any] = {
        "benchmark": "run_speed",
        "python": platform.python_version(),
        "cpus": os.cpu_count(),
        "machine_file": machine.name,
        "program_lines": lines,
        "program_moves": first["moves"],
        "planned_time_s": first["planned_time_s"],
        "homing_time_s": first["homing_time_s"],
        "machine_s": _machine_s(first),
        "completed": first["completed"],
        "reports_identical": identical,
        "runs": {"kernel": runs, "reference": reference_runs},
        "following_error_counts": {a["name"]: [a["max_error_counts"], a["rms_error_counts"]]
                                   for a in first["axes"]},
        "anatomy": parts,
        "target_multiple": TARGET_MULTIPLE,
    }
    for path in ("kernel", "reference"):
        wall = statistics.median(walls[path])
        figures[path] = {"wall_s": wall, "real_time_multiple": figures["machine_s"] / wall,
                         "walls_s": walls[path]}
    figures["kernel"]["cold_cache_wall_s"] = cold_s
    short_wall = statistics.median(short_walls)
    figures["short_run"] = {"machine_s": short_machine_s, "wall_s": short_wall,
                            "walls_s": short_walls}
    extra_wall = figures["kernel"]["wall_s"] - short_wall
    figures["kernel"]["marginal_multiple"] = (
        (figures["machine_s"] - short_machine_s) / extra_wall if extra_wall > 0 else math.inf
    )
    figures["speedup"] = figures["reference"]["wall_s"] / figures["kernel"]["wall_s"]
    bare = BARE_KERNEL_SECONDS / statistics.median(bare_s)
    figures["bare_kernel"] = {"axes": 3, "real_time_multiple": bare,
                              "share": figures["kernel"]["real_time_multiple"] / bare,
                              "target_share": TARGET_SHARE_OF_KERNEL}
    figures["bare_kernel"]["met"] = figures["bare_kernel"]["share"] >= TARGET_SHARE_OF_KERNEL
    bound = figures["kernel"]["wall_s"] - parts["kernel_main_s"]
    figures["kernel_beside"] = {
        "wall_s": bound, "real_time_multiple": figures["machine_s"] / bound,
        "share": figures["machine_s"] / bound / bare,
    }
    figures["meets_target"] = figures["kernel"]["real_time_multiple"] >= TARGET_MULTIPLE
    return figures


def report(figures: dict[str, Any]) -> str:
    """The figures as text."""
    fast, slow, parts = figures["kernel"], figures["reference"], figures["anatomy"]
    bare, beside = figures["bare_kernel"], figures["kernel_beside"]
    errors = ", ".join(f"{axis} {m} / {rms:.2f}"
                       for axis, (m, rms) in figures["following_error_counts"].items())
    return "\n".join([
        f"run_speed: usbmotion run on {figures['machine_file']} (10 kHz servo), Python"
        f" {figures['python']}, {figures['cpus']} CPUs",
        f"  program: {figures['program_moves']} moves, {figures['planned_time_s']:.1f} s"
        f" planned; homing {figures['homing_time_s']:.1f} s; machine time"
        f" {figures['machine_s']:.1f} s; completed: {figures['completed']}",
        f"  kernel:    {fast['wall_s']:7.2f} s wall = {fast['real_time_multiple']:6.1f}x real"
        f" time (median of {figures['runs']['kernel']}); the first run with an empty numba"
        f" cache took {fast['cold_cache_wall_s']:.2f} s",
        f"  fixed cost: a {figures['short_run']['machine_s']:.1f} s run (homing and one figure)"
        f" takes {figures['short_run']['wall_s']:.2f} s; beyond it the program runs at"
        f" {fast['marginal_multiple']:.0f}x real time",
        f"  reference: {slow['wall_s']:7.2f} s wall = {slow['real_time_multiple']:6.1f}x real"
        f" time (median of {figures['runs']['reference']}); kernel speed-up"
        f" {figures['speedup']:.1f}x",
        f"  bare kernel, 3 axes at 10 kHz (same run): {bare['real_time_multiple']:.0f}x real"
        f" time; end to end keeps {bare['share']:.0%} of it (target"
        f" {bare['target_share']:.0%}: {'met' if bare['met'] else 'NOT met'})",
        f"  reports identical (kernel and reference, every run): {figures['reports_identical']}"
        f"; following error max/rms counts: {errors}",
        f"  target {figures['target_multiple']:g}x real time:"
        f" {'met' if figures['meets_target'] else 'NOT met'}",
        f"  anatomy (in-process kernel run, {parts['job_wall_s']:.2f} s for"
        f" {parts['machine_s']:.1f} s, {parts['job_wall_us_per_machine_s']:.0f} us per machine"
        f" second): {parts['ticks']:,} ticks in {parts['blocks']:,} kernel blocks"
        f" ({parts['ticks_per_block']:.0f} ticks each); {parts['lines_in']:,} lines to the"
        f" devices; {parts['diagnostics_lines']:,} diagnostics lines (every"
        f" {parts['diagnostics_period_s'] * 1e3:g} ms), {parts['alarm_lines']} alarms",
        f"  of the kernel's {parts['kernel_main_s'] + parts['kernel_helper_s']:.2f} s in the"
        f" anatomy, {parts['kernel_helper_s']:.2f} s ran on the world's helper thread beside"
        f" other work and {parts['kernel_main_s']:.2f} s on the job's own thread (devices run"
        f" ahead together in {parts['rounds_together']:,} rounds,"
        f" {parts['rounds_together_wall_s']:.2f} s of wall); were all of"
        f" it beside the interpreter's work, the command would take at least"
        f" {beside['wall_s']:.2f} s = {beside['real_time_multiple']:.0f}x real time, keeping"
        f" {beside['share']:.0%} of the bare kernel",
        *(f"  what if the job asked for diagnostics every {w['label']}: {w['job_wall_s']:.2f} s"
          f" = {w['real_time_multiple']:.0f}x real time ({w['diagnostics_lines']:,} lines)"
          for w in parts["what_if"]),
    ])


def main(argv: list[str] | None = None) -> dict[str, Any]:
    """Run the benchmark, print the figures (or JSON with ``--json``) and return them."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=10.0, help="program length, minutes")
    parser.add_argument("--runs", type=int, default=3, help="kernel runs (median)")
    parser.add_argument("--reference-runs", type=int, default=3, help="reference runs (median)")
    parser.add_argument("--seed", type=int, default=2026, help="program generator seed")
    parser.add_argument("--machine", type=Path, default=MACHINE,
                        help="machine file (default: benchmarks/machine-10khz.toml)")
    parser.add_argument("--json", action="store_true", help="print the figures as JSON")
    args = parser.parse_args(argv)
    if args.runs < 1 or args.reference_runs < 1:
        parser.error("--runs and --reference-runs must be >= 1")
    if not (math.isfinite(args.minutes) and 0.1 <= args.minutes <= 60):
        parser.error(f"--minutes {args.minutes!r}: 0.1 to 60")
    figures = measure(minutes=args.minutes, runs=args.runs,
                      reference_runs=args.reference_runs, seed=args.seed, machine=args.machine)
    print(json.dumps(figures, indent=2) if args.json else report(figures))
    return figures


if __name__ == "__main__":
    main(sys.argv[1:])
