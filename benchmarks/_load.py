"""Both cores loaded by other work: busy-loop processes for the real-time benchmarks."""

from __future__ import annotations

import contextlib
import os
import subprocess
import sys
from collections.abc import Iterator

BUSY = "while True:\n    pass\n"


@contextlib.contextmanager
def busy_cores(count: int | None = None) -> Iterator[int]:
    """``count`` busy-loop processes (default: one per CPU) for as long as the block runs;
    yields how many were started."""
    wanted = os.cpu_count() or 1 if count is None else count
    loops = [subprocess.Popen([sys.executable, "-c", BUSY]) for _ in range(wanted)]
    try:
        yield len(loops)
    finally:
        for loop in loops:
            loop.kill()
        for loop in loops:
            loop.wait()
