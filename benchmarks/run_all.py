"""Every benchmark of usbmotion, one table: ``make bench``.

    python benchmarks/run_all.py [--quick] [--only NAME ...] [--json [PATH]]

Runs, in turn (each in this process, its own output captured):

- ``kernel_speed``: servo ticks/s of the compiled kernel and of the reference core1 at
  10 kHz, 1, 3 and 8 axes, as devices in a virtual-time world and as the bare block; the
  kernel's compile cost with a cold and a warm cache;
- ``run_speed``: ``usbmotion run`` of a 10-minute program on the 3-axis machine at 10 kHz,
  with the kernel and with the reference path, as multiples of real time, reports compared;
- ``streaming``: sustained setpoints/s into ``usbmotion sim --pty N`` devices;
- ``gcode_parse``, ``planner_speed``: G-code parse/interpret, plan and sample rates beside
  gcodeparser, pygcode and ``numpy.interp``;
- ``device_speed``, ``scimath_speed``: the reference core1 and the scientific-notation
  arithmetic beside Python floats.

Every figure is a median of several runs, and every ratio is against a peer measured in
the same run. ``--quick`` runs smaller sizes and fewer runs (a smoke test of the suite,
not figures to quote). ``--json`` prints every benchmark's full figures as JSON instead of
the table, or writes them to PATH and prints the table too.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import platform
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

# the benchmarks folder is not a package: import its modules from here
sys.path.insert(0, str(Path(__file__).resolve().parent))

import device_speed
import gcode_parse
import kernel_speed
import planner_speed
import run_speed
import scimath_speed
import streaming

Row = tuple[str, str, str, str]
"""(figure, ours, peer, ratio or verdict) as printed."""

FULL: dict[str, list[str]] = {
    "kernel_speed": [],
    "run_speed": [],
    "streaming": [],
    "gcode_parse": [],
    "planner_speed": [],
    "device_speed": [],
    "scimath_speed": [],
}
QUICK: dict[str, list[str]] = {
    "kernel_speed": ["--runs", "2", "--seconds", "5", "--compile-runs", "1"],
    "run_speed": ["--minutes", "0.3", "--runs", "1", "--reference-runs", "1"],
    "streaming": ["--devices", "1", "3", "--seconds", "1", "--runs", "1"],
    "gcode_parse": ["--lines", "20000", "--runs", "2"],
    "planner_speed": ["--moves", "10000", "--runs", "2"],
    "device_speed": ["--runs", "2", "--ticks", "2000"],
    "scimath_speed": ["--runs", "2", "--operations", "5000"],
}
MAINS: dict[str, Callable[[list[str]], dict[str, Any]]] = {
    "kernel_speed": kernel_speed.main,
    "run_speed": run_speed.main,
    "streaming": streaming.main,
    "gcode_parse": gcode_parse.main,
    "planner_speed": planner_speed.main,
    "device_speed": device_speed.main,
    "scimath_speed": scimath_speed.main,
}


def _x(value: float) -> str:
    return f"{value:,.1f}x" if value < 100 else f"{value:,.0f}x"


def _met(met: bool) -> str:
    return "met" if met else "NOT met"


def rows_kernel(f: dict[str, Any]) -> list[Row]:
    """Table rows of kernel_speed."""
    rows: list[Row] = []
    labels = {"devices": "devices in a world (core0 + kernel)", "kernel": "bare servo block"}
    for row in f["rows"]:
        fast, slow = row["kernel"], row["reference"]
        rows.append((
            f"ticks/s at 10 kHz, {row['axes']} {'axes' if row['axes'] > 1 else 'axis'},"
            f" {labels[row['scenario']]}",
            f"{fast['ticks_s']:,.0f} ({_x(fast['real_time_multiple'])} real time)",
            f"reference {slow['ticks_s']:,.0f} ({_x(slow['real_time_multiple'])})",
            _x(row["ratio"]),
        ))
    for name, met in f["targets_met"].items():
        rows.append((f"target: {name}", "", "", _met(met)))
    cost = f["compile"]
    if cost:
        rows.append((
            "kernel first call (compile or cache load)",
            f"cold cache {cost['cold_first_call_s']:.2f} s",
            f"warm cache {cost['warm_first_call_s']:.2f} s",
            _x(cost["cold_first_call_s"] / cost["warm_first_call_s"]),
        ))
    return rows


def rows_run(f: dict[str, Any]) -> list[Row]:
    """Table rows of run_speed."""
    fast, slow, parts = f["kernel"], f["reference"], f["anatomy"]
    rows: list[Row] = [
        (
            f"usbmotion run, 3 axes at 10 kHz, {f['machine_s']:.0f} s of machine time",
            f"{fast['wall_s']:.2f} s = {_x(fast['real_time_multiple'])} real time",
            f"reference {slow['wall_s']:.2f} s = {_x(slow['real_time_multiple'])}",
            _x(f["speedup"]),
        ),
        ("  first run with an empty numba cache (compiles the kernel)",
         f"{fast['cold_cache_wall_s']:.2f} s", f"warm cache {fast['wall_s']:.2f} s",
         f"+{fast['cold_cache_wall_s'] - fast['wall_s']:.2f} s"),
        ("  fixed cost: homing and a one-figure program (kernel)",
         f"{f['short_run']['wall_s']:.2f} s for {f['short_run']['machine_s']:.0f} s",
         "marginal speed beyond it", _x(fast["marginal_multiple"])),
        ("target: usbmotion run >= 100x real time with the kernel", "", "",
         _met(f["meets_target"])),
        ("  end to end beside the bare kernel (3 axes at 10 kHz, same run)",
         _x(fast["real_time_multiple"]),
         f"bare kernel {_x(f['bare_kernel']['real_time_multiple'])}",
         f"{f['bare_kernel']['share']:.0%}"),
        ("target: end to end >= half the bare kernel's multiple", "", "",
         _met(f["bare_kernel"]["met"])),
        ("reports of kernel and reference runs identical", "", "",
         "yes" if f["reports_identical"] else "NO"),
        (
            "  kernel blocks in the run (mean ticks); lines in, diagnostics lines out",
            f"{parts['blocks']:,} ({parts['ticks_per_block']:.0f} ticks)",
            f"{parts['lines_in']:,} in, {parts['diagnostics_lines']:,} out",
            f"{parts['job_wall_us_per_machine_s']:.0f} us per machine s",
        ),
    ]
    for what_if in parts.get("what_if", []):
        rows.append((
            f"  what if diagnostics every {what_if['label']} (job time, in-process)",
            f"{what_if['job_wall_s']:.2f} s = {_x(what_if['real_time_multiple'])}",
            f"{what_if['diagnostics_lines']:,} lines",
            "",
        ))
    return rows


def rows_streaming(f: dict[str, Any]) -> list[Row]:
    """Table rows of streaming."""
    rows: list[Row] = []
    for row in f["rows"]:
        rows.append((
            f"setpoints/s into {row['devices']} pty device{'s' if row['devices'] > 1 else ''}"
            " (10 kHz)",
            f"{row['setpoints_s']:,.0f}",
            f"device ceiling {row['device_ceiling_setpoints_s']:,}",
            f"{row['share_of_ceiling']:.0%}",
        ))
        rows.append((
            "  host CPU per 1,000 setpoints (host capacity)",
            f"{row['host_cpu_ms_per_1000']:.2f} ms",
            f"{row['host_capacity_setpoints_s']:,.0f}/s",
            "",
        ))
    best = max(f["rows"], key=lambda row: row["setpoints_s"])
    rows.append((f"target: {f['target_setpoints_s']:,} setpoints/s in total", "", "",
                 _met(best["meets_target"])))
    return rows


def rows_gcode(f: dict[str, Any]) -> list[Row]:
    """Table rows of gcode_parse."""
    rows: list[Row] = []
    rates, ratios = f["parse_lines_per_s"], f["parse_ratio"]
    for peer, target in f["parse_targets"].items():
        if peer in rates:
            rows.append((
                f"G-code parse, lines/s (target {target:g}x {peer})",
                f"{rates['ours']:,.0f}",
                f"{peer} {rates[peer]:,.0f}",
                f"{_x(ratios[peer])} {_met(ratios[peer] >= target)}",
            ))
        else:
            rows.append((f"G-code parse beside {peer}", f"{rates['ours']:,.0f}",
                         f"skipped: {f['skipped'][peer]}", ""))
    rows.append(("G-code interpret (text to moves), lines/s",
                 f"{f['interpret_lines_per_s']:,.0f}", "", ""))
    return rows


def rows_planner(f: dict[str, Any]) -> list[Row]:
    """Table rows of planner_speed."""
    peer = f["klipper"]
    rows: list[Row] = [
        ("plan, moves/s (mixed G0-G3)", f"{f['plan_moves_per_s']:,.0f}",
         f"Klipper {peer['plan_moves_per_s']:,.0f}" if peer else "Klipper: --klipper PATH",
         _x(peer["ratio"]) if peer else ""),
        ("  segments/s (arcs as chords within the arc tolerance)",
         f"{f['plan_segments_per_s']:,.0f}", "", ""),
        (f"target: mixed program >= {f['target_mixed_moves_per_s']:,} moves/s", "", "",
         _met(f["plan_moves_per_s"] >= f["target_mixed_moves_per_s"])),
    ]
    for row in f["sampling"]:
        rows.append((
            f"sample at {row['period_s'] * 1000:g} ms, axis-setpoints/s",
            f"{row['axis_setpoints_per_s']:,.0f}",
            f"numpy.interp {row['interp_axis_setpoints_per_s']:,.0f}",
            _x(row["ratio_to_interp"]),
        ))
    hermite = f["hermite"]
    rows.append(("Hermite keyframes sampled, ticks/s",
                 f"{hermite['sample_keyframes_ticks_per_s']:,.0f}",
                 f"per-tick loop {hermite['hermite_position_loop_ticks_per_s']:,.0f}",
                 _x(hermite["ratio"])))
    return rows


def rows_device(f: dict[str, Any]) -> list[Row]:
    """Table rows of device_speed."""
    rows: list[Row] = []
    for name, figures in f["configurations"].items():
        rows.append((
            f"reference core1 + core0 streaming at {name}, ticks/s",
            f"{figures['ticks_s']:,.0f} ({_x(figures['real_time_multiple'])})",
            f"core1 alone {figures['core1_only_ticks_s']:,.0f}",
            "",
        ))
    return rows


def rows_scimath(f: dict[str, Any]) -> list[Row]:
    """Table rows of scimath_speed."""
    return [
        (f"scientific-notation {name}, core ops/s", f"{row['core_ops_s']:,.0f}",
         f"float {row['float_ops_s']:,.0f}", f"{row['core_ratio']:.1f}x slower")
        for name, row in f["results"].items()
    ]


ROWS: dict[str, Callable[[dict[str, Any]], list[Row]]] = {
    "kernel_speed": rows_kernel,
    "run_speed": rows_run,
    "streaming": rows_streaming,
    "gcode_parse": rows_gcode,
    "planner_speed": rows_planner,
    "device_speed": rows_device,
    "scimath_speed": rows_scimath,
}


def table(results: dict[str, Any]) -> str:
    """Every benchmark's figures as one table."""
    header: Row = ("figure", "usbmotion", "peer (same run)", "ratio")
    body: list[Row | None] = []
    for name, figures in results["benchmarks"].items():
        if body:
            body.append(None)
        body.append((f"[{name}] {results['seconds'][name]:.0f} s", "", "", ""))
        body.extend(ROWS[name](figures))
    widths = [max(len(row[i]) for row in [header, *[r for r in body if r]]) for i in range(4)]
    line = "  ".join("-" * w for w in widths)

    def show(row: Row) -> str:
        return "  ".join(
            cell.ljust(w) if i in (0, 2) else cell.rjust(w)
            for i, (cell, w) in enumerate(zip(row, widths, strict=True))
        ).rstrip()

    out = [
        f"usbmotion benchmarks: Python {results['python']}, {results['machine']},"
        f" {results['cpus']} CPUs{', quick sizes' if results['quick'] else ''}",
        show(header), line,
    ]
    out += [line if row is None else show(row) for row in body]
    return "\n".join(out)


