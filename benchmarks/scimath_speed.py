"""Speed of the firmware's scientific-notation numbers beside Python floats.

Measures operations per second of ``SciNumber`` ``* / + -`` and of the functional core on
plain ints (``sci_mul``, ``sci_div``, ``sci_add``, ``sci_sub``), each beside the same
operation on Python floats over the same operands, in the same run. Each figure is the median
of several runs (5 by default); the ratio is float ops/s divided by scimath ops/s, so it says
how many times slower the scientific-notation operation is.

Why: the device firmware computes in these numbers for fidelity (every product and quotient
truncated exactly as the RP2040's integer arithmetic truncates it), not for speed. On the
RP2040, which has no FPU, they are the fast path; in CPython they are not, and the simulated
servo loop pays their cost on every tick. These figures size that cost.

Run: ``python benchmarks/scimath_speed.py [--json] [--runs 5] [--operations 20000]``.
"""

from __future__ import annotations

import operator
import platform
import random
import sys
from collections import deque
from collections.abc import Callable
from itertools import repeat
from typing import Any

from _common import argument_parser, emit, median_of, parse_arguments, table_row, timed
from usbmotion.scimath import DEFAULT_DIGITS, SciNumber, sci_add, sci_div, sci_mul, sci_sub

MIN_RUN_S = 0.05
"""Each timed run repeats its batch until it lasts at least this long."""

OPERATIONS: dict[str, tuple[Callable[[Any, Any], Any], Callable[..., tuple[int, int]]]] = {
    "mul": (operator.mul, sci_mul),
    "div": (operator.truediv, sci_div),
    "add": (operator.add, sci_add),
    "sub": (operator.sub, sci_sub),
}


def make_operands(count: int, *, digits: int, seed: int) -> tuple[list[SciNumber], list[SciNumber]]:
    """``count`` pairs of nonzero normalised numbers; exponents close enough to add."""
    rng = random.Random(seed)
    low, high = 10 ** (digits - 1), 10**digits - 1

    def draw() -> SciNumber:
        coefficient = rng.randint(low, high) * rng.choice((1, -1))
        return SciNumber(coefficient, rng.randint(-6, 6), digits=digits)

    return [draw() for _ in range(count)], [draw() for _ in range(count)]


def ops_per_second(batch: Callable[[], None], operations: int, *, runs: int) -> float:
    """Median operations per second of ``batch`` (which performs ``operations``) over runs."""
    loops = 1

    def run_loops() -> None:
        for _ in range(loops):
            batch()

    while timed(run_loops)[1] < MIN_RUN_S:
        loops *= 2
    return median_of(lambda: loops * operations / timed(run_loops)[1], runs)


def measure(*, operations: int, runs: int, digits: int, seed: int) -> dict[str, Any]:
    """Figures for every operation: float, SciNumber and core ops/s and the two ratios."""
    xs, ys = make_operands(operations, digits=digits, seed=seed)
    floats_x = [float(x) for x in xs]
    floats_y = [float(y) for y in ys]
    c1s = [x.coefficient for x in xs]
    e1s = [x.exponent for x in xs]
    c2s = [y.coefficient for y in ys]
    e2s = [y.exponent for y in ys]

    results: dict[str, dict[str, float]] = {}
    for name, (python_op, core_op) in OPERATIONS.items():

        def on_floats(op: Callable[[Any, Any], Any] = python_op) -> None:
            deque(map(op, floats_x, floats_y), maxlen=0)

        def on_numbers(op: Callable[[Any, Any], Any] = python_op) -> None:
            deque(map(op, xs, ys), maxlen=0)

        def on_core(op: Callable[..., tuple[int, int]] = core_op) -> None:
            deque(map(op, c1s, e1s, c2s, e2s, repeat(digits)), maxlen=0)

        float_rate = ops_per_second(on_floats, operations, runs=runs)
        number_rate = ops_per_second(on_numbers, operations, runs=runs)
        core_rate = ops_per_second(on_core, operations, runs=runs)
        results[name] = {
            "float_ops_s": float_rate,
            "scinumber_ops_s": number_rate,
            "core_ops_s": core_rate,
            "scinumber_ratio": float_rate / number_rate,
            "core_ratio": float_rate / core_rate,
        }
    return {
        "benchmark": "scimath_speed",
        "python": platform.python_version(),
        "digits": digits,
        "operations_per_run": operations,
        "runs": runs,
        "statistic": "median",
        "ratio": "float ops/s divided by scimath ops/s",
        "results": results,
    }


_COLUMNS = ("<5", ">14", ">18", ">8", ">14", ">8")


def format_table(figures: dict[str, Any]) -> str:
    """The figures as a fixed-width table."""
    header = table_row(
        ("op", "float ops/s", "SciNumber ops/s", "ratio", "core ops/s", "ratio"), _COLUMNS
    )
    lines = [
        f"scimath speed (digits={figures['digits']}, Python {figures['python']}, "
        f"median of {figures['runs']} runs; ratio = float ops/s / scimath ops/s)",
        header,
        "-" * len(header),
    ]
    for name, row in figures["results"].items():
        lines.append(
            table_row(
                (
                    name,
                    f"{row['float_ops_s']:,.0f}",
                    f"{row['scinumber_ops_s']:,.0f}",
                    f"{row['scinumber_ratio']:.1f}x",
                    f"{row['core_ops_s']:,.0f}",
                    f"{row['core_ratio']:.1f}x",
                ),
                _COLUMNS,
            )
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> dict[str, Any]:
    """Run the benchmark, print a table (or JSON with ``--json``) and return the figures."""
    parser = argument_parser(__doc__, runs=5)
    parser.add_argument("--operations", type=int, default=20_000, help="operand pairs per batch")
    parser.add_argument("--seed", type=int, default=2040, help="operand random seed")
    args = parse_arguments(parser, argv)
    if args.operations < 1:
        parser.error(f"--operations {args.operations!r} must be at least 1")
    figures = measure(
        operations=args.operations, runs=args.runs, digits=DEFAULT_DIGITS, seed=args.seed
    )
    return emit(figures, format_table, as_json=args.json)


if __name__ == "__main__":
    main(sys.argv[1:])
