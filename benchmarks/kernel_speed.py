"""Servo ticks per second: the compiled kernel beside the reference core1, 1 to 8 axes.

    python benchmarks/kernel_speed.py [--axes 1 3 8] [--seconds 20] [--runs 5] [--json]

Every device runs at 10 kHz (``5 1``) with the default motor integrated in 0.1 ms steps,
servo enabled, following a 0.5 Hz sine of 1000 counts with one setpoint every 10 ticks
(``6 10``: setpoints at 1 kHz). Two scenarios, each with the kernel and with the
reference path in the same run:

- ``devices``: N devices in one virtual-time ``SimWorld``; every 0.1 s of device time
  the host writes the next 100 setpoints of every device as a call-1 line through its
  link and advances the world (core0 parses the line, the world runs each device up to
  its next event). This is the device as the whole chain uses it.
- ``kernel``: ``servo_block`` alone on N devices' core1 arrays, each with a full queue
  (1000 setpoints, 10,000 ticks), in blocks until the queue runs dry: the servo loop with
  nothing around it.

Figures: ticks/s over all axes, and device seconds per wall second for each axis (the
multiple of real time), each the median of ``--runs`` runs; the kernel's ratio to the
reference. Targets: one axis at least 5,000,000 ticks/s (500x real time at 10 kHz);
three axes at least 300x real time.

Compile cost: the first ``block_function()`` (the kernel the devices run) in a fresh
interpreter with an empty numba cache (``NUMBA_CACHE_DIR`` pointing at a new temporary
folder, where the machine code's file goes too) and again with that cache filled, each also
as the interpreter's whole run (start, imports, compile or load).
"""

from __future__ import annotations

import math
import os
import platform
import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from functools import partial
from typing import Any

import numpy as np

from _common import argument_parser, emit, median_of, parse_arguments, table_row
from _processes import run
from usbmotion.device import Device, core1, kernel
from usbmotion.device.core1 import IntArray
from usbmotion.sim.world import SimWorld

TICK_US = 100
SCALAR = 10
CHUNK_S = 0.1
TARGET_ONE_AXIS_TICKS_S = 5_000_000
TARGET_THREE_AXES_MULTIPLE = 300.0
_COMPILE_SCRIPT = (
    "import time; started = time.perf_counter();"
    " from usbmotion.device import kernel; kernel.block_function();"
    " print(time.perf_counter() - started)"
)


def sine(first: int, count: int) -> list[int]:
    """Setpoints ``first .. first + count - 1`` of a 0.5 Hz sine of 1000 counts at 1 kHz."""
    return [round(1000 * math.sin(math.pi * k / 1000)) for k in range(first, first + count)]


def _device(fast: bool) -> Device:
    device = Device(fast=fast)
    device.feed(f"5 {TICK_US // 100}\n12 1\n6 {SCALAR}\n3 1\n".encode("ascii"))
    device.take_output()
    return device


def devices_seconds(fast: bool, axes: int, device_s: float) -> float:
    """Wall seconds for ``axes`` devices in a world to run ``device_s`` seconds."""
    world = SimWorld()
    devices = [_device(fast) for _ in range(axes)]
    links = []
    for index, device in enumerate(devices):
        key = f"axis {index}"
        world.add(device, key=key)
        links.append(world.connect(key))
    per_chunk = round(CHUNK_S * 1e6 / (TICK_US * SCALAR))
    chunks = round(device_s / CHUNK_S)
    lines = [f"1 {per_chunk} {' '.join(map(str, sine(c * per_chunk, per_chunk)))}\n".encode()
             for c in range(chunks)]
    started = time.perf_counter()
    for line in lines:
        for link in links:
            link.write(line)
        world.advance(round(CHUNK_S * 1e6))
    elapsed = time.perf_counter() - started
    faults = [device.state.fault for device in devices]
    if any(faults):
        raise RuntimeError(f"a device faulted during the benchmark: {faults}")
    return elapsed


