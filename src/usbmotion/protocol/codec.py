"""The line codec: calls to bytes and lines to calls or replies. No I/O, no clocks.

A line is ASCII: the executive call number, then its supporting inputs, all decimal
integers separated by spaces or tabs, ended by ``\\n`` (a ``\\r`` before it is ignored).
"""

from __future__ import annotations

import functools
import re
import zlib
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from enum import Enum
from typing import cast

import numpy as np
import numpy.typing as npt

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
from usbmotion.protocol.names import CallNumber
from usbmotion.protocol.table import (
    ALARM,
    BY_NUMBER,
    CALLS,
    DIAGNOSTICS,
    ERR,
    MAX_LINE_BYTES,
    REFUSALS,
    REST_FIELDS,
    CallSpec,
    Template,
)

_INT = re.compile(r"[+-]?\d+\Z")
_NUMERIC = b"0123456789+- \t\r\n"
"""The bytes of a line of decimal integers: a line of nothing else is converted at C speed
by :func:`parse_call` (``int`` then rejects a misplaced sign); anything else takes the
token-by-token path that names the offending token."""


@dataclass(frozen=True, slots=True)
class Call:
    """One executive call with its supporting inputs."""

    number: int
    args: tuple[int, ...]
    items: npt.NDArray[np.int64] | None = field(default=None, compare=False, repr=False)
    """A counted call's items as an array, when the line was converted in bulk (the same
    values as the end of ``args``)."""

    @property
    def spec(self) -> CallSpec:
        """The table entry of this call."""
        return BY_NUMBER[self.number]

    @property
    def is_query(self) -> bool:
        """True when the inputs are the call's query form."""
        return self.spec.is_query(self.args)

    def encode(self) -> bytes:
        """The call as one line of bytes, newline included."""
        return encode_call(self.number, *self.args)


def check_call(number: int, args: tuple[int, ...]) -> CallSpec:
    """Validate a call against the table and return its spec.

    Raises:
        UnknownCallError: no such call number.
        WrongCountError: wrong number of supporting inputs.
        OutOfRangeError: an input outside its range (the message names it).
    """
    call_spec = BY_NUMBER.get(number)
    if call_spec is None:
        raise UnknownCallError(
            f"unknown executive call {number!r}; known calls are {_known_calls()}",
            call=None if isinstance(number, HugeInteger) else number,
            reason="unknown call",
        )
    problem = call_spec.problem(args)
    if problem is not None:
        kind, message = problem
        if kind == "count":
            raise WrongCountError(message, call=number, reason="wrong number of inputs")
        raise OutOfRangeError(message, call=number, reason=message)
    return call_spec


def encode_call(number: int, *args: int) -> bytes:
    """Validate a call and encode it as one ASCII line ending in ``\\n``.

    Raises:
        UnknownCallError, WrongCountError, OutOfRangeError: see :func:`check_call`.
        NonIntegerTokenError: an input is not an ``int`` (``bool`` included).
    """
    if type(number) is CallNumber:
        number = int(number)
    types = set(map(type, args))
    if CallNumber in types:
        args = tuple(int(a) if type(a) is CallNumber else a for a in args)
        types = set(map(type, args))
    if type(number) is int and types <= {int}:
        return _encoded(number, args)
    for position, value in enumerate((number, *args)):
        if type(value) is not int:
            raise NonIntegerTokenError(
                f"input {position} of call {number!r} is {value!r}; every input is an int",
                call=number if type(number) is int else None,
                reason="not an integer",
            )
    raise AssertionError("unreachable: a non-int input was found above")


@functools.lru_cache(maxsize=256)
def _encoded(number: int, args: tuple[int, ...]) -> bytes:
    """A valid call as a line, remembered: a host sends the same few calls again and again
    (the queue and status queries)."""
    check_call(number, args)
    if args:
        return f"{number} {_format(len(args)) % args}\n".encode("ascii")
    return f"{number}\n".encode("ascii")


@functools.lru_cache(maxsize=64)
def _format(count: int) -> str:
    """``count`` decimal integers separated by spaces, as a format string (``%`` formats
    a batch of setpoints in half the time of ``str`` on each)."""
    return " ".join(("%d",) * count)


