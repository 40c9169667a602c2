"""Servo ticks per second of the simulated device's reference core1 (pure Python).

Two configurations, 1 kHz (``5 10``) and 10 kHz (``5 1``), default motor and gains, servo
enabled, following a stream of positions (a 1 Hz sine of 2000 counts, one value per tick,
sent in batches of 500 with call 1 and interpreted by core0 as the device runs). Each figure
is the median of several runs (5 by default), printed as ticks per second and as a multiple
of real time. Beside it, in the same run:

- ``core1 only``: ``servo_block`` on the same stream without core0 (no line parsing);
- ``scimath share``: the time of the scientific-notation operations one tick performs
  (counted, then timed on their own), as a share of the tick: what bounds the loop;
- ``idle``: an enabled servo holding still, which the device skips in big blocks.

Target: at least 50,000 ticks/s for one axis. Run:
``python benchmarks/device_speed.py [--json] [--runs 5] [--ticks 20000]``.
"""

from __future__ import annotations

import math
import platform
import sys
import time
from collections import Counter
from collections.abc import Callable
from functools import partial
from typing import Any

import numpy as np

from _common import argument_parser, emit, median_of, parse_arguments
from usbmotion import scimath
from usbmotion.device import Device
from usbmotion.device import core1 as core1_module
from usbmotion.device import motor as motor_module

TARGET_TICKS_S = 50_000
BATCH = 500
_SCI_NAMES = ("sci_add", "sci_sub", "sci_mul", "sci_compare", "sci_from_int", "sci_to_int")


def trajectory(ticks: int, tick_us: int) -> list[int]:
    """A 1 Hz sine of 2000 counts amplitude, one value per tick (within the motor's reach)."""
    return [
        round(2000 * math.sin(2 * math.pi * k * tick_us * 1e-6)) for k in range(1, ticks + 1)
    ]


def _streaming_device(interval_dms: int) -> Device:
    device = Device(fast=False)
    device.feed(f"5 {interval_dms}\n3 1\n".encode())
    return device


def run_streaming(interval_dms: int, values: list[int]) -> float:
    """Seconds to stream ``values`` through core0 and run one tick per value."""
    device = _streaming_device(interval_dms)
    lines = [
        f"1 {len(chunk)} {' '.join(map(str, chunk))}\n".encode()
        for chunk in (values[i : i + BATCH] for i in range(0, len(values), BATCH))
    ]
    start = time.perf_counter()
    for line, first in zip(lines, range(0, len(values), BATCH), strict=True):
        device.feed(line)
        device.run(min(BATCH, len(values) - first))
    elapsed = time.perf_counter() - start
    assert device.state.fault == 0, device.state
    return elapsed


def run_core1_only(interval_dms: int, values: list[int]) -> float:
    """Seconds for ``servo_block`` alone to run the same stream from a preloaded queue."""
    device = _streaming_device(interval_dms)
    state = device._state  # the benchmark drives core1 directly
    params = device._params
    queue = device._queue
    empty = np.zeros(0, dtype=np.int64)
    chunks = [values[i : i + BATCH] for i in range(0, len(values), BATCH)]
    elapsed = 0.0
    for chunk in chunks:
        queue[: len(chunk)] = chunk
        state[core1_module.S_QUEUE_HEAD] = 0
        state[core1_module.S_QUEUE_COUNT] = len(chunk)
        start = time.perf_counter()
        done = 0
        while done < len(chunk):
            done += core1_module.servo_block(state, params, queue, empty, len(chunk) - done)
        elapsed += time.perf_counter() - start
    return elapsed


def sci_calls_per_tick(interval_dms: int, values: list[int]) -> Counter[str]:
    """How many of each scientific-notation operation one streaming tick performs."""
    counts: Counter[str] = Counter()
    originals: dict[tuple[Any, str], Callable[..., Any]] = {}

    def counting(name: str, function: Callable[..., Any]) -> Callable[..., Any]:
        def wrapper(*args: Any) -> Any:
            counts[name] += 1
            return function(*args)

        return wrapper

    for module in (core1_module, motor_module):
        for name in _SCI_NAMES:
            if hasattr(module, name):
                originals[(module, name)] = getattr(module, name)
                setattr(module, name, counting(name, getattr(module, name)))
    try:
        device = _streaming_device(interval_dms)
        for first in range(0, len(values), BATCH):
            chunk = values[first : first + BATCH]
            device.feed(f"1 {len(chunk)} {' '.join(map(str, chunk))}\n".encode())
            device.run(len(chunk))
    finally:
        for (module, name), function in originals.items():
            setattr(module, name, function)
    return Counter({name: count / len(values) for name, count in counts.items()})