def kernel_seconds(fast: bool, axes: int, device_s: float) -> float:
    """Wall seconds for ``servo_block`` alone to run ``device_s`` seconds on ``axes`` axes."""
    block: Callable[[IntArray, IntArray, IntArray, IntArray, int], int] = (
        kernel.block_function() if fast else core1.servo_block
    )
    arrays = []
    for _ in range(axes):
        device = _device(fast)
        arrays.append((device._state.copy(), device._params.copy(), device._queue.copy()))
    empty = np.zeros(0, dtype=np.int64)
    per_fill = len(arrays[0][2])
    fill_ticks = per_fill * SCALAR
    fills = max(1, round(device_s * 1e6 / TICK_US / fill_ticks))
    values = [np.asarray(sine(f * per_fill, per_fill), dtype=np.int64) for f in range(fills)]
    elapsed = 0.0
    for fill in values:
        for state, _, queue in arrays:
            queue[:] = fill
            state[core1.S_QUEUE_HEAD] = 0
            state[core1.S_QUEUE_COUNT] = per_fill
        started = time.perf_counter()
        for state, params, queue in arrays:
            left = fill_ticks
            while left > 0:
                left -= block(state, params, queue, empty, left)
                state[core1.S_EVENTS] = 0
        elapsed += time.perf_counter() - started
    return elapsed * device_s / (fills * fill_ticks * TICK_US / 1e6)


def compile_cost(runs: int) -> dict[str, float]:
    """First-run times of the kernel with a cold and a warm numba cache, seconds (medians)."""
    cold_first: list[float] = []
    cold_total: list[float] = []
    warm_first: list[float] = []
    warm_total: list[float] = []
    for _ in range(runs):
        with tempfile.TemporaryDirectory(prefix="usbmotion-numba-") as cache:
            env = {**os.environ, "NUMBA_CACHE_DIR": cache}
            for first, total in ((cold_first, cold_total), (warm_first, warm_total)):
                started = time.perf_counter()
                done = run([sys.executable, "-c", _COMPILE_SCRIPT], env=env, timeout_s=600)
                if done.returncode != 0:
                    raise RuntimeError(f"compiling the kernel failed:\n{done.stderr}")
                out = done.stdout
                total.append(time.perf_counter() - started)
                first.append(float(out.strip()))
    return {
        "cold_first_call_s": statistics.median(cold_first),
        "cold_interpreter_s": statistics.median(cold_total),
        "warm_first_call_s": statistics.median(warm_first),
        "warm_interpreter_s": statistics.median(warm_total),
    }


def measure(*, axes_counts: list[int], device_s: float, reference_s: float,
            runs: int, compile_runs: int) -> dict[str, Any]:
    """Every figure of the benchmark."""
    kernel.block_function()
    tick_hz = 1_000_000 // TICK_US
    rows = []
    for scenario, timer in (("devices", devices_seconds), ("kernel", kernel_seconds)):
        for axes in axes_counts:
            row: dict[str, Any] = {"scenario": scenario, "axes": axes}
            for path, fast, seconds in (("kernel", True, device_s),
                                        ("reference", False, reference_s)):
                wall = median_of(partial(timer, fast, axes, seconds), runs)
                row[path] = {
                    "device_s": seconds,
                    "ticks_s": axes * seconds * tick_hz / wall,
                    "real_time_multiple": seconds / wall,
                }
            row["ratio"] = row["kernel"]["ticks_s"] / row["reference"]["ticks_s"]
            rows.append(row)
    targets = {}
    for row in rows:
        if row["axes"] == 1:
            targets[f"{row['scenario']}: 1 axis >= {TARGET_ONE_AXIS_TICKS_S:,} ticks/s"] = (
                row["kernel"]["ticks_s"] >= TARGET_ONE_AXIS_TICKS_S
            )
        if row["axes"] == 3:
            targets[f"{row['scenario']}: 3 axes >= {TARGET_THREE_AXES_MULTIPLE:g}x real time"] = (
                row["kernel"]["real_time_multiple"] >= TARGET_THREE_AXES_MULTIPLE
            )
    return {
        "benchmark": "kernel_speed",
        "python": platform.python_version(),
        "numba": _numba_version(),
        "machine": platform.machine(),
        "cpus": os.cpu_count(),
        "runs": runs,
        "servo_rate_hz": tick_hz,
        "setpoint_rate_hz": tick_hz // SCALAR,
        "rows": rows,
        "targets_met": targets,
        "compile": compile_cost(compile_runs) if compile_runs else {},
    }


