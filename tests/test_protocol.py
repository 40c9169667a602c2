"""The command table and the line codec: round trips, malformed lines, PROTOCOL.md."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from usbmotion.errors import (
    EmptyLineError,
    LineTooLongError,
    NonIntegerTokenError,
    OutOfRangeError,
    ProtocolError,
    UnexpectedReplyError,
    UnknownCallError,
    WrongCountError,
)
from usbmotion.protocol import (
    CALLS,
    MAX_LINE_BYTES,
    Call,
    CallSpec,
    Diagnostics,
    LineSplitter,
    Overlong,
    ReplyKind,
    codec,
    encode_call,
    encode_counted,
    format_err,
    parse_call,
    parse_diagnostics,
    parse_reply,
)
from usbmotion.protocol.reference import render_reference, splice
from usbmotion.protocol.table import BY_NUMBER, DIAGNOSTICS, REST_FIELDS, max_steps_per_tick

ROOT = Path(__file__).resolve().parents[1]


def _valid_args(spec: CallSpec) -> tuple[int, ...]:
    """A valid non-query input tuple for the call: every value at its minimum."""
    if spec.counted:
        assert spec.item is not None
        count = max(spec.params[-1].minimum, 2)
        lead = tuple(p.minimum for p in spec.params[:-1])
        return (*lead, count, *([spec.item.minimum] * count))
    args = tuple(p.minimum for p in spec.params)
    if spec.number == 34:
        return (-1000, 1000)
    return args


def _example_calls() -> list[tuple[int, tuple[int, ...]]]:
    examples: list[tuple[int, tuple[int, ...]]] = []
    for spec in CALLS:
        examples.append((spec.number, _valid_args(spec)))
        if not spec.counted:
            examples.append((spec.number, tuple(p.maximum for p in spec.params)))
        if spec.query is not None:
            examples.append((spec.number, tuple(
                param.maximum if q is None else q
                for q, param in zip(spec.query, spec.params, strict=True))))
    return examples


@pytest.mark.parametrize(("number", "args"), _example_calls())
def test_every_call_round_trips(number: int, args: tuple[int, ...]) -> None:
    line = encode_call(number, *args)
    assert line.endswith(b"\n")
    assert parse_call(line) == Call(number, args)
    assert parse_call(line.replace(b"\n", b"\r\n")) == Call(number, args)
    assert Call(number, args).encode() == line


def test_the_table_has_every_call_of_the_design() -> None:
    assert sorted(BY_NUMBER) == list(range(51))
    for spec in CALLS:
        for template in spec.debug.values():
            assert template.fields == tuple(template.fields)
        if spec.query is not None:
            assert spec.query_reply is not None, spec.name


def test_seed_strings_are_to_the_letter() -> None:
    def debug(call: int) -> str:
        return BY_NUMBER[call].debug[1].text

    def query(call: int) -> str:
        template = BY_NUMBER[call].query_reply
        assert template is not None
        return template.text

    assert debug(0) == "S0 {value}"
    assert debug(1) == "S0 {count} {values}"
    assert BY_NUMBER[0].refusal == "E0"
    assert BY_NUMBER[1].refusal == "E1"
    assert query(3) == "SERVO_ENABLE {value}"
    assert debug(3) == "SERVO ENABLE MODIFIED TO {value}"
    assert query(5) == "SERVO_UPDATE_INTERVAL_US {value}"
    assert debug(5) == "SERVO LOOP INTERVAL MODIFIED TO {value} MICROSECONDS"
    assert query(6) == "MOTION_UPDATE_INTERVAL_SCALAR {value}"
    assert debug(6) == "MOTION UPDATE INTERVAL SCALAR MODIFIED TO {value}"
    assert query(7) == "CONTROL_MODE {value}"
    assert debug(7) == "Control Mode MODIFIED TO {value}"


@given(st.integers(-(2**31), 2**31 - 1), st.lists(st.integers(-(2**31), 2**31 - 1),
                                                   min_size=1, max_size=50))
@settings(max_examples=200, deadline=None)
def test_setpoint_calls_round_trip(single: int, values: list[int]) -> None:
    assert parse_call(encode_call(0, single)) == Call(0, (single,))
    call = parse_call(encode_call(1, len(values), *values))
    assert call.args == (len(values), *values)


def test_spaces_tabs_and_signs_are_accepted() -> None:
    assert parse_call(b"  1\t2  +5 -7 \r\n") == Call(1, (2, 5, -7))


@pytest.mark.parametrize(
    ("line", "error", "words"),
    [
        (b"99 1", UnknownCallError, ["99", "unknown"]),
        (b"-3 1", UnknownCallError, ["-3"]),
        (b"3", WrongCountError, ["call 3", "1 input", "got 0"]),
        (b"3 1 1", WrongCountError, ["got 2"]),
        (b"1 3 1 2", WrongCountError, ["announced 3", "carries 2"]),
        (b"1", WrongCountError, ["count"]),
        (b"3 x", NonIntegerTokenError, ["input 1", "'x'"]),
        (b"3 1.5", NonIntegerTokenError, ["'1.5'"]),
        (b"abc 1", NonIntegerTokenError, ["executive call", "'abc'"]),
        (b"3 2", OutOfRangeError, ["enable 2", "0..1"]),
        (b"5 0", OutOfRangeError, ["interval_dms 0", "1..10000"]),
        (b"6 -5", OutOfRangeError, ["scalar -5"]),
        (b"7 0", OutOfRangeError, ["mode 0", "1..3"]),
        (b"9 1234 0", OutOfRangeError, ["coefficient 1234", "0..999"]),
        (b"0 2147483648", OutOfRangeError, ["value 2147483648"]),
        (b"1 1001", OutOfRangeError, ["count 1001", "1..1000"]),
        (b"18 2 65 10", OutOfRangeError, ["character 10", "32..126"]),
        (b"18 26", OutOfRangeError, ["length 26", "0..25"]),
        (b"8 99 1", OutOfRangeError, ["call 99"]),
        (b"8 99 -1", OutOfRangeError, ["call 99"]),
        (b"   ", EmptyLineError, ["empty"]),
    ],
)
def test_malformed_lines_raise_the_typed_error(
    line: bytes, error: type[ProtocolError], words: list[str]
) -> None:
    with pytest.raises(error) as caught:
        parse_call(line)
    message = str(caught.value)
    for word in words:
        assert word in message, (word, message)
    answer = format_err(caught.value)
    assert answer.startswith("ERR ")
    assert "\n" not in answer
    assert parse_reply(answer).kind is ReplyKind.ERROR


def test_over_long_line_is_refused() -> None:
    line = b"1 1 " + b"1" * MAX_LINE_BYTES
    with pytest.raises(LineTooLongError, match="longer than"):
        parse_call(line)


def test_err_names_the_call_when_it_can() -> None:
    with pytest.raises(ProtocolError) as caught:
        parse_call(b"5 0")
    assert format_err(caught.value) == "ERR 5 interval_dms 0 is out of range 1..10000"
    with pytest.raises(ProtocolError) as caught:
        parse_call(b"zz")
    assert format_err(caught.value).startswith("ERR ? ")


@pytest.mark.parametrize(
    ("args", "message"),
    [
        ((3, 1.0), "every input is an int"),
        ((3, True), "every input is an int"),
        ((3, "1"), "every input is an int"),
        ((51, 1), "unknown executive call 51"),
        ((3, 7), "enable 7 is out of range 0..1"),
    ],
)
def test_encode_validates_before_anything_is_sent(
    args: tuple[object, ...], message: str
) -> None:
    with pytest.raises(ProtocolError, match=message):
        encode_call(*args)  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("line", "kind", "call", "key", "values", "text"),
    [
        ("SERVO_ENABLE 0", ReplyKind.QUERY, 3, "SERVO_ENABLE", (0,), ""),
        ("SERVO_ENABLE 1 \n", ReplyKind.QUERY, 3, "SERVO_ENABLE", (1,), ""),
        ("SERVO ENABLE MODIFIED TO 1", ReplyKind.DEBUG, 3, "SERVO ENABLE MODIFIED TO", (1,), ""),
        ("S0 3910", ReplyKind.DEBUG, 0, "S0", (3910,), ""),
        ("S0 3 4929 2904 103049", ReplyKind.DEBUG, 1, "S0", (3,), "4929 2904 103049"),
        ("E0", ReplyKind.REFUSAL, 0, "E0", (), ""),
        ("E1", ReplyKind.REFUSAL, 1, "E1", (), ""),
        ("E25", ReplyKind.REFUSAL, 25, "E25", (), ""),
        ("MOTION_QUEUE 10 990", ReplyKind.QUERY, 2, "MOTION_QUEUE", (10, 990), ""),
        ("Control Mode MODIFIED TO 2", ReplyKind.DEBUG, 7, "Control Mode MODIFIED TO", (2,), ""),
        ("DEVICE_NAME ROBOT LEFT LEG", ReplyKind.QUERY, 18, "DEVICE_NAME", (), "ROBOT LEFT LEG"),
        ("PROPORTIONAL_GAIN 12 -3", ReplyKind.QUERY, 9, "PROPORTIONAL_GAIN", (12, -3), ""),
        ("STATUS 1 2 3 4 5 1 1 0 0", ReplyKind.QUERY, 20, "STATUS",
         (1, 2, 3, 4, 5, 1, 1, 0, 0), ""),
        ("D 10 5 4 100 -2500 7 -3", ReplyKind.DIAGNOSTICS, None, "D",
         (10, 5, 4, 100, -2500, 7, -3), ""),
        ("ERR 5 interval_dms 0 is out of range", ReplyKind.ERROR, 5, "ERR", (),
         "interval_dms 0 is out of range"),
        ("ERR ? empty line", ReplyKind.ERROR, None, "ERR", (), "empty line"),
    ],
)
def test_replies_parse(
    line: str, kind: ReplyKind, call: int | None, key: str, values: tuple[int, ...], text: str
) -> None:
    reply = parse_reply(line)
    assert (reply.kind, reply.call, reply.key, reply.values, reply.text) == (
        kind, call, key, values, text
    )


def test_every_template_parses_back_to_its_call() -> None:
    for spec in CALLS:
        templates = [(ReplyKind.DEBUG, t) for t in spec.debug.values()]
        if spec.query_reply is not None:
            templates.append((ReplyKind.QUERY, spec.query_reply))
        for kind, template in templates:
            sample = [("NAME X" if f in ("text", "values") else 7) for f in template.fields]
            reply = parse_reply(template.format(*sample))
            assert (reply.kind, reply.call) == (kind, spec.number), template.text


def test_a_diagnostics_line_reads_by_field_name() -> None:
    line = b"D 10 5 4 100 -2500 7 -2147483648\n"
    values = parse_diagnostics(line)
    assert values == parse_reply(line).values
    assert values is not None
    assert Diagnostics.from_values(values) == Diagnostics(
        clock=10, desired=5, actual_counts=4, velocity_counts_s=100, output_mv=-2500, queued=7,
        peak_error_counts=-(2**31))


@given(st.lists(st.integers(min_value=-(2**63), max_value=2**63 - 1), min_size=7, max_size=7))
@settings(max_examples=200, deadline=None)
def test_a_diagnostics_line_formats_the_same_in_one_step(values: list[int]) -> None:
    """What a device prints per record (``int_line_format``) is ``format``'s line."""
    assert DIAGNOSTICS.int_line_format() % tuple(values) == (
        DIAGNOSTICS.format(*values) + "\n").encode("ascii")


