"""Speed of the motion planner, the sampler and the Hermite tick evaluation.

A seeded random program of G0-G3 moves (``Move`` objects: 10% rapids, 50% lines, 40% arcs
in all three planes, a fifth of them helical, radii 0.5-20 mm, sweeps 10-270 degrees) is
planned with ``plan_moves``; the figure is input moves per second (and the chords they
become). A lines-only program of the same length shows the per-move Python cost alone.

The plan of the first ``--sample-moves`` moves is sampled with ``sample_plan`` at 1 ms and
at 0.1 ms; the figure is axis-setpoints per second (3 axes). The same-run reference is
``numpy.interp`` over the same sample times and the plan's vertices (piecewise-linear
interpolation of each axis, no rounding): the cheapest vectorised interpolation there is.

Hermite: ``sample_keyframes`` against one ``hermite_position`` call per tick (how the
device's curve mode evaluates), in ticks per second.

The peer, in the same run when a Klipper checkout is given (``--klipper PATH`` or
``KLIPPER_PATH``): Klipper's own arc segmentation (1 mm chords) and look-ahead planning the
same mixed program (``_klipper_peer.py`` says what is and is not included), in input moves
per second. Target: the mixed program at 200,000 moves/s.

Every figure is the median of ``--runs`` runs (5 by default).

Run: ``python benchmarks/planner_speed.py [--json] [--runs 5] [--moves 100000]
[--klipper PATH]``.
"""

from __future__ import annotations

import math
import os
import platform
import sys
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from _common import argument_parser, emit, median_seconds, table_row
from _klipper_peer import KlipperPlanner
from usbmotion.hermite import Keyframe, hermite_position, sample_keyframes
from usbmotion.motion.moves import Arc, Linear, Move, Plane, Point, Rapid
from usbmotion.motion.planner import AxisLimits, Plan, PlannerConfig, plan_moves
from usbmotion.motion.sampler import sample_plan, sample_times

LIMITS = (AxisLimits(250.0, 2000.0), AxisLimits(250.0, 2000.0), AxisLimits(80.0, 800.0))
COUNTS_PER_MM = (1000.0, 1000.0, 2000.0)
PLANES = (Plane.XY, Plane.XZ, Plane.YZ)
TARGET_MIXED_MOVES_S = 200_000


def random_program(count: int, *, seed: int, arcs: bool = True) -> list[Move]:
    """``count`` connected moves from the origin (see the module docstring for the mix)."""
    rng = np.random.default_rng(seed)
    kind = rng.random(count)
    unit = rng.random((count, 8))
    moves: list[Move] = []
    position: Point = (0.0, 0.0, 0.0)
    for i in range(count):
        u = unit[i]
        roll = kind[i]
        line = i + 1
        if roll < 0.1:
            end = (200.0 * u[0] - 100.0, 200.0 * u[1] - 100.0, 20.0 * u[2])
            moves.append(Rapid(line, position, end))
        elif roll < 0.6 or not arcs:
            length = 0.1 + 20.0 * u[0]
            heading = 2.0 * math.pi * u[1]
            end = (
                position[0] + length * math.cos(heading),
                position[1] + length * math.sin(heading),
                min(20.0, max(0.0, position[2] + 2.0 * u[2] - 1.0)),
            )
            moves.append(Linear(line, position, end, 300.0 + 5700.0 * u[3]))
        else:
            plane = PLANES[0 if u[0] < 0.7 else (1 if u[0] < 0.85 else 2)]
            first, second, normal = plane.axes
            radius = 0.5 + 19.5 * u[1]
            start_angle = 2.0 * math.pi * u[2]
            sweep = math.radians(10.0 + 260.0 * u[3])
            rotation = 1 if u[4] < 0.5 else -1
            centre = list(position)
            centre[first] -= radius * math.cos(start_angle)
            centre[second] -= radius * math.sin(start_angle)
            end_angle = start_angle + rotation * sweep
            end_list = list(position)
            end_list[first] = centre[first] + radius * math.cos(end_angle)
            end_list[second] = centre[second] + radius * math.sin(end_angle)
            if u[5] < 0.2:
                end_list[normal] += 4.0 * u[6] - 2.0
            end = (end_list[0], end_list[1], end_list[2])
            moves.append(
                Arc(
                    line,
                    position,
                    end,
                    (centre[0], centre[1], centre[2]),
                    plane,
                    rotation,
                    300.0 + 3700.0 * u[7],
                )
            )
        position = end
    return moves