@functools.lru_cache(maxsize=64)
def _bytes_format(count: int) -> bytes:
    """:func:`_format` as bytes (a batch formatted straight to its line's bytes)."""
    return b" ".join((b"%d",) * count)


REMEMBERED_BATCHES = 16
"""How many of the counted calls it encoded last :func:`parse_call` knows by their line."""
_encoded_batches: dict[bytes, Call] = {}


def encode_counted(number: int, lead: Sequence[int],
                   items: Sequence[int] | npt.NDArray[np.integer]) -> bytes:
    """A counted call (``number``, the inputs ``lead`` before the count, then the count
    and the ``items``) as one line: what ``encode_call(number, *lead, len(items),
    *items)`` gives, with the items checked as one array.

    Raises:
        UnknownCallError, WrongCountError, OutOfRangeError, NonIntegerTokenError: as
            :func:`encode_call` (the message names the first offending input).
    """
    spec = BY_NUMBER.get(number)
    array = np.asarray(items)
    inputs = (*lead, array.size)
    if (spec is not None and array.ndim == 1 and array.dtype.kind in "iu"
            and all(type(value) is int for value in lead)
            and _counted_fits(spec, inputs, array)):
        head = b"%d %b" % (number, _bytes_format(len(inputs)) % inputs)
        if not array.size:
            return head + b"\n"
        values = tuple(array.tolist())
        line = b"%b %b" % (head, _bytes_format(len(values)) % values)
        if len(line) > BULK_BYTES:
            _remember_batch(line, int(number), inputs + values, array)
        return line + b"\n"
    listed = array.tolist() if isinstance(items, np.ndarray) else list(items)
    return encode_call(number, *lead, len(listed), *listed)


def _remember_batch(line: bytes, number: int, args: tuple[int, ...],
                   items: npt.NDArray[np.integer]) -> None:
    """Keep the call as what ``line`` (without its newline) parses to: a simulated device
    reads the batch its host just encoded, and need not convert its text back. The items
    are kept as a read-only copy (the caller's array may change afterwards)."""
    kept = items.astype(np.int64)  # a copy, whatever the caller's integer type
    kept.flags.writeable = False
    if len(_encoded_batches) >= REMEMBERED_BATCHES:
        _encoded_batches.clear()
    _encoded_batches[line] = Call(number, args, kept)


def device_name_problem(name: object, *, allow_empty: bool = True) -> str | None:
    """Why ``name`` cannot be a device name (call 18's length and characters), or ``None``.

    ``allow_empty``: the empty name is allowed (call 18 then erases the name and the
    device answers to :data:`~usbmotion.protocol.table.DEFAULT_DEVICE_NAME`).
    """
    name_call = BY_NUMBER[CallNumber.SET_DEVICE_NAME]
    longest = name_call.params[-1].maximum
    character = name_call.item
    assert character is not None
    if not isinstance(name, str):
        return f"device name {name!r} is not text"
    if not name and not allow_empty:
        return f"device name {name!r} is empty; a name has 1..{longest} characters"
    if len(name) > longest:
        return (f"device name {name!r} is longer than {longest} characters; a name is up to"
                f" {longest} printable ASCII characters")
    bad = [c for c in name if not character.minimum <= ord(c) <= character.maximum]
    if bad:
        return (f"device name {name!r} holds {bad[0]!r}; only printable ASCII"
                f" ({character.minimum}..{character.maximum})")
    return None


def encode_device_name(name: str) -> bytes:
    """Call 18 writing ``name`` to the device's flash, as one line.

    Raises:
        OutOfRangeError: ``name`` is no device name (see :func:`device_name_problem`).
    """
    problem = device_name_problem(name)
    if problem is not None:
        raise OutOfRangeError(problem, call=CallNumber.SET_DEVICE_NAME, reason="name")
    return encode_call(CallNumber.SET_DEVICE_NAME, len(name), *(ord(c) for c in name))


def values_crc32(values: Sequence[int] | npt.NDArray[np.integer]) -> int:
    """CRC-32 (zlib) of setpoints as 32-bit little-endian two's complement integers.

    What a device answers a batch with when call 1's debug flag is 2 (``ADDED N CRC c``).
    """
    return zlib.crc32(np.asarray(values, dtype="<i4").tobytes())


