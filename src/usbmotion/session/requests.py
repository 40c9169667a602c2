"""The operator's requests: hold, resume, stop, jog cancel and the overrides wait in one
queue, put from any thread or a signal handler, and the machine takes them at defined
points (a run's every look at the devices, homing's every poll, a wait for rest, and
whenever the session starts something). What was taken is :class:`Taken`: plain fields the
thread that drives the machine reads.

A feed hold asked while nothing runs is latched, as grbl latches it: the next motion starts
held and waits for the resume.
"""

from __future__ import annotations

import queue
from dataclasses import dataclass, field
from enum import Enum

from usbmotion.errors import ArgumentError

FEED_OVERRIDE_RANGE = (10, 200)
"""The feed override's range, percent (grbl's)."""
RAPID_OVERRIDES = (25, 50, 100)
"""The rapid override's values, percent (grbl's)."""


class RequestKind(Enum):
    """What the operator asks."""

    HOLD = "hold"
    RESUME = "resume"
    STOP = "stop"
    JOG_CANCEL = "jog cancel"
    FEED_OVERRIDE = "feed override"
    RAPID_OVERRIDE = "rapid override"


@dataclass(frozen=True, slots=True)
class Request:
    """One request: its kind, its value (an override's percent), a stop's reason, and when
    it was asked (the session's clock)."""

    kind: RequestKind
    at_s: float
    value: int = 0
    reason: str = ""


def check_feed_override(percent: int) -> int:
    """``percent`` when it is a feed override grbl allows.

    Raises:
        ArgumentError: not a whole number within 10 .. 200.
    """
    low, high = FEED_OVERRIDE_RANGE
    if isinstance(percent, bool) or not isinstance(percent, int) or not low <= percent <= high:
        raise ArgumentError(f"feed override {percent!r} %: a whole percentage within"
                            f" {low} .. {high}", reason="feed_override")
    return percent


def check_rapid_override(percent: int) -> int:
    """``percent`` when it is a rapid override grbl allows.

    Raises:
        ArgumentError: not one of 25, 50, 100.
    """
    if isinstance(percent, bool) or percent not in RAPID_OVERRIDES:
        allowed = ", ".join(map(str, RAPID_OVERRIDES))
        raise ArgumentError(f"rapid override {percent!r} %: one of {allowed}",
                            reason="rapid_override")
    return percent


@dataclass(slots=True)
class Taken:
    """The requests taken so far, as the machine acts on them.

    Fields:
        stop_reason: why a stop was asked ("" when none was).
        stop_count: how many stops were asked (a second one stops at once).
        stop_at_s: when the first stop was asked.
        hold: a hold was asked and no resume has released it yet.
        hold_at_s: when that hold was asked.
        resume: a resume was asked for a hold or a pause.
        jog_cancel: a jog cancel was asked.
        feed_override, rapid_override: percent, as last asked.
        override_at_s: when an override last changed.
    """

    stop_reason: str = ""
    stop_count: int = 0
    stop_at_s: float = 0.0
    hold: bool = False
    hold_at_s: float = 0.0
    resume: bool = False
    jog_cancel: bool = False
    feed_override: int = 100
    rapid_override: int = 100
    override_at_s: float = 0.0
    log: list[Request] = field(default_factory=list)
    """The last requests taken, oldest first (at most 64)."""

    @property
    def stop_now(self) -> bool:
        """A second stop was asked: stop at once."""
        return self.stop_count >= 2


class RequestQueue:
    """The queue of the operator's requests (``put`` is safe from any thread and from a
    signal handler) and what the machine took of them (:attr:`taken`)."""

    def __init__(self) -> None:
        self._queue: queue.SimpleQueue[Request] = queue.SimpleQueue()
        self.taken = Taken()

    def put(self, request: Request) -> None:
        """Queue ``request`` for the machine to take (reentrant: a signal handler may)."""
        self._queue.put(request)

    def take(self) -> list[Request]:
        """Take every request waiting, in order, into :attr:`taken`; returns them."""
        if self._queue.empty():
            return []
        taken = self.taken
        requests: list[Request] = []
        while True:
            try:
                request = self._queue.get_nowait()
            except queue.Empty:
                break
            requests.append(request)
            _apply(taken, request)
        if requests:
            taken.log = (taken.log + requests)[-64:]
        return requests

    def clear_stop(self) -> None:
        """Forget a stop (and a jog cancel) once it is done; holds and overrides stay."""
        self.take()
        taken = self.taken
        taken.stop_reason, taken.stop_count, taken.stop_at_s = "", 0, 0.0
        taken.jog_cancel = False

    def clear_hold(self) -> None:
        """Forget a hold and a resume (the run that held ended)."""
        self.taken.hold = self.taken.resume = False


def _apply(taken: Taken, request: Request) -> None:
    kind = request.kind
    if kind is RequestKind.STOP:
        taken.stop_count += 1
        if not taken.stop_reason:
            taken.stop_reason = request.reason
            taken.stop_at_s = request.at_s
    elif kind is RequestKind.JOG_CANCEL:
        taken.jog_cancel = True
    elif kind is RequestKind.HOLD:
        if not taken.hold:
            taken.hold = True
            taken.hold_at_s = request.at_s
            taken.resume = False
    elif kind is RequestKind.RESUME:
        taken.resume = True
    elif kind is RequestKind.FEED_OVERRIDE:
        taken.feed_override = request.value
        taken.override_at_s = request.at_s
    elif kind is RequestKind.RAPID_OVERRIDE:
        taken.rapid_override = request.value
        taken.override_at_s = request.at_s