def interp_reference(plan: Plan, period_s: float) -> np.ndarray:
    """Piecewise-linear positions at the same sample times by ``numpy.interp`` (reference)."""
    times = sample_times(plan, period_s)
    knots = np.concatenate((plan.start_time_s, [plan.duration_s]))
    return np.stack(
        [np.interp(times, knots, plan.vertices_mm[:, axis]) for axis in range(3)], axis=1
    )


def hermite_keyframes(count: int, *, seed: int) -> list[Keyframe]:
    """``count`` random keyframes of 20-200 ms."""
    rng = np.random.default_rng(seed)
    return [
        Keyframe(
            int(rng.integers(20, 200)),
            int(rng.integers(-100_000, 100_000)),
            int(rng.integers(-20_000, 20_000)),
            int(rng.integers(-20_000, 20_000)),
        )
        for _ in range(count)
    ]


def hermite_loop(start: int, keyframes: list[Keyframe], tick_us: int) -> list[int]:
    """One ``hermite_position`` call per tick, as the device evaluates (reference)."""
    values = []
    previous_position, previous_tangent = start, 0
    for keyframe in keyframes:
        span_us = keyframe.duration_ms * 1000
        for elapsed in range(tick_us, span_us + 1, tick_us):
            values.append(
                hermite_position(
                    previous_position,
                    keyframe.position_counts,
                    previous_tangent,
                    keyframe.tangent_in,
                    keyframe.duration_ms,
                    elapsed,
                )
            )
        previous_position, previous_tangent = keyframe.position_counts, keyframe.tangent_out
    return values


