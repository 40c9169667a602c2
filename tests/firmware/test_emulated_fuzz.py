"""Generated sessions on the emulated RP2040 firmware and the Python device: identical output.

The device fuzz strategy (``tests/fuzz/test_device_fuzz.py``: lines, silences cut in pieces,
power cycles) replayed on the Python device and on the firmware in the emulator; made
talkative (diagnostics every 1-40 ticks, debug flags), and with a diagnostics line every
tick from the start. Each line must match byte for byte, at the same servo tick.

``make test`` runs a few hundred sessions with their silences bounded
(:data:`QUICK_MAX_TICKS` ticks per session: the emulator costs per tick); with
``USBMOTION_FUZZ_EXAMPLES`` set (``make fuzz``) that many run in all, on the full strategy
(silences of up to 60,001 ticks, cut only by the fuzz test's motor budget).
"""

from __future__ import annotations

import os
from collections.abc import Iterator, Sequence

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from device.test_replies import POWER_UP_QUERIES
from device.test_robustness import _integer_lines
from fuzz.budget import ENV, examples, fuzz_settings, hang_guard
from fuzz.test_device_fuzz import _STEP, Lines, PowerCycle, Silence
from usbmotion.sim.firmware import OutputChunk, Span

from .emulated import SPANS_TICKS, EmulatedFirmware, emulated_driver, printed_lines
from .sessions import (
    EXTREME_PARAMETERS,
    LOUD,
    NO_NEWLINE,
    Printed,
    Run,
    Step,
    byte_session,
    extreme_session,
    first_difference,
    fuzz_steps,
    lines,
    python_replay,
)

FULL = bool(os.environ.get(ENV, "").strip())
"""``USBMOTION_FUZZ_EXAMPLES`` is set: the long run, on the full strategy."""
QUICK_MAX_TICKS = 1500
"""Servo ticks per session in the quick run (a tick with a diagnostics line costs the
emulator about a millisecond)."""
MAX_TICKS = None if FULL else QUICK_MAX_TICKS
HANG_S = 900.0 if FULL else 60.0


def _examples(quick: int, share: float) -> settings:
    """``quick`` examples in ``make test``; ``share`` of the long run's budget otherwise."""
    count = max(1, round(examples() * share)) if FULL else quick
    return settings(fuzz_settings(), max_examples=count)


@pytest.fixture(scope="module")
def driver() -> Iterator[EmulatedFirmware]:
    """One emulated chip; each session powers up a fresh one on blank flash."""
    yield from emulated_driver()


def assert_same(driver: EmulatedFirmware, steps: Sequence[Step]) -> Printed:
    """Replay on both; the firmware must print what the Python prints, at the same ticks."""
    expected = python_replay(steps)
    actual = driver.replay(steps)
    assert actual == expected, first_difference(expected, actual)
    return expected


@_examples(100, 0.5)
@given(st.lists(_STEP, min_size=1, max_size=8))
def test_fuzz_sessions(driver: EmulatedFirmware,
                       steps: list[Lines | Silence | PowerCycle]) -> None:
    with hang_guard(HANG_S):
        assert_same(driver, [*fuzz_steps(steps, max_ticks=MAX_TICKS), lines(*POWER_UP_QUERIES)])


@_examples(70, 0.3)
@given(st.lists(st.one_of(_STEP, LOUD), min_size=1, max_size=10))
def test_fuzz_sessions_with_diagnostics(driver: EmulatedFirmware,
                                        steps: list[Lines | Silence | PowerCycle]) -> None:
    with hang_guard(HANG_S):
        assert_same(driver, [*fuzz_steps([Lines((b"21 3",), ()), *steps], max_ticks=MAX_TICKS),
                             lines(*POWER_UP_QUERIES)])


