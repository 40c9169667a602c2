"""Automation sequences: polled until they report ``Complete`` or ``Failure``.

A sequence does a little work each time it is polled and answers with a
:class:`Transition`. Combinators build bigger sequences from small ones: :class:`All`
runs several at once (the first fault wins and stops the rest), :class:`Chain` runs them
one after another. :func:`run_sequence` polls a sequence at a fixed rate on a clock.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from enum import Enum
from typing import Generic, Protocol, TypeVar

from usbmotion.clock import Clock, is_paced
from usbmotion.errors import ArgumentError, SequenceFaultError, StopRequestedError


class FailureKind(Enum):
    """Why a sequence failed."""

    AXIS_NOT_FOUND = "axis not found"
    UNEXPECTED_UPPER_LIMIT = "upper limit switch closed while homing toward the lower one"
    LIMIT_NOT_RELEASED = "limit switch still closed after backing off"
    SWITCH_NOT_FOUND = "no limit switch found"
    TIMEOUT = "sequence did not finish in time"
    DEVICE = "device fault"
    STOPPED = "stopped by a fault elsewhere"


@dataclass(frozen=True, slots=True)
class Failure:
    """What went wrong, and on which axis."""

    kind: FailureKind
    axis: str = ""
    detail: str = ""

    def __str__(self) -> str:
        where = f"axis {self.axis}: " if self.axis else ""
        return where + self.kind.value + (f" ({self.detail})" if self.detail else "")

    @classmethod
    def axis_not_found(cls, axis: str) -> Failure:
        """The named axis does not exist."""
        return cls(FailureKind.AXIS_NOT_FOUND, axis)

    @classmethod
    def unexpected_upper_limit(cls, axis: str) -> Failure:
        """The upper switch closed first: limits wired backwards, or the axis ran away."""
        return cls(FailureKind.UNEXPECTED_UPPER_LIMIT, axis)


class _Complete:
    __slots__ = ()

    def __repr__(self) -> str:
        return "Complete"


class _Incomplete:
    __slots__ = ()

    def __repr__(self) -> str:
        return "Incomplete"


Complete = _Complete()
"""The sequence finished successfully."""
Incomplete = _Incomplete()
"""The sequence is still running: poll it again."""

Transition = _Complete | _Incomplete | Failure
"""What one poll of a sequence reports."""


def at_end(transition: Transition) -> bool:
    """True for ``Complete`` and any ``Failure``."""
    return transition is not Incomplete


InT = TypeVar("InT")
OutT = TypeVar("OutT")
I_contra = TypeVar("I_contra", contravariant=True)
O_contra = TypeVar("O_contra", contravariant=True)


class AutomationSequence(Protocol[I_contra, O_contra]):
    """Something that is polled with inputs and outputs until it completes or faults."""

    def poll(self, inputs: I_contra, outputs: O_contra) -> Transition:
        """Do one step of work."""
        ...


class Stoppable(Protocol):
    """A sequence that can be told to stop what it drives (used when a sibling faults)."""

    def stop(self, outputs: object) -> None:
        """Bring whatever it drives to rest."""
        ...


class All(Generic[InT, OutT]):
    """Poll every live child each time; complete when all have; the first fault wins.

    When a child faults, every other live child that can be stopped (has a ``stop``
    method) is stopped, and the fault is reported.
    """

    def __init__(self, children: Sequence[AutomationSequence[InT, OutT]]) -> None:
        self._live: list[AutomationSequence[InT, OutT] | None] = list(children)

    def poll(self, inputs: InT, outputs: OutT) -> Transition:
        """Poll each child still running."""
        for index, child in enumerate(self._live):
            if child is None:
                continue
            transition = child.poll(inputs, outputs)
            if transition is Incomplete:
                continue
            self._live[index] = None
            if isinstance(transition, Failure):
                for other in self._live:
                    stop = getattr(other, "stop", None)
                    if other is not None and callable(stop):
                        stop(outputs)
                self._live = [None] * len(self._live)
                return transition
        return Complete if all(c is None for c in self._live) else Incomplete

    def stop(self, outputs: object) -> None:
        """Stop every live child that can be stopped."""
        for child in self._live:
            stop = getattr(child, "stop", None)
            if child is not None and callable(stop):
                stop(outputs)
        self._live = [None] * len(self._live)


class Chain(Generic[InT, OutT]):
    """Run children one after another; a fault ends the chain."""

    def __init__(self, children: Sequence[AutomationSequence[InT, OutT]]) -> None:
        self._children = list(children)
        self._index = 0

    def poll(self, inputs: InT, outputs: OutT) -> Transition:
        """Poll the current child; move to the next when it completes."""
        while self._index < len(self._children):
            transition = self._children[self._index].poll(inputs, outputs)
            if transition is Incomplete:
                return Incomplete
            if isinstance(transition, Failure):
                self._index = len(self._children)
                return transition
            self._index += 1
        return Complete

    def stop(self, outputs: object) -> None:
        """Stop the current child, if it can be stopped."""
        if self._index < len(self._children):
            stop = getattr(self._children[self._index], "stop", None)
            if callable(stop):
                stop(outputs)


STOP_CHECK_S = 0.002
"""How often :func:`run_sequence` asks ``should_stop`` while it waits between polls (on a
paced clock: a virtual-time world's wait between polls passes in less than that)."""


def run_sequence(
    sequence: AutomationSequence[InT, OutT],
    inputs: InT,
    outputs: OutT,
    *,
    clock: Clock,
    rate_hz: float = 100.0,
    timeout_s: float = 120.0,
    on_poll: Callable[[int], None] | None = None,
    should_stop: Callable[[], str] | None = None,
) -> None:
    """Poll ``sequence`` at ``rate_hz`` on ``clock`` until it completes.

    ``should_stop`` is asked before every poll; a non-empty answer (why) stops the sequence
    (its ``stop``, when it has one) and raises.

    Raises:
        SequenceFaultError: the sequence faulted (``axis`` and ``reason`` set), or it did
            not finish within ``timeout_s``.
        StopRequestedError: ``should_stop`` answered why it should stop.
    """
    if not (math.isfinite(rate_hz) and rate_hz > 0):
        raise ArgumentError(f"rate_hz {rate_hz!r} must be > 0", reason="rate_hz")
    period = 1.0 / rate_hz
    sliced = should_stop is not None and is_paced(clock)
    start = clock.now()
    polls = 0
    while True:
        why = should_stop() if should_stop is not None else ""
        if why:
            stop = getattr(sequence, "stop", None)
            if callable(stop):
                stop(outputs)
            raise StopRequestedError(f"stopped: {why}", reason=why)
        transition = sequence.poll(inputs, outputs)
        polls += 1
        if on_poll is not None:
            on_poll(polls)
        if transition is Complete:
            return
        if isinstance(transition, Failure):
            raise SequenceFaultError(str(transition), axis=transition.axis,
                                     reason=transition.kind.value)
        elapsed = clock.now() - start
        if elapsed > timeout_s:
            stop = getattr(sequence, "stop", None)
            if callable(stop):
                stop(outputs)
            raise SequenceFaultError(
                f"{FailureKind.TIMEOUT.value}: still running after {timeout_s:g} s",
                reason=FailureKind.TIMEOUT.value,
            )
        next_poll = start + polls * period
        while True:
            left = next_poll - clock.now()
            if left <= 0:
                break
            if should_stop is not None and should_stop():
                break
            clock.sleep(min(left, STOP_CHECK_S) if sliced else left)
