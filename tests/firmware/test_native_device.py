"""The portable firmware, built for this machine, answers byte for byte as the Python device.

Each session (bytes fed, servo ticks run, power cycles) is replayed on the Python device
(``usbmotion.device.Device``, the specification) and on the firmware's own C sources
(``firmware/src/device``) built with the native platform of ``firmware/host`` and driven by
its session driver. Both give every line they printed with the servo tick it was printed at
(ticks since the session started; the Python's from ``Device.take_timed_output``); the two
lists must be equal, byte for byte and tick for tick.

The sessions: every reply, debug line and error case of the device tests
(``tests/device/test_replies.py``, ``test_robustness.py``, ``test_replace.py``), the
scenarios that need servo ticks, hypothesis sessions from the device fuzz strategy
(``tests/fuzz/test_device_fuzz.py``: lines, silences, power cycles), random bytes, over-long
lines and integers of any length. ``USBMOTION_FUZZ_EXAMPLES`` sets the generated sessions'
count (``tests/fuzz/budget.py``).
"""

from __future__ import annotations

import importlib.util
import random
import subprocess
import zlib
from collections.abc import Iterable, Sequence
from dataclasses import replace
from pathlib import Path
from types import ModuleType

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from device.test_replies import DEBUG_LINES, POWER_UP_QUERIES, SEED_000, SET_THEN_QUERY
from device.test_robustness import BAD_LINES, HUGE_LINES, _integer_lines
from fuzz.budget import fuzz_settings, hang_guard
from fuzz.test_device_fuzz import _STEP, Lines, PowerCycle, Silence
from usbmotion.protocol import CALLS, MAX_LINE_BYTES

from .native import ROOT, build
from .sessions import (
    EXTREME_PARAMETERS,
    LOUD,
    NO_NEWLINE,
    Feed,
    Firmware,
    Power,
    Printed,
    PythonReplay,
    Run,
    Step,
    byte_session,
    extreme_session,
    first_difference,
    fuzz_steps,
    lines,
    python_replay,
)

DEVICE_SOURCES = ROOT / "firmware" / "src" / "device"
HOST_SOURCES = ROOT / "firmware" / "host"


def sources() -> list[Path]:
    """The portable device code and the native platform with its session driver."""
    return [*sorted(DEVICE_SOURCES.glob("*.c")), HOST_SOURCES / "platform_native.c",
            HOST_SOURCES / "driver.c"]


# --- sessions ----------------------------------------------------------------------------


def session_text(steps: Iterable[Step]) -> str:
    """The session as the native driver reads it."""
    commands = []
    for step in steps:
        if isinstance(step, Feed):
            commands.append(f"feed {step.data.hex()}")
        elif isinstance(step, Run):
            commands.append(f"run {step.ticks}")
        else:
            commands.append("power")
    return "".join(command + "\n" for command in commands)


def parse_driver_output(text: str) -> Printed:
    """The driver's `TICK HEX` lines; a line it printed without a newline keeps a marker."""
    printed: Printed = []
    for row in text.splitlines():
        tick, data, *rest = row.split(" ")
        line = bytes.fromhex(data)
        printed.append((int(tick), line + NO_NEWLINE if rest == ["-"] else line))
    return printed


def native_replay(driver: Path, steps: Iterable[Step], *, flash: Path | None = None) -> Printed:
    """The session on the firmware's sources, built natively."""
    command = [str(driver), *(["--flash", str(flash)] if flash is not None else [])]
    result = subprocess.run(command, input=session_text(steps), capture_output=True,
                            text=True, check=False, timeout=120)
    assert result.returncode == 0, result.stderr
    return parse_driver_output(result.stdout)


Driver = Path | Firmware
"""The native session driver's executable, or another build (the emulated RP2040's tests run
this module's scripted sessions with theirs)."""


def assert_same(driver: Driver, steps: Sequence[Step], *,
                expected: Printed | None = None) -> Printed:
    """Replay on both; the firmware must print what the Python prints, at the same ticks.
    ``expected``: the Python's replay of ``steps``, when it was played already."""
    if expected is None:
        expected = python_replay(steps)
    actual = native_replay(driver, steps) if isinstance(driver, Path) else driver.replay(steps)
    assert actual == expected, first_difference(expected, actual)
    return expected


@pytest.fixture(scope="module")
def driver() -> Path:
    """The session driver built from the firmware's sources (cached by their hash)."""
    return build("usbmotion_native", sources(), shared=False)


# --- every reply, debug line and error of the device tests ------------------------------


@pytest.mark.parametrize(("setup", "line", "expected"), SEED_000)
def test_seed_000_strings(driver: Driver, setup: list[str], line: str,
                          expected: list[str]) -> None:
    printed = assert_same(driver, [lines(*setup), Feed(b"2 -1\n"), lines(line)])
    after = [text.decode() for _, text in printed]
    assert after[after.index("MOTION_QUEUE 0 1000") + 1 :] == expected


def test_every_query_at_power_up(driver: Driver) -> None:
    steps: list[Step] = [lines(line) for line in POWER_UP_QUERIES]
    printed = assert_same(driver, steps)
    assert [text.decode() for _, text in printed] == list(POWER_UP_QUERIES.values())


@pytest.mark.parametrize(("set_line", "query", "reply"), SET_THEN_QUERY)
def test_a_set_value_is_queried_back(driver: Driver, set_line: str, query: str,
                                     reply: str) -> None:
    printed = assert_same(driver, [lines(set_line), lines(query)])
    assert printed == [(0, reply.encode())]


@pytest.mark.parametrize(("setup", "line", "expected"), DEBUG_LINES)
def test_every_debug_line(driver: Driver, setup: list[str], line: str, expected: str) -> None:
    number = int(line.split(maxsplit=1)[0])
    steps: list[Step] = [lines(*setup), lines(line), lines(*setup), lines(f"8 {number} 1"),
                         lines(line), lines(f"8 {number} 9"), lines(*setup), lines(line)]
    printed = assert_same(driver, steps)
    assert (0, expected.encode()) in printed


