"""Garbage on the wire: the device never raises, answers each malformed line with exactly one
``ERR`` line, and changes its queue and variables only through valid calls."""

from __future__ import annotations

import functools
from dataclasses import fields

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from usbmotion.device import Device, DeviceSettings
from usbmotion.errors import EmptyLineError, ProtocolError
from usbmotion.protocol import CALLS, MAX_LINE_BYTES, ReplyKind, format_err, parse_call, parse_reply
from usbmotion.protocol.table import BY_NUMBER

from .helpers import send

# Which parts of the device each valid call may change ("queue" and "keyframes" are the
# buffers; the rest are DeviceSettings fields or state words).
_MAY_CHANGE: dict[int, set[str]] = {
    0: {"queue"},
    1: {"queue"},
    3: {"enable", "desired"},
    4: {"queue"},
    5: {"servo_update_interval_us", "queue", "keyframes"},
    6: {"motion_update_interval_scalar", "queue"},
    7: {"control_mode", "queue", "keyframes", "desired"},
    8: {"debug_flags"},
    9: {"gains"},
    10: {"gains"},
    11: {"gains"},
    12: {"motor"},
    13: {"motor"},
    14: {"motor"},
    15: {"motor"},
    16: {"motor"},
    17: {"motor"},
    18: {"name", "flash_writes"},
    19: {"default_control_mode", "flash_writes"},
    39: {"flash_writes"},
    21: {"diagnostics_interval"},
    22: {"clock"},
    23: {"queue", "keyframes", "actual", "desired"},
    25: {"keyframes"},
    26: {"keyframes"},
    28: {"watchdog_ms"},
    29: {"following_error_limit"},
    30: {"fault"},
    31: {"start_tick"},
    32: {"motor"},
    33: {"motor"},
    34: {"motor"},
    37: {"queue", "keyframes", "actual", "desired"},
    38: {"queue"},
    44: {"drive", "queue", "keyframes", "actual", "desired"},
    45: {"stepper", "queue", "keyframes"},
    46: {"stepper"},
    47: {"stepper"},
    49: {"encoder", "queue", "keyframes", "actual", "desired"},
    50: {"queue"},
}
_SETTINGS = [f.name for f in fields(DeviceSettings)]


def _snapshot(device: Device) -> dict[str, object]:
    snap: dict[str, object] = {
        name: getattr(device.settings, name) for name in _SETTINGS
    }
    state = device.state
    snap.update(
        queue=device.queue_values(),
        keyframes=device.keyframes(),
        enable=state.enable,
        fault=state.fault,
        clock=state.clock,
        actual=state.actual,
        desired=state.desired,
    )
    return snap


def _check_line(device: Device, line: bytes) -> None:
    """Feed one line and check the device against the model."""
    before = _snapshot(device)
    device.feed(line + b"\n")
    out = device.take_output().decode("ascii").splitlines()
    after = _snapshot(device)
    try:
        call = parse_call(line)
    except EmptyLineError:
        assert out == []
        assert after == before
        return
    except ProtocolError as error:
        assert out == [format_err(error).encode("ascii", "backslashreplace").decode("ascii")]
        assert out[0].startswith(f"ERR {'?' if error.call is None else error.call} ")
        assert after == before
        return
    replies = [parse_reply(text) for text in out]
    if any(r.kind in (ReplyKind.ERROR, ReplyKind.REFUSAL) for r in replies):
        assert len(replies) == 1, out
        assert replies[0].call == call.number
        assert after == before, "a refused call changes nothing"
        return
    assert all(r.call == call.number for r in replies), out
    allowed = set() if call.is_query else _MAY_CHANGE.get(call.number, set())
    changed = {key for key in before if before[key] != after[key]}
    assert changed <= allowed, (call, changed)
    if call.number in (0, 1) and not call.is_query:
        values = call.args if call.number == 0 else call.args[1:]
        assert after["queue"] == (*before["queue"], *values)  # type: ignore[misc]


_SPECS = st.sampled_from(CALLS)


