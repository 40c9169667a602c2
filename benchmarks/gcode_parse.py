"""G-code parsing and interpreting speed, against gcodeparser and pygcode in the same run.

    python benchmarks/gcode_parse.py [--lines N] [--runs N] [--seed N] [--json]

A deterministic program of G0-G3 moves (every arc valid, every line with its G word, no
comments, so that every parser reads every word) is timed:

- parsing (text to blocks of words): ours (``parse_blocks``), gcodeparser
  (``GcodeParser(text)``) and pygcode (``Line(text)`` for each line; pygcode is slow, so
  it is timed on the first 10,000 lines and its rate scaled to lines/s);
- interpreting (text to typed moves): ours (``parse_gcode``).

Each figure is the median of ``--runs`` runs, the tools taking turns within each run.
``items_parsed`` is a sanity check: our blocks, gcodeparser's GcodeLine commands (a line
with several G codes makes several), pygcode's Line objects.
Targets: parsing at least 1.5x gcodeparser and 5x pygcode. A peer that is not installed
is skipped (``pip install -r benchmarks/requirements.txt``).
"""

from __future__ import annotations

import math
import random
import statistics
import sys
import warnings
from collections.abc import Callable
from typing import Any

from _common import argument_parser, emit, parse_arguments, timed
from usbmotion.motion.gcode import parse_blocks, parse_gcode

PYGCODE_SLICE_LINES = 10_000
TARGET_VS_GCODEPARSER = 1.5
TARGET_VS_PYGCODE = 5.0
INSTALL_HINT = "pip install -r benchmarks/requirements.txt"


def make_program(lines: int, *, seed: int = 2024) -> str:
    """A valid program of ``lines`` lines: G0/G1/G2/G3 moves in mm, ending with M2.

    Arc centres are given as I/J offsets rounded to 3 decimals and end points on the same
    circle rounded to 3 decimals, so every arc is within LinuxCNC's radius tolerance.
    """
    if lines < 3:
        raise ValueError(f"lines={lines!r} is too few; at least 3 (header, moves, M2)")
    rng = random.Random(seed)
    out = ["G21 G90 G17 G0 X0 Y0 Z1", "G1 Z0 F600"]
    x = y = 0.0
    z = 0.0
    for _ in range(lines - 3):
        kind = rng.random()
        if kind < 0.15 or abs(x) > 150.0 or abs(y) > 150.0:
            x = round(rng.uniform(-100.0, 100.0), 3)
            y = round(rng.uniform(-100.0, 100.0), 3)
            z = round(rng.uniform(0.0, 5.0), 3)
            out.append(f"G0 X{x:.3f} Y{y:.3f} Z{z:.3f}")
        elif kind < 0.55:
            x = round(x + rng.uniform(-20.0, 20.0), 3)
            y = round(y + rng.uniform(-20.0, 20.0), 3)
            out.append(f"G1 X{x:.3f} Y{y:.3f} F{rng.choice((300, 600, 900, 1200))}")
        else:
            radius = rng.uniform(1.0, 20.0)
            towards = rng.uniform(-math.pi, math.pi)
            i = round(radius * math.cos(towards), 3)
            j = round(radius * math.sin(towards), 3)
            cx, cy = x + i, y + j
            radius = math.hypot(i, j)
            start = math.atan2(y - cy, x - cx)
            clockwise = rng.random() < 0.5
            sweep = rng.uniform(0.2, 5.5)
            end = start - sweep if clockwise else start + sweep
            x = round(cx + radius * math.cos(end), 3)
            y = round(cy + radius * math.sin(end), 3)
            out.append(f"G{2 if clockwise else 3} X{x:.3f} Y{y:.3f} I{i:.3f} J{j:.3f}")
    out.append("M2")
    return "\n".join(out) + "\n"


def _gcodeparser() -> Callable[[str], int] | None:
    try:
        from gcodeparser import GcodeParser  # noqa: PLC0415 - an optional peer
    except ImportError:
        return None

    def run(text: str) -> int:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", DeprecationWarning)
            return len(GcodeParser(text).lines)

    return run


def _pygcode() -> Callable[[list[str]], int] | None:
    try:
        from pygcode import Line  # noqa: PLC0415 - an optional peer
    except ImportError:
        return None

    def run(lines: list[str]) -> int:
        return len([Line(line) for line in lines])

    return run


