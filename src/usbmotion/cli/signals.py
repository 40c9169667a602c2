"""Ctrl-C and SIGTERM while a command drives a machine: a stop along the deceleration."""

from __future__ import annotations

import signal
from collections.abc import Iterator
from contextlib import contextmanager
from types import FrameType
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from usbmotion.session import MachineSession


@contextmanager
def stop_on_signals(session: MachineSession) -> Iterator[None]:
    """While inside: SIGINT and SIGTERM ask ``session`` to stop (a second one: at once)."""
    from usbmotion.session.state import StopReason  # noqa: PLC0415 - keeps --help fast

    reasons = {signal.SIGINT: StopReason.USER.value, signal.SIGTERM: StopReason.TERMINATED.value}

    def on_signal(signum: int, frame: FrameType | None) -> None:
        session.request_stop(reasons.get(signal.Signals(signum), StopReason.USER.value))

    previous = {sig: signal.signal(sig, on_signal) for sig in reasons}
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
