"""Sessions replayed on the Python device and on a firmware build, and their comparison.

A session is a list of steps: bytes fed from USB, servo ticks run with no input, power
cycles. :func:`python_replay` plays it on the Python device (``usbmotion.device.Device``, the
specification); a firmware build plays it through a :class:`Firmware` (the emulated RP2040
of ``tests/firmware/emulated.py``) or the native session driver (``test_native_device``).
Each gives every line printed with the servo tick it was printed at, ticks counted from
the session's start and never zeroed (across power cycles too); the two lists must be
equal, byte for byte and tick for tick.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

from hypothesis import strategies as st

from fuzz.test_device_fuzz import MOTOR_STEPS_PER_EXAMPLE, Lines, PowerCycle, Silence
from usbmotion.device import Device


@dataclass(frozen=True, slots=True)
class Feed:
    """Bytes from USB."""

    data: bytes


@dataclass(frozen=True, slots=True)
class Run:
    """Servo ticks with no input."""

    ticks: int


@dataclass(frozen=True, slots=True)
class Power:
    """A power cycle (flash kept)."""


Step = Feed | Run | Power
Printed = list[tuple[int, bytes]]
"""Every line printed (without its newline) with the tick it was printed at."""

NO_NEWLINE = b" <no newline>"
"""Marks a last line a firmware printed without its newline (the Python never does)."""


@runtime_checkable
class Firmware(Protocol):
    """A firmware build that replays sessions (the native driver is a plain path instead)."""

    def replay(self, steps: Sequence[Step]) -> Printed:
        """The session on a fresh device with blank flash: every line with its tick."""
        ...


def lines(*texts: str | bytes) -> Feed:
    """One feed of these lines, each ended by a newline."""
    return Feed(b"".join((t.encode("ascii") if isinstance(t, str) else t) + b"\n"
                         for t in texts))


class PythonReplay:
    """The Python device playing a session one step at a time, keeping every line it
    printed with its tick (``printed``)."""

    def __init__(self) -> None:
        self.device = Device()
        self.now = 0
        self.printed: Printed = []

    def _take(self) -> None:
        for ago, chunk in self.device.take_timed_output():
            assert chunk.endswith(b"\n")
            self.printed.extend((self.now - ago, line) for line in chunk[:-1].split(b"\n"))

    def play(self, step: Step) -> None:
        """Play one step."""
        if isinstance(step, Feed):
            self.device.feed(step.data)
        elif isinstance(step, Run):
            self.device.run(step.ticks)
            self.now += step.ticks
        else:
            self._take()
            self.device.restart()
        self._take()


def python_replay(steps: Iterable[Step]) -> Printed:
    """The session on the Python device."""
    replay = PythonReplay()
    for step in steps:
        replay.play(step)
    return replay.printed


def first_difference(expected: Printed, actual: Printed) -> str:
    """Where two outputs part, for a failure message."""
    for index, (want, got) in enumerate(zip(expected, actual, strict=False)):
        if want != got:
            return f"line {index}: Python {want!r}, firmware {got!r}"
    if len(expected) != len(actual):
        index = min(len(expected), len(actual))
        extra = expected[index:] if len(expected) > len(actual) else actual[index:]
        who = "Python" if len(expected) > len(actual) else "firmware"
        return f"only the {who} printed from line {index}: {extra[:3]!r}"
    return "identical"


def byte_session(data: bytes, cuts: Sequence[int]) -> list[Step]:
    """``data`` fed in pieces of the ``cuts``' lengths, the rest in one."""
    steps: list[Step] = []
    position = 0
    for cut in cuts:
        steps.append(Feed(data[position : position + cut]))
        position += cut
    steps.append(Feed(data[position:]))
    return steps


def simulated_motor_only(line: bytes) -> bytes:
    """``line``, or ``39 0`` when it selects the motor on the pins (call 39 with 1).

    A firmware that powers up on its pins runs the motor outside the chip, which the Python
    device, always on its simulated motor, does not have: the byte-exact comparisons keep to
    the simulated motor (the pins have their own tests, test_emulated_pins.py).
    """
    words = line.replace(b"\t", b" ").split()
    try:
        numbers = [int(word) for word in words]
    except ValueError:
        return line
    return b"39 0" if numbers == [39, 1] else line


