"""Both cores loaded by other work: busy-loop processes for the real-time benchmarks."""

from __future__ import annotations

import contextlib
import os
import sys
from collections.abc import Iterator

from _processes import reaped, start

BUSY = "while True:\n    pass\n"


@contextlib.contextmanager
def busy_cores(count: int | None = None) -> Iterator[int]:
    """``count`` busy-loop processes (default: one per CPU) for as long as the block runs,
    killed however it ends; yields how many were started."""
    wanted = os.cpu_count() or 1 if count is None else count
    with contextlib.ExitStack() as loops:
        for _ in range(wanted):
            loops.enter_context(reaped(start([sys.executable, "-c", BUSY]), grace_s=0))
        yield wanted