def test_a_template_with_text_has_no_integer_line_format() -> None:
    text = next(t for spec in CALLS for t in spec.debug.values()
                if any(f in REST_FIELDS for f in t.fields))
    with pytest.raises(ValueError, match="takes text"):
        text.int_line_format()


@pytest.mark.parametrize("line", ["", "HELLO", "SERVO_ENABLE x", "E9", "MOTION_QUEUE 1",
                                  "D 10 5 4 100 -2500 7", "D 10 5 4 100 -2500 7 1 2"])
def test_unexpected_replies_raise(line: str) -> None:
    with pytest.raises(UnexpectedReplyError):
        parse_reply(line)


@given(st.lists(st.binary(max_size=40), max_size=20), st.data())
@settings(max_examples=300, deadline=None)
def test_line_splitter_is_independent_of_chunking(chunks: list[bytes], data: st.DataObject) -> None:
    stream = b"\n".join(chunks) + b"\n"
    whole = LineSplitter(max_bytes=64).feed(stream)
    cuts = sorted(data.draw(st.lists(st.integers(0, len(stream)), max_size=10)))
    splitter = LineSplitter(max_bytes=64)
    pieces: list[bytes | Overlong] = []
    last = 0
    for cut in [*cuts, len(stream)]:
        pieces += splitter.feed(stream[last:cut])
        last = cut
    assert [p if isinstance(p, bytes) else "long" for p in pieces] == [
        p if isinstance(p, bytes) else "long" for p in whole
    ]
    assert splitter.pending == 0