def run(names: list[str], *, quick: bool) -> dict[str, Any]:
    """Run the named benchmarks (their own output captured); returns all figures."""
    results: dict[str, Any] = {
        "python": platform.python_version(),
        "machine": platform.machine(),
        "cpus": os.cpu_count(),
        "quick": quick,
        "benchmarks": {},
        "seconds": {},
    }
    for name in names:
        argv = [*(QUICK if quick else FULL)[name], "--json"]
        print(f"running {name} ...", file=sys.stderr, flush=True)
        started = time.perf_counter()
        with contextlib.redirect_stdout(io.StringIO()):
            results["benchmarks"][name] = MAINS[name](argv)
        results["seconds"][name] = time.perf_counter() - started
    return results


def main(argv: list[str] | None = None) -> dict[str, Any]:
    """Run the suite, print the table (or JSON with ``--json``) and return the figures."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="small sizes, few runs")
    parser.add_argument("--only", nargs="+", choices=list(MAINS), default=list(MAINS),
                        metavar="NAME", help=f"benchmarks to run: {', '.join(MAINS)}")
    parser.add_argument("--json", nargs="?", const="-", default=None, metavar="PATH",
                        help="print JSON instead of the table, or write it to PATH")
    args = parser.parse_args(argv)
    results = run(args.only, quick=args.quick)
    if args.json == "-":
        print(json.dumps(results, indent=2))
    else:
        if args.json is not None:
            Path(args.json).write_text(json.dumps(results, indent=2) + "\n", encoding="utf-8")
        print(table(results))
    return results


if __name__ == "__main__":
    main(sys.argv[1:])
