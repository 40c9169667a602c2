"""How many examples a fuzz property runs, and a guard that turns a hang into a failure."""

from __future__ import annotations

import contextlib
import os
import signal
from collections.abc import Iterator
from types import FrameType

from hypothesis import HealthCheck, settings

ENV = "USBMOTION_FUZZ_EXAMPLES"
"""Environment variable: examples per fuzz property (``make fuzz`` sets 100000)."""
DEFAULT_EXAMPLES = 300
"""Examples per property when the variable is not set (the quick run of ``make test``)."""
HANG_S = 10.0
"""One example running longer than this is a hang: the example fails."""


def examples(quick: int = DEFAULT_EXAMPLES) -> int:
    """Examples per property, from ``USBMOTION_FUZZ_EXAMPLES``; ``quick`` when it is not set.

    Raises:
        ValueError: the variable is set but is not a whole number >= 1.
    """
    text = os.environ.get(ENV, "").strip()
    if not text:
        return quick
    try:
        count = int(text.replace("_", ""))
    except ValueError:
        count = 0
    if count < 1:
        raise ValueError(f"{ENV} {text!r} is not a whole number >= 1")
    return count


def fuzz_settings(*, quick: int = DEFAULT_EXAMPLES) -> settings:
    """Hypothesis settings of a fuzz property: the example budget, no deadline.

    ``quick``: the examples of the quick run (the variable not set), for a property whose
    examples cost several times the others'; the long run gives every property the
    variable's budget. A hang is caught by :func:`hang_guard` instead of a deadline, so a
    slow shared machine does not make a property flaky.
    """
    return settings(
        max_examples=examples(quick),
        deadline=None,
        suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
    )


class HangError(AssertionError):
    """An example ran longer than :data:`HANG_S`."""


@contextlib.contextmanager
def hang_guard(limit_s: float = HANG_S) -> Iterator[None]:
    """Fail the example with :class:`HangError` if the block runs longer than ``limit_s``.

    Uses the real-time interval timer (main thread, POSIX); where there is none the block
    runs unguarded and pytest's own timeout is the backstop.
    """
    if not hasattr(signal, "setitimer"):
        yield
        return

    def on_alarm(signum: int, frame: FrameType | None) -> None:
        raise HangError(f"one example ran longer than {limit_s:g} s")

    previous = signal.signal(signal.SIGALRM, on_alarm)
    signal.setitimer(signal.ITIMER_REAL, limit_s)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)