def _numba_version() -> str:
    import numba  # noqa: PLC0415 - only to name its version

    return str(numba.__version__)


_COLUMNS = ("<9", ">5", ">16", ">13", ">19", ">13", ">8")


def report(figures: dict[str, Any]) -> str:
    """The figures as text."""
    lines = [
        f"kernel_speed: servo ticks/s at {figures['servo_rate_hz']:,} Hz (setpoints at"
        f" {figures['setpoint_rate_hz']:,} Hz), median of {figures['runs']} runs,"
        f" Python {figures['python']}, numba {figures['numba']}, {figures['cpus']} CPUs",
        table_row(
            ("scenario", "axes", "kernel ticks/s", "x real time", "reference ticks/s",
             "x real time", "ratio"),
            _COLUMNS,
        ),
    ]
    for row in figures["rows"]:
        fast, slow = row["kernel"], row["reference"]
        lines.append(table_row(
            (row["scenario"], str(row["axes"]), f"{fast['ticks_s']:,.0f}",
             f"{fast['real_time_multiple']:,.0f}x", f"{slow['ticks_s']:,.0f}",
             f"{slow['real_time_multiple']:,.1f}x", f"{row['ratio']:.0f}x"),
            _COLUMNS,
        ))
    for name, met in figures["targets_met"].items():
        lines.append(f"target {name}: {'met' if met else 'NOT met'}")
    cost = figures["compile"]
    if cost:
        lines.append(
            f"compile: first kernel call {cost['cold_first_call_s']:.2f} s with a cold cache"
            f" ({cost['cold_interpreter_s']:.2f} s for the whole interpreter),"
            f" {cost['warm_first_call_s']:.2f} s warm ({cost['warm_interpreter_s']:.2f} s)"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> dict[str, Any]:
    """Run the benchmark, print the figures (or JSON with ``--json``) and return them."""
    parser = argument_parser(__doc__, runs=5)
    parser.add_argument("--axes", type=int, nargs="+", default=[1, 3, 8], help="axis counts")
    parser.add_argument("--seconds", type=float, default=20.0,
                        help="device seconds per kernel run")
    parser.add_argument("--reference-seconds", type=float, default=1.0,
                        help="device seconds per reference run")
    parser.add_argument("--compile-runs", type=int, default=1,
                        help="cold/warm compile measurements (0 to skip)")
    args = parse_arguments(parser, argv)
    if args.compile_runs < 0:
        parser.error(f"--compile-runs {args.compile_runs!r}: at least 0")
    if min(args.seconds, args.reference_seconds) < 1.0:
        parser.error("--seconds and --reference-seconds must be >= 1.0 (one queue fill)")
    if any(not 1 <= n <= 64 for n in args.axes):
        parser.error(f"--axes {args.axes!r}: each 1 to 64")
    if not kernel.numba_available():
        parser.error("numba is not installed: pip install 'usbmotion[fast]'")
    figures = measure(axes_counts=args.axes, device_s=args.seconds,
                      reference_s=args.reference_seconds, runs=args.runs,
                      compile_runs=args.compile_runs)
    return emit(figures, report, as_json=args.json)


if __name__ == "__main__":
    main(sys.argv[1:])