@functools.cache
def _any_integers(count: int) -> st.SearchStrategy[list[int]]:
    return st.lists(st.integers(-(2**40), 2**40), min_size=count, max_size=count)


@functools.cache
def _argument(minimum: int, maximum: int) -> st.SearchStrategy[int]:
    """A value within a parameter's range (two times in three) or at or just past an end.

    Built once per range: a strategy made afresh at each draw is validated afresh, which
    cost more than the rest of the example."""
    inside = st.integers(minimum, maximum)
    near = st.sampled_from([minimum, maximum, minimum - 1, maximum + 1, 0, 1])
    return st.one_of(inside, inside, near)


@st.composite
def _integer_lines(draw: st.DrawFn) -> bytes:
    if draw(st.integers(0, 9)) == 0:
        number = draw(st.integers(-3, 70))
        count = draw(st.integers(0, 5))
        args = draw(_any_integers(count))
    else:
        spec = draw(_SPECS)
        number = spec.number
        params = list(spec.params)
        lead = len(spec.params) - 1
        if spec.counted and spec.item is not None:
            n = draw(st.integers(0, 4))
            params = [*spec.params, *[spec.item] * n]
        if spec.query is not None and draw(st.booleans()):
            args = [draw(st.integers(0, 63)) if q is None else q for q in spec.query]
        else:
            args = []
            for param in params:
                args.append(draw(_argument(param.minimum, param.maximum)))
            if spec.counted and args:
                if draw(st.integers(0, 3)) == 0:
                    args[lead] = draw(st.integers(-1, 30))
                else:
                    args[lead] = len(args) - lead - 1
        if draw(st.integers(0, 5)) == 0:
            args = args[: draw(st.integers(0, len(args)))] + draw(
                st.lists(st.integers(-5, 5), max_size=2)
            )
    tokens = [str(number), *map(str, args)]
    if draw(st.integers(0, 9)) == 0:
        position = draw(st.integers(0, len(tokens) - 1))
        tokens[position] = draw(st.sampled_from(["x", "1.5", "--1", "0x10", "", "+7", "1e3"]))
    if draw(st.integers(0, 19)) == 0:
        position = draw(st.integers(0, len(tokens) - 1))
        sign = draw(st.sampled_from(["", "-", "+"]))
        zeros = "0" * draw(st.sampled_from([0, 1, 30]))
        digits = draw(st.sampled_from([18, 19, 20, 4301, 9000]))
        tokens[position] = sign + zeros + "9" * (digits - 1) + "1"
    separator = draw(st.sampled_from([" ", "  ", "\t", " \t"]))
    text = separator.join(tokens)
    if draw(st.booleans()):
        text += "\r"
    return text.encode("ascii")


@settings(max_examples=500, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(_integer_lines(), min_size=1, max_size=4))
def test_random_integer_lines_follow_the_model(lines: list[bytes]) -> None:
    """On a device just powered up. The fuzz sessions check the same lines against the same
    model on devices in every state (tests/fuzz/test_device_fuzz.py)."""
    device = Device()
    for line in lines:
        _check_line(device, line)


@settings(max_examples=1000, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.binary(max_size=48).map(lambda b: b.replace(b"\n", b"")), max_size=4))
def test_random_bytes_follow_the_model(lines: list[bytes]) -> None:
    device = Device()
    send(device, "8 0 1", "8 1 1", "7 1")
    for line in lines:
        _check_line(device, line)


@settings(max_examples=200, deadline=None)
@given(st.binary(max_size=300), st.lists(st.integers(1, 40), min_size=1, max_size=8))
def test_any_byte_stream_in_any_split_never_raises(data: bytes, cuts: list[int]) -> None:
    device = Device()
    position = 0
    for cut in cuts:
        device.feed(data[position : position + cut])
        position += cut
    device.feed(data[position:] + b"\n")
    for line in device.take_output().decode("ascii").splitlines():
        parse_reply(line)
    assert send(device, "3 -1") in (["SERVO_ENABLE 0"], ["SERVO_ENABLE 1"])