def main(argv: list[str] | None = None) -> dict[str, Any]:
    """Run the benchmark, print the figures and return them.

    Parameters:
        argv: command-line arguments (``--lines``, ``--runs``, ``--seed``, ``--json``);
            ``None`` reads ``sys.argv``.
    """
    parser = argument_parser(__doc__, runs=5)
    parser.add_argument("--lines", type=int, default=100_000, help="program length")
    parser.add_argument("--seed", type=int, default=2024, help="program generator seed")
    args = parse_arguments(parser, argv)

    text = make_program(args.lines, seed=args.seed)
    lines = text.splitlines()
    pygcode_lines = lines[:PYGCODE_SLICE_LINES]
    gcodeparser = _gcodeparser()
    pygcode = _pygcode()

    ours_parse: list[float] = []
    ours_interpret: list[float] = []
    peer_gcodeparser: list[float] = []
    peer_pygcode: list[float] = []
    blocks = moves = parsed_gcodeparser = parsed_pygcode = 0
    for _ in range(args.runs):
        blocks, seconds = timed(lambda: len(parse_blocks(text)))
        ours_parse.append(seconds)
        if gcodeparser is not None:
            parsed_gcodeparser, seconds = timed(lambda: gcodeparser(text))
            peer_gcodeparser.append(seconds)
        if pygcode is not None:
            parsed_pygcode, seconds = timed(lambda: pygcode(pygcode_lines))
            peer_pygcode.append(seconds)
        moves, seconds = timed(lambda: len(parse_gcode(text, file="<benchmark>").moves))
        ours_interpret.append(seconds)

    count = len(lines)
    ours_rate = count / statistics.median(ours_parse)
    rates: dict[str, float] = {"ours": ours_rate}
    ratios: dict[str, float] = {}
    skipped: dict[str, str] = {}
    parsed: dict[str, int] = {"ours": blocks}
    if gcodeparser is not None:
        rates["gcodeparser"] = count / statistics.median(peer_gcodeparser)
        ratios["gcodeparser"] = ours_rate / rates["gcodeparser"]
        parsed["gcodeparser"] = parsed_gcodeparser
    else:
        skipped["gcodeparser"] = f"not installed ({INSTALL_HINT})"
    if pygcode is not None:
        rates["pygcode"] = len(pygcode_lines) / statistics.median(peer_pygcode)
        ratios["pygcode"] = ours_rate / rates["pygcode"]
        parsed["pygcode"] = parsed_pygcode
    else:
        skipped["pygcode"] = f"not installed ({INSTALL_HINT})"
    result: dict[str, Any] = {
        "lines": count,
        "runs": args.runs,
        "seed": args.seed,
        "python": sys.version.split()[0],
        "parse_lines_per_s": rates,
        "parse_ratio": ratios,
        "parse_targets": {"gcodeparser": TARGET_VS_GCODEPARSER, "pygcode": TARGET_VS_PYGCODE},
        "pygcode_timed_lines": len(pygcode_lines),
        "items_parsed": parsed,
        "interpret_lines_per_s": count / statistics.median(ours_interpret),
        "moves": moves,
        "skipped": skipped,
    }
    return emit(result, report, as_json=args.json)


def report(result: dict[str, Any]) -> str:
    """The figures as text."""
    rates, ratios = result["parse_lines_per_s"], result["parse_ratio"]
    targets = result["parse_targets"]
    lines = [
        f"G-code program: {result['lines']:,} lines of G0-G3 (seed {result['seed']}), "
        f"median of {result['runs']} runs, Python {result['python']}",
        "parsing (text to blocks of words), lines/s:",
        f"  ours         {rates['ours']:>12,.0f}",
    ]
    for peer in ("gcodeparser", "pygcode"):
        if peer in rates:
            note = (
                f" (timed on the first {result['pygcode_timed_lines']:,} lines, scaled)"
                if peer == "pygcode"
                else ""
            )
            verdict = "meets" if ratios[peer] >= targets[peer] else "MISSES"
            lines.append(
                f"  {peer:<12} {rates[peer]:>12,.0f}   ours/{peer} = {ratios[peer]:.2f}x "
                f"({verdict} the {targets[peer]:g}x target){note}"
            )
        else:
            lines.append(f"  {peer:<12} skipped: {result['skipped'][peer]}")
    lines.append("interpreting (text to typed moves), lines/s:")
    lines.append(
        f"  ours         {result['interpret_lines_per_s']:>12,.0f}   ({result['moves']:,} moves)"
    )
    return "\n".join(lines)


if __name__ == "__main__":
    main()