def test_every_debug_flag_of_every_call(driver: Driver) -> None:
    """Every defined flag value and a few undefined ones, on every call's example line."""
    steps: list[Step] = [lines("7 1")]
    examples_of = {int(line.split()[0]): (setup, line) for setup, line, _ in DEBUG_LINES}
    for flag in (0, 1, 2, 3, 255):
        for number, (setup, line) in sorted(examples_of.items()):
            steps += [lines(*setup), lines(f"8 {number} {flag}", f"8 {number} -1", line)]
    assert_same(driver, steps)


@pytest.mark.parametrize(("line", "reply"), HUGE_LINES)
def test_integers_of_any_length(driver: Driver, line: str, reply: str) -> None:
    assert_same(driver, [lines(line), lines(line), lines("30 -1")])


@pytest.mark.parametrize(("line", "err", "query"), BAD_LINES)
def test_bad_values(driver: Driver, line: str, err: str, query: str) -> None:
    printed = assert_same(driver, [lines(query), lines(line), lines(query), lines("0 5", "2 -1")])
    assert (0, err.encode()) in printed


def test_every_query_after_settings(driver: Driver) -> None:
    settings = [set_line for set_line, _, _ in SET_THEN_QUERY]
    queries = list(POWER_UP_QUERIES)
    assert_same(driver, [lines(*settings), lines(*queries), Power(), lines(*queries)])


def test_replies_in_order_and_any_split(driver: Driver) -> None:
    whole = b"8 0 1\n0 3910\r\n\n  \n1 2 5 6\n2 -1\n8 1 2\n1 3 -1 2147483647 -2147483648\n"
    for size in (1, 2, 3, 7, len(whole)):
        steps: list[Step] = [Feed(whole[i : i + size]) for i in range(0, len(whole), size)]
        assert_same(driver, steps)


def test_counts_before_ranges_and_query_forms(driver: Driver) -> None:
    assert_same(driver, [lines(
        "1", "1 0", "1 1001 5", "1 2 5", "1 2 5 6 7", "1 2 2147483648 x", "1 2 5 -2147483649",
        "1 +2 005 -006", "18", "18 -1", "18 -2", "18 0", "18 1 31", "18 1 127", "18 2 65",
        "18 26", "18 -1 5", "8", "8 3", "8 64 -1", "8 -1 -1", "8 63 -1", "8 63 -2", "8 63 256",
        "8 0 1 2", "9 -1 0", "9 -1 1", "9 -1", "9 1000 -13", "34 -1 -1", "34 -1 0", "34 5 5",
        "34 6 5", "36 0", "36 3", "36 1", "36 2", "36", "36 1 1", "20 0", "20", "20 -1 -1",
        "22 1", "22 -1", "30 -1", "30 1", "35 -1", "35 1", "38", "38 0", "38 -1 0",
        "38 0 -1", "38 0 1", "38 0 1 5 6", "38 0 1 2147483648", "38 0 0", "-0 5", "+0 6",
        "0 -0", "00000000000000000000000000000000000000000000000001 1 7",
    )])


def test_long_lines_of_many_inputs(driver: Driver) -> None:
    many = " ".join(["1"] * 1500)
    assert_same(driver, [lines(
        f"1 1000 {' '.join(['2'] * 999)} x", f"1 1000 {' '.join(['2'] * 1000)} x",
        f"1 1001 {many}", f"0 {many}", f"38 5 1000 {' '.join(['-3'] * 1000)}",
        f"1 1000 {' '.join(['2'] * 998)} 2147483648 5", f"18 25 {' '.join(['126'] * 25)}",
        "18 -1", "18 3 32 65 32", "18 -1", f"18 25 {' '.join(['32'] * 24)} 31", "18 -1",
        f"99 {many} x", f"{many} x",
    )])


def test_messages_of_refused_calls(driver: Driver) -> None:
    assert_same(driver, [
        lines("7 3", "0 5", "1 1 5", "38 0 1 5", "7 1", "25 1 2 3 4", "34 10 -10", "34 0 0"),
        lines("7 3", *(f"25 {d} {d} 0 0" for d in range(1, 11)), "27 -1", "20 -1", "26 0"),
        lines("1 1000 " + " ".join(["7"] * 1000), "0 1", "1 1 1", "2 -1", "4 0", "2 -1"),
    ])


def test_the_crc_acknowledgement_of_a_full_queue(driver: Driver) -> None:
    values = [random.Random(7).randint(-(2**31), 2**31 - 1) for _ in range(1000)]
    printed = assert_same(driver, [lines("8 1 2", "1 1000 " + " ".join(map(str, values)))])
    crc = zlib.crc32(b"".join(v.to_bytes(4, "little", signed=True) for v in values))
    assert printed == [(0, f"ADDED 1000 CRC {crc}".encode())]


# --- lines the splitter and the parser must read as the Python does ----------------------