def test_line_splitter_bounds_a_garbage_stream() -> None:
    splitter = LineSplitter(max_bytes=16)
    out = splitter.feed(b"x" * 1000)
    assert out == []
    assert splitter.pending == 0
    out = splitter.feed(b"yy\n3 1\n")
    assert isinstance(out[0], Overlong)
    assert out[0].length == 1002
    assert out[1] == b"3 1"


def test_protocol_md_matches_the_table() -> None:
    document = (ROOT / "PROTOCOL.md").read_text(encoding="utf-8")
    assert splice(document, render_reference()) == document, (
        "PROTOCOL.md disagrees with the command table; regenerate it with "
        "`python -m usbmotion.protocol.reference --write PROTOCOL.md`"
    )


def _outcome(action: Callable[[], object]) -> object:
    """What ``action`` returns, or the type and message of what it raises."""
    try:
        return action()
    except ProtocolError as error:
        return (type(error), str(error))


_TOKENS = st.one_of(
    st.integers(-(2**31), 2**31 - 1).map(str),
    st.integers(-(10**25), 10**25).map(str),
    st.sampled_from(["-", "--5", "5-", "+7", "-0", "007", "1-2", "- 3", "99999999999999999999"]),
)


@given(st.sampled_from([0, 1, 3, 18, 38]), st.lists(_TOKENS, min_size=0, max_size=120),
       st.sampled_from([" ", "  ", "\t", " \t", " \r "]),
       st.sampled_from(["\n", "\r\n", "", " \n", "-", "-\n"]))