def main(argv: list[str] | None = None) -> dict[str, Any]:
    """Run the benchmark, print a table (or JSON with ``--json``), return the figures."""
    parser = argument_parser(__doc__, runs=5)
    parser.add_argument("--moves", type=int, default=100_000, help="moves in the program")
    parser.add_argument(
        "--sample-moves", type=int, default=3_000, help="moves of the program to sample"
    )
    parser.add_argument("--seed", type=int, default=20260101)
    parser.add_argument("--klipper", type=Path, default=os.environ.get("KLIPPER_PATH"),
                        help="a Klipper checkout, to plan the same program with (the peer)")
    args = parser.parse_args(argv)
    runs = max(1, args.runs)

    config = PlannerConfig()
    program = random_program(args.moves, seed=args.seed)
    plan = plan_moves(program, LIMITS, config)
    plan_s = median_seconds(lambda: plan_moves(program, LIMITS, config), runs)
    lines = random_program(args.moves, seed=args.seed, arcs=False)
    lines_s = median_seconds(lambda: plan_moves(lines, LIMITS, config), runs)

    figures: dict[str, Any] = {
        "python": platform.python_version(),
        "numpy": np.__version__,
        "machine": platform.machine(),
        "runs": runs,
        "moves": args.moves,
        "arc_moves": sum(isinstance(m, Arc) for m in program),
        "segments": len(plan),
        "program_duration_s": plan.duration_s,
        "plan_moves_per_s": args.moves / plan_s,
        "plan_segments_per_s": len(plan) / plan_s,
        "plan_lines_only_moves_per_s": args.moves / lines_s,
        "target_mixed_moves_per_s": TARGET_MIXED_MOVES_S,
        "sampling": [],
        "klipper": None,
    }
    if args.klipper is not None:
        peer = KlipperPlanner(Path(args.klipper), max_velocity=max(a.velocity_mm_s for a in LIMITS),
                              max_accel=max(a.accel_mm_s2 for a in LIMITS),
                              junction_deviation_mm=config.junction_deviation_mm)
        chords = peer.plan(program)
        peer_s = median_seconds(lambda: peer.plan(program), runs)
        figures["klipper"] = {"source": peer.version, "planned_moves": chords,
                              "plan_moves_per_s": args.moves / peer_s,
                              "ratio": plan_s and peer_s / plan_s}

    part = plan_moves(program[: args.sample_moves], LIMITS, config)
    for period_s in (0.001, 0.0001):
        setpoints = sample_plan(part, period_s=period_s, counts_per_mm=COUNTS_PER_MM)
        sample_s = median_seconds(
            partial(sample_plan, part, period_s=period_s, counts_per_mm=COUNTS_PER_MM), runs
        )
        interp_s = median_seconds(partial(interp_reference, part, period_s), runs)
        figures["sampling"].append(
            {
                "period_s": period_s,
                "program_duration_s": part.duration_s,
                "axis_setpoints": int(setpoints.size),
                "axis_setpoints_per_s": setpoints.size / sample_s,
                "interp_axis_setpoints_per_s": setpoints.size / interp_s,
                "ratio_to_interp": interp_s / sample_s,
            }
        )

    keyframes = hermite_keyframes(200, seed=args.seed)
    tick_us = 1000
    ticks = len(sample_keyframes(0, keyframes, tick_us=tick_us))
    vector_s = median_seconds(lambda: sample_keyframes(0, keyframes, tick_us=tick_us), runs)
    loop_s = median_seconds(lambda: hermite_loop(0, keyframes, tick_us), max(1, runs // 2))
    figures["hermite"] = {
        "ticks": ticks,
        "sample_keyframes_ticks_per_s": ticks / vector_s,
        "hermite_position_loop_ticks_per_s": ticks / loop_s,
        "ratio": loop_s / vector_s,
    }

    return emit(figures, report, as_json=args.json)


_COLUMNS = ("<44", ">16")


def _line(figure: str, value: str, note: str = "") -> str:
    return table_row((figure, value), _COLUMNS) + (f"  {note}" if note else "")


def report(figures: dict[str, Any]) -> str:
    """The figures as a plain table."""
    lines = [
        f"planner_speed: Python {figures['python']}, numpy {figures['numpy']}, "
        f"{figures['machine']}, median of {figures['runs']} runs",
        f"program: {figures['moves']:,} moves ({figures['arc_moves']:,} arcs) -> "
        f"{figures['segments']:,} segments, {figures['program_duration_s']:,.0f} s of motion",
        "",
        _line("figure", "value", "target"),
        _line(
            "plan_moves, mixed program (moves/s)", f"{figures['plan_moves_per_s']:,.0f}",
            f"{figures['target_mixed_moves_per_s']:,}"
        ),
        _line("plan_moves, mixed program (segments/s)", f"{figures['plan_segments_per_s']:,.0f}"),
        _line("plan_moves, lines only (moves/s)", f"{figures['plan_lines_only_moves_per_s']:,.0f}"),
    ]
    peer = figures["klipper"]
    if peer is None:
        lines.append(_line("  Klipper, same program (moves/s)", "-",
                           "(not measured: --klipper PATH of a Klipper checkout)"))
    else:
        lines.append(_line("  Klipper, same program (moves/s)", f"{peer['plan_moves_per_s']:,.0f}",
                           f"({peer['planned_moves']:,} planned moves with 1 mm arc chords;"
                           f" plan_moves is {peer['ratio']:.2f}x its speed)"))
    for row in figures["sampling"]:
        lines.append(
            _line(
                f"sample_plan at {row['period_s'] * 1000:g} ms (axis-setpoints/s)",
                f"{row['axis_setpoints_per_s']:,.0f}",
                "5,000,000",
            )
        )
        lines.append(
            _line(
                "  numpy.interp, same times (axis-setpoints/s)",
                f"{row['interp_axis_setpoints_per_s']:,.0f}",
                f"(sample_plan is {row['ratio_to_interp']:.2f}x its speed)",
            )
        )
    hermite = figures["hermite"]
    lines.append(
        _line("sample_keyframes (ticks/s)", f"{hermite['sample_keyframes_ticks_per_s']:,.0f}")
    )
    lines.append(
        _line(
            "  hermite_position per tick (ticks/s)",
            f"{hermite['hermite_position_loop_ticks_per_s']:,.0f}",
            f"(sample_keyframes is {hermite['ratio']:.1f}x faster)",
        )
    )
    return "\n".join(lines)


if __name__ == "__main__":
    main(sys.argv[1:])