# --- bad values on the wire ----------------------------------------------------------------

HUGE_LINES = [
    ("0 " + "7" * 18, "ERR 0 value 777777777777777777 is out of range -2147483648..2147483647"),
    ("0 -" + "7" * 19,
     "ERR 0 value -777777777777777777...(19 digits) is out of range -2147483648..2147483647"),
    ("0 +000" + "1" * 5000,
     "ERR 0 value 111111111111111111...(5000 digits) is out of range -2147483648..2147483647"),
    ("1 1 " + "2" * 4400,
     "ERR 1 value 222222222222222222...(4400 digits) is out of range -2147483648..2147483647"),
    ("1 " + "9" * 25 + " 1",
     "ERR 1 count 999999999999999999...(25 digits) is out of range 1..1000"),
    ("-" + "3" * 40 + " 1", "ERR ? unknown call"),
    ("3" * 19 + " x", "ERR ? input 1 'x' is not an integer"),
    ("8 " + "0" * 40 + "3 1", ""),
    ("0" * 4301, "ERR 0 wrong number of inputs"),
    ("0 -" + "0" * 4400 + "7", ""),
]


@pytest.mark.parametrize(("line", "reply"), HUGE_LINES)
def test_an_integer_of_any_length_is_read_without_a_fault(line: str, reply: str) -> None:
    """Integers beyond 18 significant digits are out of every range: refused with their
    digits abbreviated, never an internal error (Python's int() refuses 4,301 digits)."""
    device = Device()
    assert send(device, line) == ([reply] if reply else [])
    assert device.state.fault == 0
    for text in send(device, line):
        parse_reply(text)

BAD_LINES = [
    ("5 0", "ERR 5 interval_dms 0 is out of range 1..10000", "5 -1"),
    ("6 -5", "ERR 6 scalar -5 is out of range 1..65535", "6 -1"),
    ("7 4", "ERR 7 mode 4 is out of range 1..3", "7 -1"),
    ("7 0", "ERR 7 mode 0 is out of range 1..3", "7 -1"),
    ("18 30 " + " ".join(["65"] * 30), "ERR 18 length 30 is out of range 0..25", "18 -1"),
    ("9 1234 0", "ERR 9 coefficient 1234 is out of range 0..999", "9 -1 0"),
    ("10 5", "ERR 10 wrong number of inputs", "10 -1 0"),
    ("3 x", "ERR 3 input 1 'x' is not an integer", "3 -1"),
    ("99 1", "ERR 99 unknown call", "2 -1"),
    ("hello", "ERR ? executive call 'hello' is not an integer", "2 -1"),
]


@pytest.mark.parametrize(("line", "err", "query"), BAD_LINES)
def test_a_bad_value_is_one_err_line_and_changes_nothing(
    line: str, err: str, query: str
) -> None:
    device = Device()
    before = send(device, query)
    snapshot = _snapshot(device)
    assert send(device, line) == [err]
    assert send(device, query) == before
    assert _snapshot(device) == snapshot
    assert send(device, "0 5", "2 -1") == ["MOTION_QUEUE 1 999"], "the device keeps serving"


def test_an_over_long_line_is_one_err_and_the_next_line_works() -> None:
    device = Device()
    device.feed(b"1 " + b"7 " * MAX_LINE_BYTES)
    device.feed(b"7\n2 -1\n")
    assert device.take_output().decode().splitlines() == [
        f"ERR ? line longer than {MAX_LINE_BYTES} bytes",
        "MOTION_QUEUE 0 1000",
    ]


def test_empty_and_blank_lines_are_ignored() -> None:
    device = Device()
    device.feed(b"\n\r\n  \t \n\n")
    assert device.take_output() == b""


def test_a_full_queue_in_one_line_fits_the_line_buffer() -> None:
    device = Device()
    line = "1 1000 " + " ".join(["-2147483648"] * 1000)
    assert len(line) <= MAX_LINE_BYTES
    assert send(device, line, "2 -1") == ["MOTION_QUEUE 1000 0"]