@_examples(40, 0.2)
@given(st.lists(_STEP, min_size=1, max_size=8))
def test_fuzz_sessions_with_diagnostics_every_tick(
        driver: EmulatedFirmware, steps: list[Lines | Silence | PowerCycle]) -> None:
    """A ``D`` line after every tick, until a line of the session changes call 21 or a power
    cycle ends it: every count of every tick compared."""
    with hang_guard(HANG_S):
        session = fuzz_steps([Lines((b"21 1", b"7 -1"), ()), *steps], max_ticks=MAX_TICKS)
        assert_same(driver, [*session, lines(*POWER_UP_QUERIES)])


# --- the native module's other generated sessions, with budgets of their own --------------


@settings(fuzz_settings(), max_examples=25)
@given(st.lists(st.binary(max_size=64), min_size=1, max_size=6),
       st.lists(st.integers(1, 40), max_size=6))
def test_random_bytes(driver: EmulatedFirmware, chunks: list[bytes], cuts: list[int]) -> None:
    steps = byte_session(b"8 0 1\n8 1 1\n" + b"".join(chunks) + b"\n2 -1\n", cuts)
    with hang_guard(HANG_S):
        assert_same(driver, steps)


@settings(fuzz_settings(), max_examples=25)
@given(st.lists(_integer_lines(), min_size=1, max_size=8))
def test_random_integer_lines(driver: EmulatedFirmware, lines_: list[bytes]) -> None:
    with hang_guard(HANG_S):
        assert_same(driver, [lines(*lines_), lines(*POWER_UP_QUERIES)])


@settings(max_examples=15, deadline=None)
@given(*EXTREME_PARAMETERS)
def test_extreme_parameters(driver: EmulatedFirmware, sci: list[tuple[int, int]],
                            interval_dms: int, sim_dms: int, counts: int, mode: int,
                            target: int, drive: int) -> None:
    with hang_guard(HANG_S):
        assert_same(driver, extreme_session(sci, interval_dms, sim_dms, counts, mode, target,
                                            drive))


# --- the test of the test ----------------------------------------------------------------


class _Mutated:
    """The emulated firmware with one change made to what it printed."""

    def __init__(self, firmware: EmulatedFirmware, mutation: str) -> None:
        self.firmware = firmware
        self.mutation = mutation

    def replay(self, steps: Sequence[Step]) -> Printed:
        printed = self.firmware.replay(steps)
        if self.mutation == "tick":
            index = [i for i, (_, text) in enumerate(printed) if text.startswith(b"D ")][6]
            tick, text = printed[index]
            printed[index] = (tick + 1, text)
        elif self.mutation == "reply byte":
            index = next(i for i, (_, text) in enumerate(printed) if text.startswith(b"STATUS"))
            tick, text = printed[index]
            at = len(text) // 2
            printed[index] = (tick, text[:at] + bytes([text[at] ^ 0x01]) + text[at + 1 :])
        else:  # one count of one diagnostics value: the position of the 7th D line
            index = [i for i, (_, text) in enumerate(printed) if text.startswith(b"D ")][6]
            tick, text = printed[index]
            fields = text.split(b" ")
            fields[2] = b"%d" % (int(fields[2]) + 1)
            printed[index] = (tick, b" ".join(fields))
        return printed


@pytest.mark.parametrize("mutation", ["reply byte", "diagnostics count", "tick"])
def test_a_changed_byte_count_or_tick_is_caught(driver: EmulatedFirmware, mutation: str) -> None:
    steps: list[Step] = [lines("21 1", "3 1", "0 40"), Run(12), lines("20 -1")]
    assert_same(driver, steps)
    with pytest.raises(AssertionError, match=r"line \d+: Python"):
        assert_same(_Mutated(driver, mutation), steps)  # type: ignore[arg-type]


def test_lines_are_stamped_with_the_ticks_their_bytes_arrived_at() -> None:
    spans = [Span(3, (OutputChunk(3, b"A 1\nB "),), (0, 0), 0),
             Span(5, (OutputChunk(4, b"2\n"), OutputChunk(5, b"C 3\nD")), (0, 0), 0)]
    assert printed_lines(spans) == [(3, b"A 1"), (3, b"B 2" + SPANS_TICKS % (3, 4)),
                                    (5, b"C 3"), (5, b"D" + NO_NEWLINE)]
