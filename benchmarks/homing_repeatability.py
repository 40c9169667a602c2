"""Homing repeatability in real time with both cores loaded: the same machine zero every time.

    python benchmarks/homing_repeatability.py [--homings 50] [--load N] [--json]

Serves three simulated devices on pseudo-terminals (``usbmotion sim --pty 3``, another
process), connects a machine session to them and homes it ``--homings`` times, moving each
axis to a random place inside its travel between homings, while ``--load`` busy-loop
processes (default: one per core) load the machine. Each homing after the first shifts the
device counters (call 37) by what the new zero differs from the previous one: a repeatable
zero shifts by 0 counts. The same run also reports where a host that zeroes on the position
it polled (at 50 Hz) when it saw the switch close would have put the zero, the way homing
worked before the devices latched their switch edges: the peer, measured in the same run.
"""

from __future__ import annotations

import random
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from _common import argument_parser, emit, parse_arguments
from _load import busy_cores
from _processes import sigterm_unwinds
from reliability.bench import bench_machine, served
from usbmotion.host.config import load_config
from usbmotion.session import MachineSession


def measure(homings: int, load: int | None, seed: int = 7) -> dict[str, Any]:
    """Home ``homings`` times under load; per axis, the spread of the zero's shifts and of a
    polled zero's offsets, counts."""
    rng = random.Random(seed)
    shifts: dict[str, list[int]] = {}
    polled: dict[str, list[int]] = {}
    seconds: list[float] = []
    with (sigterm_unwinds(), tempfile.TemporaryDirectory() as folder,
          served(Path(folder) / "flash") as paths):
        machine_file = bench_machine(Path(folder), paths, watchdog_ms=0)
        config = load_config(machine_file)
        with busy_cores(load) as loops, MachineSession.connect(config) as session:
            for index in range(homings):
                started = time.monotonic()
                session.home()
                seconds.append(time.monotonic() - started)
                for name, zero in session.zeroes.items():
                    if index:
                        shifts.setdefault(name, []).append(zero.shift_counts)
                    polled.setdefault(name, []).append(zero.seen_counts - zero.edge_counts)
                x, y, z = (rng.uniform(2.0, 20.0) for _ in range(3))
                prepared = session.prepare("away.ngc",
                                           text=f"G21 G90\nG0 X{x:.3f} Y{y:.3f} Z{-z:.3f}\nM2\n")
                report, _ = session.run(prepared)
                if not report.completed:
                    raise RuntimeError(f"the move away failed: {report.stop_reason}")
            session.shutdown()
    return {
        "homings": homings,
        "busy_loops": loops,
        "median_homing_s": statistics.median(seconds),
        "shift_spread_counts": {n: max(v) - min(v) for n, v in shifts.items()},
        "shift_counts": {n: sorted(set(v)) for n, v in shifts.items()},
        "polled_spread_counts": {n: max(v) - min(v) for n, v in polled.items()},
        "polled_offsets_counts": {n: sorted(set(v)) for n, v in polled.items()},
    }


def _text(figures: dict[str, Any]) -> str:
    lines = [f"{figures['homings']} homings in real time, {figures['busy_loops']} busy loops"
             f" loading the cores; median homing {figures['median_homing_s']:.2f} s",
             "axis  latched-edge zero: spread (shifts seen)   polled zero: spread (offsets)"]
    for name in sorted(figures["shift_spread_counts"]):
        lines.append(
            f"{name}     {figures['shift_spread_counts'][name]:3d} counts"
            f" {figures['shift_counts'][name]!s:<22}"
            f"  {figures['polled_spread_counts'][name]:3d} counts"
            f" {figures['polled_offsets_counts'][name]}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = argument_parser(__doc__, runs=1)
    parser.add_argument("--homings", type=int, default=50)
    parser.add_argument("--load", type=int, default=None, help="busy loops (default: cores)")
    args = parse_arguments(parser, argv)
    return emit(measure(args.homings, args.load), _text, as_json=args.json)


if __name__ == "__main__":
    main()