def test_enabling_with_a_latched_fault_is_refused() -> None:
    device = Device()
    send(device, "29 1", "3 1", "0 100")
    device.run(1)
    assert device.state.fault == 2
    assert device.take_output() == b"ALARM 2 1\n"
    assert send(device, "3 1") == [
        "ERR 3 fault 2 (following error) is latched; clear it with call 30 before enabling"
    ]
    assert device.state.enable == 0


def test_an_unexpected_exception_is_an_err_reply_and_fault_4(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    device = Device()
    send(device, "3 1")

    def broken(call: object) -> None:
        raise RuntimeError("bad\nthing")

    monkeypatch.setitem(device._handlers, 24, broken)
    lines = send(device, "24 -1")
    assert lines == [
        "ERR 24 internal error (RuntimeError: bad thing); fault 4 latched",
        "ALARM 4 0",
    ]
    state = device.state
    assert (state.fault, state.enable) == (4, 0)
    assert send(device, "30 -1", "3 -1") == ["FAULT 4 0", "SERVO_ENABLE 0"]
    assert send(device, "30 0", "3 1", "3 -1") == ["SERVO_ENABLE 1"]


def test_an_exception_in_the_servo_loop_faults_and_keeps_the_clock(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    device = Device(fast=False)  # the reference path; test_kernel.py breaks the kernel
    send(device, "3 1", "0 100")
    calls = []

    def broken(*args: object) -> int:
        calls.append(args)
        raise ZeroDivisionError("oops")

    monkeypatch.setattr("usbmotion.device.core0.servo_block", broken)
    device.run(50)
    assert device.clock == 50
    assert send(device, "30 -1") == [
        "ERR ? internal error in the servo loop (ZeroDivisionError: oops); fault 4 latched",
        "ALARM 4 0",
        "FAULT 4 0",
    ]
    assert len(calls) == 1
    monkeypatch.undo()
    device.run(10)
    assert device.clock == 60


def test_every_call_number_in_the_table_has_a_handler() -> None:
    device = Device()
    assert set(device._handlers) == set(BY_NUMBER)


_SCI = st.tuples(st.sampled_from([1, 9999, 5, 1234]), st.sampled_from([-12, -6, 0, 3, 6]))


@settings(max_examples=150, deadline=None)
@given(
    st.fixed_dictionaries(
        {
            "9": _SCI.map(lambda p: (min(p[0], 999), p[1])),
            "10": _SCI.map(lambda p: (min(p[0], 999), p[1])),
            "11": _SCI.map(lambda p: (min(p[0], 999), p[1])),
            "13": _SCI,
            "14": _SCI,
            "15": _SCI,
            "17": _SCI,
            "32": _SCI,
            "33": _SCI,
        }
    ),
    st.sampled_from([1, 3, 10, 10000]),
    st.sampled_from([1, 10, 10000]),
    st.sampled_from([1, 1920, 1_000_000]),
    st.sampled_from([1, 2]),
    st.sampled_from([-(2**31), -1, 5000, 2**31 - 1]),
)
def test_extreme_parameters_keep_every_value_within_int64(
    sci: dict[str, tuple[int, int]],
    interval_dms: int,
    sim_dms: int,
    counts: int,
    mode: int,
    target: int,
) -> None:
    device = Device()
    lines = [f"{call} {c} {e}" for call, (c, e) in sci.items()]
    lines += [f"5 {interval_dms}", f"12 {sim_dms}", f"16 {counts}", f"7 {mode}", "3 1"]
    assert send(device, *lines) == []
    send(device, f"1 3 {target} {-target - 1} {target}")
    for _ in range(6):
        device.run(1 if interval_dms > 100 else 25)
        assert abs(device.state.shaft_speed_micro_counts_s) <= 10**12
    # a value beyond int64 cannot be stored in core1's state: it would latch fault 4
    assert b"internal error" not in device.take_output()
    assert device.state.fault in (0, 2, 3)