@settings(max_examples=400, deadline=None)
def test_a_long_line_of_numbers_parses_as_token_by_token(
    number: int, tokens: list[str], gap: str, end: str
) -> None:
    """The bulk conversion of long lines (numpy, one pass) answers exactly what the
    token-by-token path answers (``parse_call`` of text), errors and messages included."""
    count = [str(len(tokens))] if number in (1, 18) else []
    line = gap.join([str(number), *count, *tokens]) + end
    assert _outcome(lambda: parse_call(line.encode("ascii"))) == _outcome(
        lambda: parse_call(line))


@pytest.mark.parametrize("values", [list(range(-300, 300)), list(range(600))],
                         ids=["signed", "unsigned"])
def test_the_bulk_path_is_taken_and_refuses_a_misplaced_sign(values: list[int]) -> None:
    line = encode_call(1, len(values), *values)
    assert len(line) > codec.BULK_BYTES
    assert parse_call(line) == Call(1, (len(values), *values))
    for bad in (b" 5- ", b" -- ", b" - ", b" 1-2 ", b" +-3 ", b" 5+ ", b" ++3 ", b" + ",
                b" 1+2 "):
        broken = line.replace(b" 7 ", bad, 1)
        with pytest.raises(NonIntegerTokenError):
            parse_call(broken)
    assert parse_call(line.replace(b" 7 ", b" +7 ", 1)) == Call(1, (len(values), *values))
    huge = line.replace(b" 7 ", b" 99999999999999999999999 ", 1)
    with pytest.raises(OutOfRangeError, match=r"999999999999999999\.\.\.\(23 digits\)"):
        parse_call(huge)


@given(st.sampled_from([1, 18, 38, 3]),
       st.lists(st.integers(-(2**33), 2**33), min_size=0, max_size=30),
       st.lists(st.integers(-(2**31), 2**31), min_size=0, max_size=2),
       st.sampled_from(["int64", "int32", "int16", "int8", "uint64", "uint32", "uint8"]))
@settings(max_examples=300, deadline=None)
def test_a_counted_call_encodes_as_encode_call(number: int, items: list[int],
                                               lead: list[int], dtype: str) -> None:
    """``encode_counted`` gives the bytes (or the error) ``encode_call`` gives, whatever
    the items' integer type (one that holds only values in range is not scanned)."""
    held = np.iinfo(dtype)
    items = [value for value in items if held.min <= value <= held.max]
    array = np.asarray(items, dtype=dtype)
    expected = _outcome(lambda: encode_call(number, *lead, len(items), *items))
    assert _outcome(lambda: encode_counted(number, tuple(lead), array)) == expected
    assert _outcome(lambda: encode_counted(number, tuple(lead), items)) == expected


def test_a_batch_just_encoded_parses_as_its_text_converted() -> None:
    """A simulated device reads the batch its host encoded: recalled rather than converted,
    the same call, kept whole when the host's array changes afterwards."""
    values = np.arange(-300, 300, dtype=np.int64)
    line = encode_counted(1, (), values).rstrip(b"\n")
    remembered = parse_call(line)
    assert remembered is codec._encoded_batches[line]
    values[0] = 12345
    codec._encoded_batches.clear()
    converted = parse_call(line)
    assert remembered == converted == Call(1, (600, *range(-300, 300)))
    assert remembered.items is not None and converted.items is not None
    assert remembered.items.tolist() == converted.items.tolist() == list(range(-300, 300))
    assert parse_call(encode_counted(1, (), values).rstrip(b"\n")).items[0] == 12345


@pytest.mark.parametrize(("tick_us", "pulse_ns", "setup_ns", "steps"),
                         [(1000, 100, 20, 4807), (1000, 2000, 1000, 249), (100, 2000, 1000, 24),
                          (100, 5000, 0, 10), (1000, 1_000_000, 0, 0), (250, 333, 17, 371)])
def test_the_steps_a_tick_can_issue(tick_us: int, pulse_ns: int, setup_ns: int,
                                    steps: int) -> None:
    """Call 46's count, which the device issues at most and a host checks a step rate
    against: (tick - set-up) // (2 x pulse), each in 8 ns periods rounded up (250 us with
    333 ns pulses after 17 ns: (31,250 - 3) // 84 = 371)."""
    assert max_steps_per_tick(tick_us, pulse_ns, setup_ns) == steps
