"""What the benchmark scripts share: timing, medians of runs, their options and their output.

The scripts import it as ``_common``: run as ``python benchmarks/NAME.py`` their folder is
the first entry of ``sys.path``, and ``run_all.py`` puts the folder there before importing
them.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time
from collections.abc import Callable, Mapping, Sequence
from typing import Any, TypeVar

T = TypeVar("T")
Figures = TypeVar("Figures", bound=Mapping[str, Any])


def command_environment(**settings: str) -> dict[str, str]:
    """The environment a timed ``usbmotion`` command runs in: this one, with ``settings``,
    and with Python's bytecode cache written and read as an installed package has it
    (``PYTHONDONTWRITEBYTECODE``, which some shells set, would have every run compile the
    package's modules again: about 0.14 s a run)."""
    env = {**os.environ, **settings}
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    return env


def timed(action: Callable[[], T]) -> tuple[T, float]:
    """What ``action()`` returns, and the wall seconds it took."""
    started = time.perf_counter()
    result = action()
    return result, time.perf_counter() - started


def median_of(measure: Callable[[], float], runs: int) -> float:
    """The median of ``runs`` calls of ``measure`` (a time, a rate: whatever it returns)."""
    return statistics.median(measure() for _ in range(runs))


def median_seconds(action: Callable[[], object], runs: int) -> float:
    """The median wall seconds of ``runs`` calls of ``action``."""
    return median_of(lambda: timed(action)[1], runs)


def argument_parser(doc: str | None, *, runs: int) -> argparse.ArgumentParser:
    """A parser described by the first line of ``doc``, with the options of every benchmark.

    Parameters:
        doc: the script's docstring.
        runs: the default of ``--runs``, the number of runs each figure is the median of.
            ``--json`` prints the figures as JSON instead of text.
    """
    parser = argparse.ArgumentParser(description=doc.splitlines()[0] if doc else None)
    parser.add_argument("--runs", type=int, default=runs, help="runs per figure (median)")
    parser.add_argument("--json", action="store_true", help="print the figures as JSON")
    return parser


def parse_arguments(parser: argparse.ArgumentParser, argv: list[str] | None) -> argparse.Namespace:
    """``argv`` parsed by ``parser``; exits with a usage error when ``--runs`` is below 1."""
    args = parser.parse_args(argv)
    if args.runs < 1:
        parser.error(f"--runs {args.runs!r}: at least 1")
    return args


def table_row(cells: Sequence[str], columns: Sequence[str], *, gap: str = "") -> str:
    """One line of a fixed-width table.

    Parameters:
        cells: the cells' text, one per column.
        columns: each column's alignment and width as a format spec (``"<9"``, ``">16"``),
            the same for the header and every row.
        gap: what stands between two columns.
    """
    return gap.join(f"{cell:{column}}" for cell, column in zip(cells, columns, strict=True))


def emit(figures: Figures, text: Callable[[Figures], str], *, as_json: bool) -> Figures:
    """Print ``figures`` as JSON (``as_json``) or as ``text(figures)``, and return them."""
    print(json.dumps(figures, indent=2) if as_json else text(figures))
    return figures