def sci_seconds_per_tick(per_tick: Counter[str]) -> float:
    """Seconds the counted operations take on their own, on representative operands."""
    operands: dict[str, tuple[int, ...]] = {
        "sci_add": (1234, -3, 5678, -4, 4),
        "sci_sub": (1234, -3, 5678, -4, 4),
        "sci_mul": (1234, -3, 5678, 2, 4),
        "sci_compare": (1234, -3, 5678, -3),
        "sci_from_int": (123456, 4),
        "sci_to_int": (1234, 3),
    }
    total = 0.0
    repeats = 20_000
    for name, calls in per_tick.items():
        function = getattr(scimath, name)
        args = operands[name]
        start = time.perf_counter()
        for _ in range(repeats):
            function(*args)
        total += (time.perf_counter() - start) / repeats * calls
    return total


def idle_ticks_per_second(ticks: int) -> float:
    """Ticks per second of an enabled servo holding still (skipped in blocks)."""
    device = Device(fast=False)
    device.feed(b"3 1\n0 100\n")
    device.run(1000)
    start = time.perf_counter()
    device.run(ticks)
    return ticks / (time.perf_counter() - start)


def median_rate(measure: Callable[[], float], ticks: int, runs: int) -> float:
    """Median ticks/s over ``runs`` calls of ``measure`` (which returns elapsed seconds)."""
    return median_of(lambda: ticks / measure(), runs)


def measure(*, ticks: int, runs: int) -> dict[str, Any]:
    """All figures of the benchmark."""
    results: dict[str, Any] = {
        "python": platform.python_version(),
        "machine": platform.machine(),
        "runs": runs,
        "ticks": ticks,
        "target_ticks_s": TARGET_TICKS_S,
        "configurations": {},
    }
    for interval_dms in (10, 1):
        tick_us = interval_dms * 100
        values = trajectory(ticks, tick_us)
        streaming = median_rate(partial(run_streaming, interval_dms, values), ticks, runs)
        bare = median_rate(partial(run_core1_only, interval_dms, values), ticks, runs)
        per_tick = sci_calls_per_tick(interval_dms, values[:2000])
        sci_s = sci_seconds_per_tick(per_tick)
        results["configurations"][f"{1_000_000 // tick_us} Hz"] = {
            "tick_us": tick_us,
            "ticks_s": streaming,
            "real_time_multiple": streaming * tick_us / 1e6,
            "core1_only_ticks_s": bare,
            "sci_calls_per_tick": dict(per_tick),
            "sci_share_of_tick": sci_s * bare,
            "meets_target": streaming >= TARGET_TICKS_S,
        }
    results["idle_ticks_s"] = idle_ticks_per_second(10_000_000)
    return results


def report(results: dict[str, Any]) -> str:
    """The figures as text."""
    lines = [
        f"device_speed: reference core1 in CPython {results['python']} ({results['machine']}),"
        f" median of {results['runs']} runs of {results['ticks']} ticks",
    ]
    for name, figures in results["configurations"].items():
        calls = sum(figures["sci_calls_per_tick"].values())
        lines.append(
            f"  {name:>8}: {figures['ticks_s']:>9,.0f} ticks/s streaming"
            f" = {figures['real_time_multiple']:6.1f}x real time"
            f" (target {results['target_ticks_s']:,}: "
            f"{'met' if figures['meets_target'] else 'NOT met'});"
            f" core1 alone {figures['core1_only_ticks_s']:,.0f} ticks/s"
        )
        lines.append(
            f"            bound by CPython running the firmware's arithmetic: {calls:.1f}"
            f" scientific-notation operations per tick take"
            f" {100 * figures['sci_share_of_tick']:.0f} % of a core1 tick; core0 parsing"
            f" takes {100 * (1 - figures['ticks_s'] / figures['core1_only_ticks_s']):.0f} %"
            " of a streaming tick"
        )
    lines.append(
        f"  idle (enabled, holding still): {results['idle_ticks_s']:.2e} ticks/s"
        " (skipped in blocks up to the next event)"
    )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> dict[str, Any]:
    """Run the benchmark, print the figures (or JSON) and return them."""
    parser = argument_parser(__doc__, runs=5)
    parser.add_argument("--ticks", type=int, default=20_000, help="servo ticks per run")
    args = parse_arguments(parser, argv)
    if args.ticks < BATCH:
        parser.error(f"--ticks {args.ticks!r}: at least {BATCH}")
    return emit(measure(ticks=args.ticks, runs=args.runs), report, as_json=args.json)


if __name__ == "__main__":
    main(sys.argv[1:])