def parse_call(line: bytes | str) -> Call:
    """Parse one line (with or without its newline) into a validated :class:`Call`.

    Never returns a half-parsed call: any problem raises.

    Raises:
        LineTooLongError: longer than :data:`MAX_LINE_BYTES`.
        EmptyLineError: no tokens.
        NonIntegerTokenError: a token is not a decimal integer (names it).
        UnknownCallError, WrongCountError, OutOfRangeError: see :func:`check_call`.
    """
    if type(line) is bytes:
        if len(line) <= BULK_BYTES:
            return _short_call(line)
        known = _encoded_batches.get(line)
        if known is not None:
            return known
    return _parse_call(line)


@functools.lru_cache(maxsize=256)
def _short_call(line: bytes) -> Call:
    """:func:`parse_call` of a short line, remembered (a line that raises is not): a device
    reads the same few lines again and again (the queue and status queries)."""
    return _parse_call(line)


def _parse_call(line: bytes | str) -> Call:
    if isinstance(line, bytes):
        if len(line) <= MAX_LINE_BYTES and not line.translate(None, _NUMERIC):
            if len(line) > BULK_BYTES:
                bulk = _bulk_call(line)
                if bulk is not None:
                    return bulk
            try:
                numbers = list(map(int, line.split()))
            except ValueError:
                numbers = []
            if numbers and min(numbers) > -HUGE_INTEGER and max(numbers) < HUGE_INTEGER:
                number, args = numbers[0], tuple(numbers[1:])
                check_call(number, args)
                return Call(number, args)
        if len(line.rstrip(b"\r\n")) > MAX_LINE_BYTES:
            raise LineTooLongError(
                f"line of {len(line)} bytes is longer than {MAX_LINE_BYTES}",
                reason=f"line longer than {MAX_LINE_BYTES} bytes",
            )
        text = line.decode("ascii", errors="replace")
    else:
        text = line
        if len(text.rstrip("\r\n")) > MAX_LINE_BYTES:
            raise LineTooLongError(
                f"line of {len(text)} characters is longer than {MAX_LINE_BYTES}",
                reason=f"line longer than {MAX_LINE_BYTES} bytes",
            )
    tokens = text.split()
    if not tokens:
        raise EmptyLineError("empty line", reason="empty line")
    number = _to_int(tokens[0], None, 0)
    known = None if isinstance(number, HugeInteger) else number
    args = tuple(_to_int(token, known, i) for i, token in enumerate(tokens[1:], start=1))
    check_call(number, args)
    return Call(number, args)


BULK_BYTES = 256
"""A line of decimal integers longer than this (a batch of setpoints) is converted and
checked by numpy in one pass: 600 values in a fraction of the time of ``int`` on each."""
_BLANK = np.zeros(256, dtype=bool)
_BLANK[[ord(c) for c in " \t\r\n"]] = True
_DIGIT = np.zeros(256, dtype=bool)
_DIGIT[ord("0") : ord("9") + 1] = True


def _bulk_call(line: bytes) -> Call | None:
    """A long line of digits, signs and blanks as a valid counted call, or None when it is
    anything else (a misplaced sign, an overlong token, a call that is not counted, any
    problem: the token-by-token path then names it)."""
    if b"-" in line or b"+" in line:  # (the search for a byte runs at C speed)
        data = np.frombuffer(line, dtype=np.uint8)
        signs = np.flatnonzero((data == ord("-")) | (data == ord("+")))
        after = signs + 1
        if after[-1] >= data.size or not _DIGIT[data[after]].all():
            return None
        if signs[0] == 0 or not _BLANK[data[signs - 1]].all():
            return None
    values = np.fromstring(line, dtype=np.int64, sep=" ")  # an overlong token saturates
    if values.size < 2:
        return None
    spec = BY_NUMBER.get(int(values[0]))
    if spec is None:
        return None
    lead = len(spec.params)
    if values.size < lead + 1:
        return None
    items = values[lead + 1 :]
    args: tuple[int, ...] = tuple(values[1 : lead + 1].tolist())
    if not _counted_fits(spec, args, items):
        return None
    return Call(int(values[0]), args + tuple(items.tolist()), items)


