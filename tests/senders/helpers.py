"""What the sender tests share: skipping (or, in CI, failing) when a sender is not
installed, the fake machine served in real time, and the program they stream."""

from __future__ import annotations

import json
import math
import os
import shutil
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest
from tests.grbl.fake_machine import FakeMachine

from usbmotion.grbl.protocol import Statistics
from usbmotion.grbl.server import GrblServer

HERE = Path(__file__).resolve().parent
MEASUREMENTS = HERE.parents[1] / "build" / "senders"
"""Where each sender test records what it measured (build/ is not committed)."""
NODE_MODULES = HERE / "node_modules"
INSTALL = "bash tests/senders/install.sh"


def need(available: bool, what: str) -> None:
    """Skip the test when ``what`` is missing; in CI (``CI=true``) fail instead."""
    if available:
        return
    text = f"{what} is not installed: run `{INSTALL}`"
    if os.environ.get("CI") == "true":
        pytest.fail(text, pytrace=False)
    pytest.skip(text)


def node_package(name: str) -> bool:
    """True when the npm package ``name`` is installed under tests/senders/node_modules."""
    return (NODE_MODULES / name / "package.json").is_file() and shutil.which("node") is not None


SEGMENTS = 72
"""The circle's segments: short moves, so the planner and the receive buffer both fill."""


def _circle() -> list[tuple[float, float]]:
    points = []
    for index in range(1, SEGMENTS + 1):
        angle = 2 * math.pi * index / SEGMENTS
        points.append((round(10 + 10 * math.cos(angle), 3), round(10 + 10 * math.sin(angle), 3)))
    return points


PROGRAM = "\n".join([
    "G21 G90 G54 (a 20 mm square with its diagonal, then a circle in 72 segments)",
    "G0 X0 Y0 Z1",
    "G1 Z0 F600",
    "G1 X20 F3000",
    "G1 Y20",
    "G1 X10 Y20",
    "G1 X0 Y20",
    "G1 Y0",
    "G1 X20 Y20",
    *(f"G1 X{x:.3f} Y{y:.3f}" for x, y in _circle()),
    "G0 Z1",
    "G0 X0 Y0",
    "M2",
]) + "\n"
PROGRAM_LINES = PROGRAM.count("\n")

PROGRAM_PATH = [
    (0.0, 0.0, 1.0), (0.0, 0.0, 0.0), (20.0, 0.0, 0.0), (20.0, 20.0, 0.0),
    (10.0, 20.0, 0.0), (0.0, 20.0, 0.0), (0.0, 0.0, 0.0), (20.0, 20.0, 0.0),
    *((x, y, 0.0) for x, y in _circle()),
    (20.0, 10.0, 1.0), (0.0, 0.0, 1.0),
]
"""Where each move of :data:`PROGRAM` ends, machine coordinates (no work offset)."""


@contextmanager
def served_fake(**server_options: object) -> Iterator[tuple[GrblServer, FakeMachine]]:
    """The fake machine in real time, served on a pseudo-terminal (or as asked). Only the
    server's thread may call the machine; a test reads its plain attributes."""
    machine = FakeMachine(time.monotonic, homing_s=1.0)  # long enough to be seen in reports
    with GrblServer(machine, **server_options) as server:  # type: ignore[arg-type]
        server.start()
        yield server, machine
        assert server.error is None


def wait_for(condition: object, *, timeout_s: float, what: str) -> None:
    """Poll ``condition()`` until true; fail saying ``what`` did not happen."""
    deadline = time.monotonic() + timeout_s
    while not condition():  # type: ignore[operator]
        if time.monotonic() > deadline:
            raise AssertionError(f"{what} did not happen within {timeout_s} s")
        time.sleep(0.01)


def record(sender: str, statistics: Statistics, *, path_problems: list[str]) -> None:
    """Record what the front measured while ``sender`` streamed, in
    ``build/senders/SENDER.json``, and print it (seen with ``pytest -s``)."""
    measured = {"sender": sender, "max_rx_bytes": statistics.max_rx_bytes,
                "rx_buffer_bytes": 128, "dropped_rx_bytes": statistics.dropped_rx_bytes,
                "lines": statistics.lines, "path_equals_program": not path_problems,
                "path_problems": path_problems}
    MEASUREMENTS.mkdir(parents=True, exist_ok=True)
    (MEASUREMENTS / f"{sender}.json").write_text(json.dumps(measured, indent=2) + "\n")
    print(f"{sender}: receive buffer at most {statistics.max_rx_bytes} of 128 bytes,"
          f" {statistics.dropped_rx_bytes} dropped, {statistics.lines} lines,"
          f" path {'equals the program' if not path_problems else 'differs'}")