def fuzz_steps(steps: Sequence[Lines | Silence | PowerCycle], *,
               motor_steps: int = MOTOR_STEPS_PER_EXAMPLE,
               max_ticks: int | None = None,
               replay: PythonReplay | None = None) -> list[Step]:
    """A fuzz session as the replay's steps, its silences cut to a budget.

    ``motor_steps`` is the fuzz test's budget of simulated motor steps (measured on a Python
    device, so both replays run the same ticks); ``max_ticks``, when given, also bounds the
    servo ticks of the whole session (an emulated chip costs per tick, whatever the motor).
    A silence cut short runs in one piece. The budget is measured by playing each step on
    ``replay`` (a fresh one when not given): given, it holds the Python's side of the
    comparison afterwards (what :func:`python_replay` of the steps returns).
    """
    if replay is None:
        replay = PythonReplay()
    budget = motor_steps
    ticks_left = max_ticks
    out: list[Step] = []
    for step in steps:
        if isinstance(step, Lines):
            data = b"".join(simulated_motor_only(line) + b"\n" for line in step.lines)
            position = 0
            for cut in (*step.cuts, len(data)):
                out.append(Feed(data[position:cut]))
                replay.play(out[-1])
                position = cut
        elif isinstance(step, Silence):
            cost = max(1, replay.device.motor_constants.steps)
            ticks = min(step.ticks, budget // cost)
            if ticks_left is not None:
                ticks = min(ticks, ticks_left)
                ticks_left -= ticks
            budget -= ticks * cost
            pieces = step.pieces if ticks == step.ticks else (ticks,)
            for piece in pieces:
                out.append(Run(piece))
                replay.play(out[-1])
        else:
            out.append(Power())
            replay.play(out[-1])
    return out


LOUD = st.builds(
    lambda diag, call, flag: Lines((b"21 %d" % diag, b"8 %d %d" % (call, flag)), ()),
    st.integers(1, 40), st.sampled_from([0, 1, 3, 7, 23, 25, 37, 38, 40, 42, 44, 45, 46, 47]),
    st.integers(0, 2))
"""A diagnostics interval and a debug flag: the fuzz strategy's sessions made talkative."""


EXTREME_PARAMETERS = (
    st.lists(st.sampled_from([(1, -12), (999, 6), (5, 0), (1234, -6), (9999, 3), (1, 6)]),
             min_size=9, max_size=9),
    st.sampled_from([1, 3, 10, 10000]),
    st.sampled_from([1, 10, 10000]),
    st.sampled_from([1, 1920, 1_000_000]),
    st.sampled_from([1, 2]),
    st.sampled_from([-(2**31), -1, 5000, 2**31 - 1]),
    st.sampled_from([0, 1, 2]),
)
"""Strategies of :func:`extreme_session`'s arguments."""


def extreme_session(sci: list[tuple[int, int]], interval_dms: int, sim_dms: int, counts: int,
                    mode: int, target: int, drive: int = 0) -> list[Step]:
    """test_robustness's extreme motors and gains, every value at its int64 edge, run tick
    by tick with a diagnostics line every tick; in the DC drive or a step drive (call 44:
    the stepper's fastest step timing, its speed bound within reach)."""
    calls = [9, 10, 11, 13, 14, 15, 17, 32, 33]
    setup = [f"{call} {min(c, 999) if call < 12 else c} {e}"
             for call, (c, e) in zip(calls, sci, strict=True)]
    setup += [f"5 {interval_dms}", f"12 {sim_dms}", f"16 {counts}", f"7 {mode}"]
    if drive:
        setup += [f"44 {drive}", "46 100 0", "45 1000 256"]
    setup += ["21 1", "3 1", f"1 3 {target} {-target - 1} {target}"]
    ticks = 1 if interval_dms > 100 else 25
    return [lines(*setup), *[Run(1)] * (6 * ticks), lines("20 -1", "35 -1")]