def _counted_fits(spec: CallSpec, inputs: tuple[int, ...],
                  items: npt.NDArray[np.integer]) -> bool:
    """Whether a counted call of ``spec`` with ``inputs`` (the count last) and ``items`` is
    valid, as ``spec.problem(inputs + items)`` would find it, the items checked as one
    array (:func:`encode_counted` and the bulk path of :func:`parse_call`)."""
    item = spec.item
    if not (item is not None and len(inputs) == len(spec.params) and inputs[-1] == items.size
            and (spec.query is None or len(spec.query) != len(inputs) + items.size)
            and all(p.check(v) is None for p, v in zip(spec.params, inputs, strict=True))):
        return False
    lowest, highest = _TYPE_RANGES.get(items.dtype, (item.minimum - 1, item.maximum + 1))
    return (not items.size or (lowest >= item.minimum and highest <= item.maximum)
            or (int(items.min()) >= item.minimum and int(items.max()) <= item.maximum))


_TYPE_RANGES: dict[np.dtype[np.integer], tuple[int, int]] = {
    np.dtype(kind): (int(np.iinfo(kind).min), int(np.iinfo(kind).max))
    for kind in (np.int8, np.int16, np.int32, np.int64, np.uint8, np.uint16, np.uint32,
                 np.uint64)}
"""The values each integer type can hold: items of a type that holds nothing outside an
item's range need no pass over them."""


HUGE_DIGITS = 18
"""Significant digits an integer input is read with exactly (every such value fits a signed
64-bit integer); a longer one is beyond every range of the table and is read as a
:class:`HugeInteger`."""
HUGE_INTEGER = 10**HUGE_DIGITS


class HugeInteger(int):
    """An integer input of more than :data:`HUGE_DIGITS` significant digits.

    Its value is ``+-10**18`` (outside every range, so a range check refuses it) and its
    ``repr`` abbreviates the digits as written: ``123456789012345678...(5000 digits)``. A
    firmware reads such a token without arbitrary-precision numbers, and no message is
    longer than a line.
    """

    shown: str

    def __new__(cls, negative: bool, digits: str) -> HugeInteger:
        number = super().__new__(cls, -HUGE_INTEGER if negative else HUGE_INTEGER)
        number.shown = f"{'-' if negative else ''}{digits[:HUGE_DIGITS]}...({len(digits)} digits)"
        return number

    def __repr__(self) -> str:
        return self.shown

    __str__ = __repr__


def _to_int(token: str, call: int | None, position: int) -> int:
    if _INT.match(token) is None:
        shown = token if len(token) <= 24 else token[:21] + "..."
        what = "executive call" if position == 0 else f"input {position}"
        raise NonIntegerTokenError(
            f"{what} {shown!r} is not a decimal integer",
            call=call,
            reason=f"{what} {shown!r} is not an integer",
        )
    digits = token.lstrip("+-").lstrip("0")
    if len(digits) > HUGE_DIGITS:
        return HugeInteger(token[0] == "-", digits)
    value = int(digits or "0")
    return -value if token[0] == "-" else value


def _known_calls() -> str:
    numbers = sorted(BY_NUMBER)
    return f"{numbers[0]}..{numbers[-1]}"


def format_err(error: ProtocolError) -> str:
    """The device's one-line answer to a malformed line: ``ERR <call> <reason>``."""
    call = "?" if error.call is None else str(error.call)
    reason = " ".join(error.reason.split()) or "malformed line"
    return ERR.format(call, reason)


# --- replies -------------------------------------------------------------------------------


class ReplyKind(Enum):
    """What a line from the device is."""

    QUERY = "query"
    """The answer to a query (``SERVO_ENABLE 1``)."""
    DEBUG = "debug"
    """A debug-flag line (``SERVO ENABLE MODIFIED TO 1``)."""
    REFUSAL = "refusal"
    """``E0``, ``E1`` or ``E25``: values not taken."""
    ERROR = "error"
    """``ERR <call> <reason>``: a malformed or refused line."""
    DIAGNOSTICS = "diagnostics"
    """A ``D ...`` line printed every N servo ticks."""
    ALARM = "alarm"
    """``ALARM <fault> <tick>``: printed unasked when a fault latches."""