def test_over_long_lines(driver: Driver) -> None:
    limit = MAX_LINE_BYTES
    body = b"1 " + b"7 " * (limit // 2)
    cases = [
        b"5" * limit, b"5" * (limit - 1) + b"\r", b"5" * limit + b"\r", b"5" * limit + b"\r\r",
        b"5" * (limit + 1), b"5" * (limit - 2) + b"\r\r\r", b"\r" * (limit + 1), b"\r" * limit,
        b"0 " * (limit // 2), body, b"1 1000 " + b" ".join([b"-2147483648"] * 1000),
        b"x" * (3 * limit),
    ]
    steps: list[Step] = []
    for case in cases:
        steps += [Feed(case + b"\n"), lines("2 -1")]
        steps += [Feed(case[: limit // 3]), Feed(case[limit // 3 :]), Feed(b"\n2 -1\n")]
        steps += [Feed(case), Power(), lines("2 -1")]
    assert_same(driver, steps)


def test_a_long_run_of_leading_zeros(driver: Driver) -> None:
    assert_same(driver, [lines("0" * 4301, "0 " + "0" * 4300 + "7", "30 -1")])


def test_tokens_shown_as_python_repr_shows_them(driver: Driver) -> None:
    """Quotes, escapes, U+FFFD printed as \\ufffd, the 24-character cut, separators."""
    tokens = [
        b"'", b'"', b"'\"", b"a'b", b'a"b', b"\\", b"a\\'b", b"\x00", b"\x07\x1b\x7f",
        b"\x80", b"\xff\xfe", b"\xe2\x82\xac", b"x" * 24, b"x" * 25, b"y" * 21 + b"'" + b"z" * 5,
        b"'" * 30, b"\x81" * 30, b"1.5", b"--1", b"+-1", b"-", b"+", b"0x10", b"1e3", b"1_0",
        b"\xd9\xa3", b"\xef\xbc\x91", b"12a", b"a12",
    ]
    separators = [b" ", b"\t", b"\x0b", b"\x0c", b"\r", b"\x1c", b"\x1d", b"\x1e", b"\x1f",
                  b"\x85", b"\xa0", b" \t\x0b"]
    data = bytearray()
    for token in tokens:
        data += token + b"\n" + b"3 " + token + b"\n" + b"99 1 " + token + b"\n"
        data += b"3" * 19 + b" " + token + b"\n" + b"-" + b"3" * 40 + b" 5 " + token + b"\n"
    for separator in separators:
        data += b"8" + separator + b"3" + separator + b"1\n" + b"3" + separator + b"-1\n"
    assert_same(driver, [Feed(bytes(data))])


def test_huge_integers_everywhere(driver: Driver) -> None:
    huge = ["9" * 18, "9" * 19, "1" + "0" * 18, "0" * 50 + "9" * 18, "-" + "9" * 18,
            "+" + "0" * 30 + "1" * 19, "-" + "2" * 4301, "7" * 9000]
    data = []
    for value in huge:
        data += [value, f"{value} 1", f"0 {value}", f"1 {value}", f"1 1 {value}",
                 f"8 {value} -1", f"36 {value}", f"18 1 {value}", f"38 {value} 0",
                 f"38 0 1 {value}", f"25 1 2 3 {value}", f"3 {value} x", f"{value} x"]
    assert_same(driver, [lines(*data)])


@fuzz_settings()
@given(st.lists(st.binary(max_size=64), min_size=1, max_size=6),
       st.lists(st.integers(1, 40), max_size=6))
def test_random_bytes(driver: Driver, chunks: list[bytes], cuts: list[int]) -> None:
    steps = byte_session(b"8 0 1\n8 1 1\n" + b"".join(chunks) + b"\n2 -1\n", cuts)
    with hang_guard():
        assert_same(driver, steps)


@fuzz_settings()
@given(st.lists(_integer_lines(), min_size=1, max_size=8))
def test_random_integer_lines(driver: Driver, lines_: list[bytes]) -> None:
    with hang_guard():
        assert_same(driver, [lines(*lines_), lines(*POWER_UP_QUERIES)])


# --- sessions with servo ticks -----------------------------------------------------------


def test_status_after_a_move(driver: Driver) -> None:
    assert_same(driver, [lines("3 1", "0 500"), Run(300), lines("20 -1", "35 -1")])


def test_a_fault_alarm_and_the_refusal_to_enable(driver: Driver) -> None:
    assert_same(driver, [lines("29 1", "3 1", "0 100"), Run(1), lines("3 1", "30 -1", "20 -1"),
                         lines("30 0", "3 1", "3 -1")])


def test_the_crc_of_a_batch_that_wraps_the_queue_ring(driver: Driver) -> None:
    values = " ".join(map(str, range(-250, 250)))
    assert_same(driver, [lines("3 1", "1 700 " + " ".join(["5"] * 700)), Run(600),
                         lines("8 1 2", f"1 500 {values}", "2 -1")])


def test_diagnostics_lines_at_their_ticks(driver: Driver) -> None:
    assert_same(driver, [lines("21 7", "3 1", "0 300"), Run(100), lines("22 0", "21 3"), Run(20),
                         lines("7 2", "3 1", "1 2 4000 -4000"), Run(60), lines("7 3", "3 1"),
                         lines("25 20 400 0 0", "25 10 -100 512 -512"), Run(80),
                         lines("20 -1"), Power(), lines("21 1"), Run(5)])


def test_the_peak_of_diagnostics_lines(driver: Driver) -> None:
    """Restarted by each line, call 21 and call 35's reset; kept over calls 22, 23 and the
    queries; not counted while an armed start holds or in velocity mode."""
    assert_same(driver, [lines("21 10", "3 1", "0 400"), Run(3), lines("35 0"), Run(10),
                         lines("21 10"), Run(14), lines("0 -400"), Run(4),
                         lines("22 0", "23 7", "0 -300"), Run(3), lines("35 -1", "21 -1"),
                         Run(20), lines("31 1000", "0 200"), Run(15),
                         lines("7 2", "3 1", "1 1 3000"), Run(20)])


def test_alarms_of_every_fault(driver: Driver) -> None:
    assert_same(driver, [
        lines("21 50", "28 5", "3 1"), Run(20), lines("30 -1", "30 0"),
        lines("34 -50 50", "3 1", "0 80"), Run(400), lines("30 -1", "36 2", "30 0"),
        lines("23 0", "29 40", "3 1", "0 100000"), Run(50), lines("30 -1", "35 -1"),
    ])


def test_the_probe_input(driver: Driver) -> None:
    """Calls 40 and 41: a surface on each side crossed both ways in position mode, the edges
    latched and shifted by calls 37 and 23, a moved surface taking its state without an
    edge, the debug line, bad values, and a power cycle back to no surface."""
    assert_same(driver, [
        lines("41 -1", "40 -1 0", "8 40 1", "40 2 300", "41 -1", "3 1", "0 500"), Run(150),
        lines("41 -1", "36 2"), Run(250), lines("41 -1", "0 100"), Run(400),
        lines("41 -1", "37 1000", "41 -1", "36 1", "23 -5", "41 -1", "20 -1"),
        lines("40 1 50", "41 -1", "0 -100"), Run(400), lines("41 -1", "40 -1 0"),
        lines("40 1 200", "41 -1", "40 2 200", "41 -1", "40 0 0", "41 -1", "8 40 2",
              "40 2 -2147483648", "41 -1", "40 1 2147483647", "40 -1 0", "41 -1"),
        lines("40 3 0", "40 -1 5", "40 1", "40 -2 0", "41 0", "41", "41 -1 -1", "40 -1 0"),
        Run(3), Power(), lines("40 -1 0", "41 -1"),
    ])


def test_the_probe_edge_in_velocity_mode_and_its_counter_reset(driver: Driver) -> None:
    """A probe edge latched in velocity mode moves with the counter at its 60 s reset (100 ms
    ticks: 600 of them), as the switches' edges do."""
    assert_same(driver, [
        lines("5 1000", "12 1000", "40 2 2000", "34 -100000 100000", "7 2", "3 1",
              "1 1 100"), Run(200),
        lines("41 -1", "20 -1", "0 0"), Run(390), lines("41 -1", "20 -1"), Run(60),
        lines("41 -1", "20 -1", "40 -1 0"),
    ])


def test_outputs_on_their_ticks(driver: Driver) -> None:
    """Calls 42 and 43: changes applied on their ticks (read on the tick before and the tick
    of each), two on one tick, one already past, three past ones for two ticks applied
    together, the queue's 16 and the 17th refused (on 16 ticks, and on one), bad values, a
    decreasing tick, the debug line, clearing, call 22 dropping the pending and calls 23/37
    changing nothing, a fault turning everything off and refusing changes until cleared,
    and a power cycle."""
    fill = [f"42 3 {10 * k} {200 + k}" for k in range(16)]
    one_tick = [f"42 {k % 4} {1000 * (k // 4 % 2) if k % 4 < 2 else 10 * k} 280"
                for k in range(16)]
    assert_same(driver, [
        lines("43 0", "8 42 1", "42 0 1000 5", "42 2 500 5", "42 3 250 9", "43 0"), Run(5),
        lines("43 0"), Run(1), lines("43 0"), Run(3), lines("43 0"), Run(1), lines("43 0"),
        lines("42 1 7 3", "42 0 500 20", "42 4 0 0", "42 2 1001 0", "42 2 0 -1", "43 2",
              "42 1 1000 30", "42 2 0 29", "42 2 0 30", "8 42 0", "43 0"), Run(25),
        lines("43 0", "42 3 1000 3", "43 0"), Run(1), lines("43 0"),
        lines("42 0 1000 4", "42 1 1000 5", "42 2 7 5", "43 0"), Run(1), lines("43 0"),
        lines(*fill, "42 3 999 300", "43 0"), Run(195), lines("43 0"), Run(2),
        lines("43 0", "43 1"), Run(30), lines("43 0"),
        lines(*one_tick, "42 1 0 290", "43 0"), Run(16), lines("43 0"), Run(1), lines("43 0"),
        lines("42 0 0 400", "23 77", "37 -5", "43 0", "22 0", "43 0", "22 -1"), Run(500),
        lines("43 0", "42 0 1000 0", "42 2 640 1", "42 3 1 1000"), Run(3),
        lines("43 0", "29 5", "3 1", "0 3000"), Run(40),
        lines("30 -1", "43 0", "42 0 1000 0", "30 0", "42 0 1000 0"), Run(1),
        lines("43 0", "28 5", "3 1"), Run(20), lines("30 -1", "43 0", "30 0", "42 1 1000 2"),
        Run(3), Power(), lines("43 0", "42 1 1000 0"), Run(1), lines("43 0"),
    ])


# --- the step drives (calls 44-48) --------------------------------------------------------

STEPPER = ("17 1 -5", "33 20 0", "16 4000", "12 1", "9 1 -1", "10 1 0", "11 2 -3")
"""A NEMA 17 stepper's rotor with a small load (1e-5 kg m^2, 20 mNm), a 1000-line encoder on
it (4000 counts a turn), 100 us integration steps (ten sub-steps a tick at 1 kHz) and the
closed loop's gains (the host's defaults: 0.1 microstep of lead per microstep of error, 1
per microstep-second, 2e-3 per microstep/s; an open loop runs no PID). The
stepper's own defaults (call 47): 590 mNm holding, 20 detent, corner 760 rpm; 200 full steps
of 16 microsteps (call 45): 3200 microsteps a turn."""


def ramp(start: int, end: int, count: int) -> str:
    """Call 1 of ``count`` positions from ``start`` (excluded) to ``end``, evenly."""
    values = [start + (end - start) * k // count for k in range(1, count + 1)]
    return f"1 {count} " + " ".join(map(str, values))


def shaft_scan(low: int, high: int, step: int) -> tuple[str, ...]:
    """Lines that read where the shaft is, which an open loop's counter does not say: the
    probe's surface (call 40) moved to each position from ``low`` to ``high`` by ``step`` and
    the probe read there (call 41: closed while the shaft is at or above it; a moved surface
    takes its state without an edge), then the surface removed."""
    scan: list[str] = []
    for position in range(low, high + 1, step):
        scan += [f"40 2 {position}", "41 -1"]
    return (*scan, "40 0 0")


def replay_both(driver: Driver, steps: Sequence[Step]) -> tuple[Printed, PythonReplay]:
    """:func:`assert_same`, keeping the Python's device (its shaft, for what the lines cannot
    show: the steps an open loop lost)."""
    replay = PythonReplay()
    for step in steps:
        replay.play(step)
    assert_same(driver, steps, expected=replay.printed)
    return replay.printed, replay


def replies(printed: Printed, word: str) -> list[list[int]]:
    """The values of every reply that starts with ``word``, in order (not its debug lines:
    ``DRIVE MODIFIED TO 1``)."""
    found = []
    for _, text in printed:
        head, *values = text.split()
        if head == word.encode() and all(v.lstrip(b"-").isdigit() for v in values):
            found.append([int(v) for v in values])
    return found


@pytest.mark.parametrize("drive", [1, 2])
def test_step_drives_follow_moves_in_every_mode(driver: Driver, drive: int) -> None:
    """A turn in position mode, velocities held for 100 ticks, keyframes in curve mode, then
    a power cycle back to the DC motor: diagnostics every 20 ticks (their output the tick's
    steps), call 48 after each. The probe's surface at the turn's end shows the shaft, which
    the open loop's counter does not: its edges count the shaft's swings about the turn."""
    printed, _ = replay_both(driver, [
        lines(*STEPPER, "8 44 1", f"44 {drive}", "40 2 3200", "21 20", "3 1",
              ramp(0, 3200, 160)), Run(600),
        lines("20 -1", "48 -1", "35 -1", "41 -1", *shaft_scan(3180, 3220, 1), "40 2 3200"),
        lines("7 2", "6 100", "3 1", "1 3 12000 -12000 0"), Run(350),
        lines("20 -1", "48 -1", "41 -1", *shaft_scan(2000, 5000, 16)),
        lines("7 3", "3 1", "25 200 1600 0 0", "25 100 -800 5000 -5000", "25 150 0 0 0"),
        Run(500), lines("20 -1", "48 -1", "27 -1", "35 -1", *shaft_scan(-64, 64, 1)),
        Power(), lines("44 -1", "48 -1", "20 -1"),
    ])
    status = replies(printed, "STATUS")
    steps = replies(printed, "STEPS")
    assert abs(status[0][1] - 3200) <= (0 if drive == 1 else 63)   # the turn, no cycle lost
    assert steps[0][0] != 0 and steps[-1] == [0, 0, 249]
    assert replies(printed, "DRIVE") == [[0]]
    assert any(line[4] not in (0, 249_000) for line in replies(printed, "D"))
    assert replies(printed, "PROBE")[0][1] >= 1   # the shaft reached the turn
    assert {probe[0] for probe in replies(printed, "PROBE")} == {0, 1}   # scans read it


def test_a_load_beyond_the_pull_out_torque_loses_steps_open_loop(driver: Driver) -> None:
    """700 mNm of load on a 590 mNm stepper: the open loop's counter (the steps issued) goes
    on to 6400 while the shaft stays at a turn (the probe surface at 5000 microsteps does
    not close); with the load light again the shaft follows the next turn from where it
    stopped, a turn short of the counter, and closes the probe there."""
    printed, replay = replay_both(driver, [
        lines(*STEPPER, "44 1", "40 2 5000", "21 50", "3 1", ramp(0, 3200, 160)), Run(200),
        lines("33 700 0", ramp(3200, 6400, 160)), Run(300),
        lines("20 -1", "48 -1", "41 -1", "33 20 0", ramp(6400, 9600, 160)), Run(300),
        lines("20 -1", "48 -1", "41 -1", *shaft_scan(6300, 6500, 2)),
    ])
    status = replies(printed, "STATUS")
    probe = replies(printed, "PROBE")
    assert status[0][1] == 6400 and probe[0][0] == 0   # counted, not moved: steps lost
    assert status[1][1] == 9600 and probe[1][:3] == [1, 1, 1]
    assert probe[1][3] > 5000 + 3000   # the counter where the shaft crossed 5000
    shaft = replay.device.state.shaft_micro_counts // 10**6
    assert abs(shaft - (9600 - 3200)) <= 8


def test_a_load_beyond_the_pull_out_torque_stalls_the_closed_loop(driver: Driver) -> None:
    """The same load on the closed loop: the shaft stalls where the load caught it (the field
    never leads it by more than a full step, so it does not slip), catches up once the load
    is light again, and with a following-error limit (call 29) the stall is fault 2."""
    printed, _ = replay_both(driver, [
        lines(*STEPPER, "44 2", "40 2 5000", "21 50", "3 1", ramp(0, 3200, 160)), Run(200),
        lines("33 700 0", ramp(3200, 6400, 160)), Run(300),
        lines("20 -1", "48 -1", "41 -1", "33 20 0"), Run(700), lines("20 -1", "48 -1", "41 -1"),
        lines("29 200", "33 700 0", ramp(6400, 9600, 160)), Run(300),
        lines("30 -1", "20 -1", "48 -1", "24 -1"),
    ])
    status = replies(printed, "STATUS")
    assert 3000 <= status[0][1] <= 3300 and status[0][2] == 6400   # stalled a turn behind
    assert abs(status[1][1] - 6400) <= 40   # caught up
    assert replies(printed, "PROBE")[1][:3] == [1, 1, 1]
    fault = replies(printed, "FAULT")[0]
    assert fault[0] == 2 and [2, fault[1]] in replies(printed, "ALARM")


def test_an_open_loop_beyond_its_pull_out_speed_loses_steps(driver: Driver) -> None:
    """Velocity mode ramped to 300,000 microsteps/s (5600 rpm, far above the 760 rpm corner
    where the torque starts to fall): the rotor falls behind, slips cycle after cycle and
    ends well short of the steps issued (the scans read it)."""
    printed, replay = replay_both(driver, [
        lines(*STEPPER, "44 1", "7 2", "21 40", "3 1",
              "1 400 " + " ".join(str(750 * k) for k in range(1, 401))), Run(420),
        lines("20 -1", "48 -1", *shaft_scan(0, 64_000, 512)),
    ])
    issued = replies(printed, "STEPS")[0][0]
    shaft = replay.device.state.shaft_micro_counts // 10**6
    assert issued > 50_000 and shaft < issued - 3200   # more than a turn lost
    assert {probe[0] for probe in replies(printed, "PROBE")} == {0, 1}


@pytest.mark.parametrize("drive", [1, 2])
def test_calls_23_and_37_shift_a_step_drive(driver: Driver, drive: int) -> None:
    """The counter's coordinates move; the driver's step counter (call 48) does not, and the
    steps that follow take the shaft where the new coordinates say."""
    printed, _ = replay_both(driver, [
        lines(*STEPPER, f"44 {drive}", "21 30", "3 1", ramp(0, 800, 80)), Run(400),
        lines("23 10000", "20 -1", "48 -1", "8 37 1", ramp(10000, 10400, 40)), Run(400),
        lines("37 -2500", "20 -1", "48 -1", ramp(7900, 7000, 60)), Run(400),
        lines("20 -1", "48 -1", "36 1", "41 -1"),
    ])
    status = replies(printed, "STATUS")
    steps = replies(printed, "STEPS")
    near = 20 if drive == 1 else 63  # closed loop: the rotor behind, within a cycle
    assert status[0][1] == 10000 and abs(steps[0][0] - 800) <= near
    assert abs(steps[1][0] - steps[0][0] - 400) <= near and abs(status[1][1] - 7900) <= near
    assert abs(status[2][1] - 7000) <= near and abs(steps[2][0] - steps[1][0] + 900) <= 2 * near


@pytest.mark.parametrize("drive", [1, 2])
def test_the_60_s_reset_of_velocity_mode_in_a_step_drive(driver: Driver, drive: int) -> None:
    """100 ms ticks (600 to the reset) in 10 ms integration steps, a heavy load: the
    counter goes to 0 after 60 s in velocity mode and the desired position moves with it,
    so the stepper runs on without a jump."""
    printed, _ = replay_both(driver, [
        lines("5 1000", "12 100", "17 1 -2", "33 20 0", "16 4000", f"44 {drive}", "7 2",
              "6 700", "21 100", "9 1 -1", "10 0 0", "11 0 0", "3 1", "0 300"), Run(590),
        lines("20 -1", "48 -1"), Run(20), lines("20 -1", "48 -1"), Run(60), lines("20 -1"),
    ])
    status = replies(printed, "STATUS")
    assert status[0][1] > 17_000 and abs(status[1][1]) < 1000   # reset between them
    assert status[2][1] > status[1][1]   # and on at the same speed


def test_the_step_drive_calls_refuse_and_answer(driver: Driver) -> None:
    """Call 44 refused while the servo is enabled and when no step fits the tick, call 46
    when no step would fit, call 47 with more detent than holding torque, call 5 to a
    period that fits no step in a step drive (and taken in the DC drive); the debug lines,
    the queries, and a power cycle back to the defaults."""
    replay_both(driver, [
        lines("3 1", "44 1", "3 0", "8 44 1", "8 45 1", "8 46 1", "8 47 1", "46 1000000 0",
              "46 100000 0", "44 1", "48 -1", "5 1", "5 -1", "47 100 200", "47 100 100 1",
              "47 -1 0 0", "45 0 5", "44 3", "45 400 8", "45 -1 0", "44 -1", "44 0", "5 1",
              "44 2", "46 -1 0", "46 2000 1000", "44 2", "48 -1", "3 1", "44 1", "3 0",
              "20 -1"),
        Power(), lines("44 -1", "45 -1 0", "46 -1 0", "47 -1 0 0", "48 -1"),
    ])


@pytest.mark.parametrize("scalar", [1, 3])
def test_replacing_the_queue_future(driver: Driver, scalar: int) -> None:
    ramp = " ".join(str(3 * k) for k in range(1, 401))
    steps: list[Step] = [lines("8 38 1", f"6 {scalar}", "3 1", f"1 400 {ramp}"),
                         Run(60 * scalar + 1)]
    clock = 60 * scalar + 1
    for lead in (-25, -1, 0, 1, 17):
        tick = clock + (scalar - 1) + lead * scalar
        steps += [lines(f"38 {tick} 5 1 2 3 4 5", "2 -1", "20 -1"), Run(7)]
        clock += 7
    steps += [lines("31 500", "38 510 3 7 8 9", "2 -1"), Run(400), lines("3 0", "38 0 1 9"),
              lines("3 1", "4 0", "1 1000 " + " ".join(["5"] * 999) + " 6"), Run(3),
              lines(f"38 {clock + 410} 991 " + " ".join(["1"] * 991), "2 -1"),
              lines(f"38 {clock + 410} 990 " + " ".join(["1"] * 990), "2 -1"), Run(20),
              lines("38 0 0", "2 -1", "20 -1"), Run(5), lines("20 -1")]
    assert_same(driver, steps)


@pytest.mark.parametrize("scalar", [1, 3])
def test_stopping_on_time_and_late(driver: Driver, scalar: int) -> None:
    """Call 50 on time (as call 38), late by one value and by more than its length (every
    value offset from the value due), in velocity mode (delayed, not offset), from an empty
    queue (offset from the held position), an offset beyond int32, and too many to fit."""
    ramp = " ".join(str(3 * k) for k in range(1, 401))
    steps: list[Step] = [lines("8 50 1", f"6 {scalar}")]
    clock = 0
    for lead in (17, 0, -1, -25):
        steps += [lines("3 0", "23 0", "3 1", f"1 400 {ramp}"), Run(60 * scalar + 1)]
        tick = clock + 60 * scalar + 1 + (scalar - 1) + lead * scalar
        steps += [lines(f"50 {tick} 5 190 193 195 196 196", "2 -1", "20 -1"), Run(9 * scalar)]
        clock += 69 * scalar + 1
    steps += [Run(100), lines(f"50 {clock + 10} 2 7 8", "20 -1"), Run(50),
              lines("3 0", "7 2", "3 1", "1 50 " + " ".join(["400"] * 50)), Run(20),
              lines("50 3 3 300 200 0", "2 -1", "20 -1"), Run(20), lines("20 -1"),
              lines("3 0", "7 1", "23 2147483000", "3 1", "1 3 2147483000 2147483100 2147483200"),
              Run(2), lines("50 0 2 -5 2147483647", "2 -1", "20 -1"),
              lines("3 0", "23 0", "3 1", "1 1000 " + " ".join(["5"] * 1000)), Run(3),
              lines(f"50 {10 ** 6} 991 " + " ".join(["1"] * 991), "2 -1"), Run(5),
              lines("7 3", "50 0 1 5")]
    printed = assert_same(driver, steps)
    text = [line.decode() for _, line in printed]
    acks = [[int(v) for v in line.split()[1:5]] for line in text if line.startswith("STOPPED")]
    assert [ack[1] for ack in acks[:4]] == [0, 0, 1, 25]  # late, in value periods
    assert [ack[3] for ack in acks] == [0, 0, -4, -4, 185, 0]  # offset: late, mode 1 only
    assert acks[0][0] == 17 and acks[4][1] > 0 and acks[5][1] > 0
    assert text.count("E50") == 2


@settings(max_examples=60, deadline=None)
@given(*EXTREME_PARAMETERS)
def test_extreme_parameters(driver: Driver, sci: list[tuple[int, int]], interval_dms: int,
                            sim_dms: int, counts: int, mode: int, target: int, drive: int) -> None:
    """test_robustness's extreme motors and gains, every value at its int64 edge."""
    with hang_guard(30.0):  # tick by tick: see test_a_stale_derivative_history_after_rest
        assert_same(driver, extreme_session(sci, interval_dms, sim_dms, counts, mode, target,
                                            drive))


_STALE_HISTORY = ["9 1 -12", "10 999 6", "11 999 6", "13 9999 3", "14 1 -12", "15 1 -12",
                  "17 1 -12", "32 1 -12", "33 999 6", "5 1", "12 1", "16 1", "7 1", "21 1",
                  "3 1", "1 3 -2147483648 2147483647 -2147483648"]


def test_a_stale_derivative_history_tick_by_tick(driver: Driver) -> None:
    assert_same(driver, [lines(*_STALE_HISTORY), *[Run(1)] * 14])


def test_a_stale_derivative_history_after_rest(driver: Driver) -> None:
    assert_same(driver, [lines(*_STALE_HISTORY), Run(14)])


def assert_fuzz_same(driver: Driver, steps: Sequence[Lines | Silence | PowerCycle]) -> None:
    """:func:`assert_same` on the fuzz session, then the power-up queries; the Python device
    that measured the session's budget is its replay (played once, not twice)."""
    replay = PythonReplay()
    session = [*fuzz_steps(steps, replay=replay), lines(*POWER_UP_QUERIES)]
    replay.play(session[-1])
    assert_same(driver, session, expected=replay.printed)


@fuzz_settings()
@given(st.lists(_STEP, min_size=1, max_size=8))
def test_fuzz_sessions(driver: Driver, steps: list[Lines | Silence | PowerCycle]) -> None:
    with hang_guard(30.0):
        assert_fuzz_same(driver, steps)


@fuzz_settings(quick=100)
@given(st.lists(st.one_of(_STEP, LOUD), min_size=1, max_size=10))
def test_fuzz_sessions_with_diagnostics(driver: Driver,
                                        steps: list[Lines | Silence | PowerCycle]) -> None:
    with hang_guard(30.0):
        assert_fuzz_same(driver, [Lines((b"21 3",), ()), *steps])


# --- the test of the test ----------------------------------------------------------------


def test_one_changed_byte_or_tick_is_caught(driver: Path) -> None:
    steps: list[Step] = [lines("21 5", "3 1", "0 20", "8 1 1", "1 2 3 4"), Run(12),
                         lines("20 -1", "18 -1")]
    expected = python_replay(steps)
    actual = native_replay(driver, steps)
    assert actual == expected
    changed = 0
    for index, (tick, line) in enumerate(actual):
        for at in range(len(line)):
            mutated = list(actual)
            byte = bytes([line[at] ^ 0x01])
            mutated[index] = (tick, line[:at] + byte + line[at + 1 :])
            assert mutated != expected, (index, at)
            changed += 1
        for delta in (-1, 1):
            mutated = list(actual)
            mutated[index] = (tick + delta, line)
            assert mutated != expected
    assert changed == sum(len(line) for _, line in actual) > 100
    # and through the driver's own output: one hex digit changed fails the parse's compare
    result = subprocess.run([str(driver)], input=session_text(steps), capture_output=True,
                            text=True, check=True)
    text = result.stdout
    at = text.index(" ") + 1
    digit = "1" if text[at] != "1" else "2"
    assert parse_driver_output(text) == expected
    assert parse_driver_output(text[:at] + digit + text[at + 1 :]) != expected


@pytest.mark.parametrize("mutation", ["byte", "tick", "line dropped", "newline lost"])
def test_assert_same_fails_on_a_mutated_firmware_output(
        driver: Path, monkeypatch: pytest.MonkeyPatch, mutation: str) -> None:
    steps: list[Step] = [lines("21 4", "3 1", "0 20"), Run(9), lines("20 -1")]
    real = native_replay

    def mutated(driver_: Path, steps_: Iterable[Step], *, flash: Path | None = None) -> Printed:
        printed = real(driver_, steps_, flash=flash)
        tick, line = printed[1]
        if mutation == "byte":
            printed[1] = (tick, line[:-1] + bytes([line[-1] ^ 0x20]))
        elif mutation == "tick":
            printed[1] = (tick + 1, line)
        elif mutation == "line dropped":
            del printed[1]
        else:
            printed[1] = (tick, line + b" <no newline>")
        return printed

    assert_same(driver, steps)
    monkeypatch.setitem(globals(), "native_replay", mutated)
    with pytest.raises(AssertionError, match=r"line 1|only the Python"):
        assert_same(driver, steps)


def test_the_calls_of_the_table_are_all_exercised() -> None:
    covered = {int(line.split()[0]) for _, line, _ in DEBUG_LINES}
    covered |= {int(line.split()[0]) for line in POWER_UP_QUERIES}
    assert covered == {spec.number for spec in CALLS}


# --- the generated call table ------------------------------------------------------------


def _generator() -> ModuleType:
    path = ROOT / "firmware" / "tools" / "gen_table.py"
    spec = importlib.util.spec_from_file_location("gen_table", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_generated_table_is_the_python_table() -> None:
    generator = _generator()
    for path, text in generator.generated().items():
        assert path.read_text(encoding="ascii") == text, (
            f"{path.name} is stale: run .venv/bin/python firmware/tools/gen_table.py")


def test_a_changed_python_table_makes_the_generated_one_stale(
        monkeypatch: pytest.MonkeyPatch) -> None:
    generator = _generator()
    before = generator.source()
    changed = replace(generator.CALLS[5], params=(replace(generator.CALLS[5].params[0],
                                                          maximum=9999),))
    monkeypatch.setattr(generator, "CALLS", (*generator.CALLS[:5], changed,
                                             *generator.CALLS[6:]))
    assert generator.source() != before
    assert "{\"interval_dms\", 1, 9999}" in generator.source()


# --- flash: a power cut at any point leaves the old value or the new one ------------------


def _names(printed: Printed) -> list[str]:
    return [text.decode().removeprefix("DEVICE_NAME ") for _, text in printed
            if text.startswith(b"DEVICE_NAME ")]


def _name_line(name: str) -> str:
    return f"18 {len(name)} " + " ".join(str(ord(c)) for c in name)


def _cut_session(writes_before: int, cut_at: int) -> str:
    """`writes_before` names written, then one whose flash operation stops after `cut_at`
    bytes, a power cycle, the name asked, one more write and its name after a power cycle."""
    steps = [f"feed {lines(_name_line(f'N{i}')).data.hex()}" for i in range(writes_before)]
    steps += [f"flash-fail {cut_at}", f"feed {lines(_name_line('NEW')).data.hex()}", "power",
              f"feed {lines('18 -1', '19 -1').data.hex()}",
              f"feed {lines(_name_line('AFTER'), '19 3').data.hex()}", "power",
              f"feed {lines('18 -1', '19 -1').data.hex()}"]
    return "".join(step + "\n" for step in steps)


@pytest.mark.parametrize("writes_before", [0, 1, 15, 16, 31, 32, 40])
def test_a_power_cut_in_a_flash_write_leaves_the_old_or_the_new_name(
        driver: Path, writes_before: int) -> None:
    """Cuts inside a page program, and (after 16 or 32 writes, a full sector) inside the
    erase of the other sector, at byte offsets across the record and beyond."""
    old = f"N{writes_before - 1}" if writes_before else "GENERIC USB MOTION DEVICE"
    for cut_at in (0, 1, 4, 8, 20, 35, 36, 39, 40, 41, 255, 256, 1000, 4095):
        result = subprocess.run([str(driver)], input=_cut_session(writes_before, cut_at),
                                capture_output=True, text=True, check=True)
        printed = parse_driver_output(result.stdout)
        texts = [text.decode() for _, text in printed]
        failed = [t for t in texts if t.startswith("ERR 18 flash write failed, value unchanged: ")]
        assert len(failed) == 1, texts
        names = _names(printed)
        assert names[0] in (old, "NEW"), (cut_at, texts)
        assert names[1] == "AFTER", (cut_at, texts)
        assert texts[-1] == "DEFAULT_CONTROL_MODE 3"


def test_flash_survives_in_its_file_and_a_failed_write_changes_nothing(
        driver: Path, tmp_path: Path) -> None:
    flash = tmp_path / "flash.bin"
    first = native_replay(driver, [lines(_name_line("AXIS X"), "19 2", "18 -1")], flash=flash)
    assert [t for _, t in first] == [b"DEVICE_NAME AXIS X"]
    again = native_replay(driver, [lines("18 -1", "19 -1", "7 -1")], flash=flash)
    assert [t for _, t in again] == [b"DEVICE_NAME AXIS X", b"DEFAULT_CONTROL_MODE 2",
                                     b"CONTROL_MODE 2"]
    session = ("flash-fail 0\n" + f"feed {lines('8 19 1', '19 3', '19 -1', '7 -1').data.hex()}\n")
    result = subprocess.run([str(driver), "--flash", str(flash)], input=session,
                            capture_output=True, text=True, check=True)
    texts = [t.decode() for _, t in parse_driver_output(result.stdout)]
    assert texts[0].startswith("ERR 19 flash write failed, value unchanged: ")
    assert texts[1:] == ["DEFAULT_CONTROL_MODE 2", "CONTROL_MODE 2"]
    assert flash.stat().st_size == 2 * 4096
