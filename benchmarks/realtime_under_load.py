"""Every real-time test, run again and again with both cores loaded: how often each passes.

    python benchmarks/realtime_under_load.py [--rounds 20] [--load N] [--json]

Starts ``--load`` busy-loop processes (default: one per core) and, while they run, runs
``pytest -m realtime`` ``--rounds`` times (each round in a fresh process, so every test
gets its own devices and hosts), then prints, for every real-time test, how many rounds it
passed. A test that fails one round in ten is a defect, in the test or in the product.
"""

from __future__ import annotations

import signal
import sys
import tempfile
import time
from pathlib import Path
from typing import Any
from xml.etree import ElementTree

from _common import argument_parser, emit, parse_arguments
from _load import busy_cores
from _processes import run

ROOT = Path(__file__).resolve().parents[1]
ROUND_TIMEOUT_S = 1800
"""The most one round of the real-time tests may take."""


def _round(report: Path) -> dict[str, str | None]:
    """One ``pytest -m realtime`` run: test id -> None if it passed, else why it failed
    (the first line of its failure message)."""
    # SIGINT first if it must stop: pytest then tears its fixtures down (their servers too)
    run([sys.executable, "-m", "pytest", "-m", "realtime", "-q", "-p", "no:cacheprovider",
         f"--junitxml={report}"], cwd=ROOT, timeout_s=ROUND_TIMEOUT_S, grace_s=30,
        first_signal=signal.SIGINT)
    results: dict[str, str | None] = {}
    for case in ElementTree.parse(report).getroot().iter("testcase"):
        name = f"{case.get('classname')}::{case.get('name')}"
        failed = [child for child in case if child.tag in ("failure", "error")]
        results[name] = None if not failed else (
            (failed[0].get("message") or failed[0].tag).splitlines() or [failed[0].tag])[0][:300]
    return results


def measure(rounds: int, load: int | None) -> dict[str, Any]:
    """Pass counts per real-time test over ``rounds`` rounds under load."""
    passes: dict[str, int] = {}
    seen: dict[str, int] = {}
    why: dict[str, list[str]] = {}
    started = time.monotonic()
    with busy_cores(load) as loops, tempfile.TemporaryDirectory() as folder:
        for index in range(rounds):
            for name, failure in _round(Path(folder) / f"round-{index}.xml").items():
                seen[name] = seen.get(name, 0) + 1
                passes[name] = passes.get(name, 0) + int(failure is None)
                if failure is not None:
                    why.setdefault(name, []).append(f"round {index + 1}: {failure}")
    return {"rounds": rounds, "busy_loops": loops, "wall_s": time.monotonic() - started,
            "passed": {name: passes[name] for name in sorted(seen)},
            "ran": {name: seen[name] for name in sorted(seen)},
            "failures": {name: why[name] for name in sorted(why)}}


def _text(figures: dict[str, Any]) -> str:
    lines = [f"{figures['rounds']} rounds of every real-time test with {figures['busy_loops']}"
             f" busy loops loading the cores ({figures['wall_s'] / 60:.1f} min)"]
    for name, passed in figures["passed"].items():
        lines.append(f"  {passed:3d} / {figures['ran'][name]:<3d} {name}")
        lines.extend(f"        {failure}" for failure in figures["failures"].get(name, ()))
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = argument_parser(__doc__, runs=1)
    parser.add_argument("--rounds", type=int, default=20)
    parser.add_argument("--load", type=int, default=None, help="busy loops (default: cores)")
    args = parse_arguments(parser, argv)
    return emit(measure(args.rounds, args.load), _text, as_json=args.json)


if __name__ == "__main__":
    main()