@dataclass(frozen=True, slots=True)
class Reply:
    """One parsed line from the device.

    ``call`` is the executive call it belongs to (``None`` for diagnostics or an
    ``ERR`` whose call could not be read); ``key`` is the reply's literal head
    (``SERVO_ENABLE``, ``E0``, ``ERR``, ``D``); ``values`` are its integer fields in
    order; ``text`` holds a text field (device name, error reason, call-1 values).
    """

    kind: ReplyKind
    call: int | None
    key: str
    values: tuple[int, ...]
    text: str
    line: str


@dataclass(frozen=True, slots=True)
class _Matcher:
    kind: ReplyKind
    call: int | None
    template: Template
    pattern: re.Pattern[str]
    integers: bool
    """Every field is an integer (no text field)."""


def _matchers() -> dict[str, list[_Matcher]]:
    table: dict[str, list[_Matcher]] = {}

    def add(kind: ReplyKind, call: int | None, template: Template) -> None:
        first = template.text.split(" ", 1)[0]
        integers = not any(name in REST_FIELDS for name in template.fields)
        table.setdefault(first, []).append(
            _Matcher(kind, call, template, template.pattern(), integers)
        )

    for call_spec in CALLS:
        if call_spec.query_reply is not None:
            add(ReplyKind.QUERY, call_spec.number, call_spec.query_reply)
        for template in call_spec.debug.values():
            add(ReplyKind.DEBUG, call_spec.number, template)
    add(ReplyKind.DIAGNOSTICS, None, DIAGNOSTICS)
    add(ReplyKind.ALARM, None, ALARM)
    return table


_MATCHERS = _matchers()
_ERR = re.compile(r"^ERR (\?|-?\d+) (.*)$")
_DIAGNOSTICS = re.compile(DIAGNOSTICS.pattern().pattern.encode("ascii"))
"""Diagnostics lines as bytes: the most frequent line by far, parsed without decoding."""
_DIAGNOSTICS_BYTES = b"D -0123456789"


def parse_diagnostics(line: bytes) -> tuple[int, ...] | None:
    """The values of a diagnostics line (``D <clock> ...``), or None if it is not one.

    The fast path for the most frequent line: exactly what :func:`parse_reply` would read.
    """
    line = line.rstrip(b"\r\n")
    if line[:2] != b"D " or line.translate(None, _DIAGNOSTICS_BYTES):
        return None
    found = _DIAGNOSTICS.match(line)
    return None if found is None else tuple(map(int, found.groups()))


_DIAGNOSTICS_LINES = re.compile(
    b"(?:" + re.escape(DIAGNOSTICS.text.split(" ", 1)[0].encode("ascii"))
    + b"(?: -?[0-9]{1,%d}){%d}\n)*" % (HUGE_DIGITS, len(DIAGNOSTICS.fields)))
"""Whole diagnostics lines, each ended by a newline: a single space before every value, no
sign but ``-``, no value beyond what an int64 holds."""


def parse_diagnostics_lines(lines: Sequence[bytes]) -> npt.NDArray[np.int64] | None:
    """The values of diagnostics lines, one row per line in order, converted by numpy in one
    pass; None unless every line is a diagnostics line written exactly as a device prints
    it (anything else, :func:`parse_diagnostics` and :func:`parse_reply` take one line
    at a time)."""
    fields = len(DIAGNOSTICS.fields)
    if not lines:
        return np.zeros((0, fields), dtype=np.int64)
    text = b"\n".join(lines) + b"\n"
    if _DIAGNOSTICS_LINES.fullmatch(text) is None:
        return None
    values = np.fromstring(text.replace(b"D", b" "), dtype=np.int64, sep=" ")
    return values.reshape(len(lines), fields)


def parse_reply(line: bytes | str) -> Reply:
    """Parse one line from the device.

    Raises:
        UnexpectedReplyError: the line matches no reply in the table.
    """
    if isinstance(line, bytes) and line[:2] == b"D ":
        diagnostics = parse_diagnostics(line)
        if diagnostics is not None:
            text = line.rstrip(b"\r\n").decode("ascii")
            return Reply(ReplyKind.DIAGNOSTICS, None, "D", diagnostics, "", text)
    text = line.decode("ascii", errors="replace") if isinstance(line, bytes) else line
    exact = text.rstrip("\r\n")
    text = exact.strip()
    refused = REFUSALS.get(text)
    if refused is not None:
        return Reply(ReplyKind.REFUSAL, refused, text, (), "", text)
    first = text.split(" ", 1)[0]
    if first == "ERR":
        match = _ERR.match(text)
        if match is not None:
            call = None if match.group(1) == "?" else int(match.group(1))
            return Reply(ReplyKind.ERROR, call, "ERR", (), match.group(2), text)
    for matcher in _MATCHERS.get(first, ()):
        # The line as printed first: a device name may begin or end with a space.
        match = matcher.pattern.match(exact) or matcher.pattern.match(text)
        if match is None:
            continue
        if matcher.integers:
            return Reply(matcher.kind, matcher.call, matcher.template.head,
                         tuple(map(int, match.groups())), "", text)
        values: list[int] = []
        rest = ""
        for name, group in zip(matcher.template.fields, match.groups(), strict=True):
            if name in REST_FIELDS:
                rest = group
            else:
                values.append(int(group))
        return Reply(matcher.kind, matcher.call, matcher.template.head, tuple(values), rest, text)
    shown = text if len(text) <= 60 else text[:57] + "..."
    raise UnexpectedReplyError(f"unexpected line from device: {shown!r}")


# --- framing -------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Overlong:
    """Marks a line that exceeded :data:`MAX_LINE_BYTES`; its bytes were discarded."""

    length: int


class LineSplitter:
    """Cut a byte stream into lines, whatever the chunking. No I/O.

    Bytes are buffered until a ``\\n``; a line that grows past ``max_bytes`` is
    discarded up to its newline and reported once as :class:`Overlong`, so a garbage
    stream can never grow the buffer without bound.
    """

    def __init__(self, *, max_bytes: int = MAX_LINE_BYTES) -> None:
        self._max = max_bytes
        self._buffer = bytearray()
        self._discarding = 0

    def feed(self, data: bytes) -> list[bytes | Overlong]:
        """Take a chunk and return the whole lines it completes (without ``\\n``/``\\r``)."""
        if not self._buffer and not self._discarding:
            if data[-1:] == b"\n" and len(data) <= self._max:  # whole lines, none too long
                pieces = data.split(b"\n")
                pieces.pop()
                if b"\r" in data:
                    return [piece.rstrip(b"\r") for piece in pieces]
                return cast("list[bytes | Overlong]", pieces)
            pieces = data.split(b"\n")
            rest = pieces.pop()
            if not pieces or max(map(len, pieces)) <= self._max:
                self._keep(rest)
                return [piece.rstrip(b"\r") for piece in pieces]
        out: list[bytes | Overlong] = []
        start = 0
        while True:
            end = data.find(b"\n", start)
            if end < 0:
                self._keep(data[start:])
                return out
            piece = data[start:end]
            if self._discarding:
                out.append(Overlong(self._discarding + len(piece)))
                self._discarding = 0
            elif len(self._buffer) + len(piece) > self._max + 1:
                out.append(Overlong(len(self._buffer) + len(piece)))
                self._buffer.clear()
            else:
                self._buffer += piece
                line = bytes(self._buffer).rstrip(b"\r")
                self._buffer.clear()
                if len(line) > self._max:
                    out.append(Overlong(len(line)))
                else:
                    out.append(line)
            start = end + 1

    def _keep(self, rest: bytes) -> None:
        if self._discarding:
            self._discarding += len(rest)
        elif len(self._buffer) + len(rest) > self._max + 1:
            self._discarding = len(self._buffer) + len(rest)
            self._buffer.clear()
        else:
            self._buffer += rest

    @property
    def pending(self) -> int:
        """Bytes held waiting for a newline."""
        return len(self._buffer)

    def reset(self) -> None:
        """Drop any partial line."""
        self._buffer.clear()
        self._discarding = 0


def iter_calls(lines: Iterable[bytes]) -> Iterator[Call | ProtocolError]:
    """Parse lines into calls, yielding the error for each malformed line instead of raising."""
    for line in lines:
        try:
            yield parse_call(line)
        except ProtocolError as error:
            yield error
