"""grbl's line handling, no I/O: the pre-parser, its words, ``$J=`` jogs, sync words.

grbl reads a line character by character into an 80-character line buffer: control
characters and spaces dropped, ``(...)`` and ``;`` comments dropped, ``/`` dropped, letters
put in upper case; a line with more than 79 kept characters is answered ``error:11`` at its
end. Words are a letter and a number (``read_float``: optional sign, digits, one point).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

from usbmotion.grbl.codes import GrblErrorCode
from usbmotion.grbl.interface import JogMove, ModalState

LINE_BUFFER_CHARS = 80
"""grbl's line buffer; a line may keep at most one less character."""

MM_PER_INCH = 25.4


@dataclass(slots=True)
class PreParser:
    """Builds one line from the bytes grbl keeps, as they come."""

    _chars: list[str] = field(default_factory=list)
    _in_parentheses: bool = False
    _in_semicolon: bool = False
    _overflow: bool = False

    def feed(self, byte: int) -> tuple[str, bool] | None:
        """Take one byte (never a real-time one). At a line's end, returns the line and
        whether it overflowed; else None."""
        if byte in (0x0A, 0x0D):
            line = "".join(self._chars)
            overflow = self._overflow
            self.clear()
            return line, overflow
        if self._in_parentheses or self._in_semicolon or self._overflow:
            if byte == 0x29:  # ')'
                self._in_parentheses = False
            return None
        if byte <= 0x20 or byte == 0x2F:  # control, space, '/'
            return None
        if byte == 0x28:  # '('
            self._in_parentheses = True
        elif byte == 0x3B:  # ';'
            self._in_semicolon = True
        elif len(self._chars) >= LINE_BUFFER_CHARS - 1:
            self._overflow = True
        else:
            self._chars.append(chr(byte).upper())
        return None

    def clear(self) -> None:
        """Forget the line being built (after a soft reset)."""
        self._chars.clear()
        self._in_parentheses = self._in_semicolon = self._overflow = False


_NUMBER = re.compile(r"[-+]?(?:\d+\.?\d*|\.\d+)")


class WordError(ValueError):
    """A line that is not a sequence of words: grbl's error number."""

    def __init__(self, code: GrblErrorCode) -> None:
        super().__init__(f"grbl error {int(code)}: {code.name.lower()}")
        self.code = code


def read_number(text: str, start: int) -> tuple[float, int] | None:
    """The number at ``text[start:]`` as grbl's ``read_float`` reads it, and where it
    ends; None when there is none."""
    match = _NUMBER.match(text, start)
    if match is None:
        return None
    return float(match.group()), match.end()


def words(line: str) -> list[tuple[str, float]]:
    """The words of a pre-parsed line.

    Raises:
        WordError: 1 when a letter is missing, 2 when a number is.
    """
    found: list[tuple[str, float]] = []
    index = 0
    while index < len(line):
        letter = line[index]
        if not "A" <= letter <= "Z":
            raise WordError(GrblErrorCode.EXPECTED_COMMAND_LETTER)
        number = read_number(line, index + 1)
        if number is None:
            raise WordError(GrblErrorCode.BAD_NUMBER_FORMAT)
        value, index = number
        found.append((letter, value))
    return found


def line_number(line: str) -> int | None:
    """The ``N`` word at the start of a pre-parsed line, if any."""
    if not line.startswith("N"):
        return None
    number = read_number(line, 1)
    if number is None or number[0] != int(number[0]):
        return None
    return int(number[0])


_OFFSET_G = frozenset({100, 431, 490, 540, 550, 560, 570, 580, 590, 920, 921, 922, 923})
"""G codes (times ten) that change the work coordinate offset (or may: G10)."""
_PROBE_G = frozenset({382, 383, 384, 385})
"""G38.2 to G38.5 (times ten): probing, answered once the probe has run with ``[PRB:...]``."""
_SYNC_G = _OFFSET_G | _PROBE_G | {40, 281, 301}
"""G codes grbl answers only once the motion before them is done: the dwell, offset changes,
stored positions and probing."""


@dataclass(frozen=True, slots=True)
class LineEffects:
    """What the front does around a G-code line besides passing it on."""

    sync: bool = False
    """Its ``ok`` waits for the motion before it to end."""
    pause: bool = False
    """M0: hold once the motion before it ends."""
    end: bool = False
    """M2 or M30: ``[MSG:Pgm End]``."""
    offsets: bool = False
    """It changes the work coordinate offset: the next report carries ``WCO:``."""
    probe: bool = False
    """G38.2 to G38.5: ``[PRB:...]`` once the probe has run, before the ``ok``."""


def line_effects(line: str) -> LineEffects:
    """The effects of a pre-parsed line (none for a line that is not all words: the
    machine rejects it)."""
    try:
        parsed = words(line)
    except WordError:
        return LineEffects()
    sync = pause = end = offsets = probe = False
    for letter, value in parsed:
        if letter == "G" and round(value * 10) in _SYNC_G:
            sync = True
            offsets = offsets or round(value * 10) in _OFFSET_G
            probe = probe or round(value * 10) in _PROBE_G
        elif letter == "M" and value == int(value) and int(value) in (0, 2, 30):
            sync = True
            pause = pause or int(value) == 0
            end = end or int(value) in (2, 30)
    return LineEffects(sync, pause, end, offsets, probe)


_JOG_MODAL_GROUPS = {200: "units", 210: "units", 900: "distance", 910: "distance"}


def parse_jog(text: str, axes: tuple[str, ...], modal: ModalState) -> JogMove:
    """A ``$J=`` jog's words (``text`` after the ``=``), as jogging.md allows them.

    Parameters:
        text: the pre-parsed words (``G91X10F500``).
        axes: the machine's axis letters.
        modal: the parser state, whose units and distance mode a jog uses by default.

    Raises:
        WordError: grbl's error number: 16 a G or M code other than G20/G21/G90/G91/G53,
            21 two of one modal group, 25 a repeated word, 36 S or T (or another value
            word), 20 a letter grbl does not know, 4 a negative F, 27 an N out of range,
            22 no F, 26 no axis word.
    """
    groups: dict[str, int] = {}
    machine_coordinates = False
    seen: set[str] = set()
    axis_values: dict[str, float] = {}
    feed: float | None = None
    number: int | None = None
    for letter, value in words(text):
        if letter == "G":
            code = round(value * 10)
            if code == 530:
                if machine_coordinates:
                    raise WordError(GrblErrorCode.MODAL_GROUP_VIOLATION)
                machine_coordinates = True
                continue
            group = _JOG_MODAL_GROUPS.get(code)
            if group is None:
                raise WordError(GrblErrorCode.INVALID_JOG_COMMAND)
            if group in groups:
                raise WordError(GrblErrorCode.MODAL_GROUP_VIOLATION)
            groups[group] = code
            continue
        if letter == "M":
            raise WordError(GrblErrorCode.INVALID_JOG_COMMAND)
        if letter in seen:
            raise WordError(GrblErrorCode.WORD_REPEATED)
        seen.add(letter)
        if letter in axes:
            axis_values[letter] = value
        elif letter == "F":
            if value < 0:
                raise WordError(GrblErrorCode.NEGATIVE_VALUE)
            feed = value
        elif letter == "N":
            if value < 0:
                raise WordError(GrblErrorCode.NEGATIVE_VALUE)
            if value != int(value) or not 0 <= value <= 9_999_999:
                raise WordError(GrblErrorCode.INVALID_LINE_NUMBER)
            number = int(value)
        elif letter in "IJKLPRST":
            raise WordError(GrblErrorCode.UNUSED_WORDS)
        else:
            raise WordError(GrblErrorCode.UNSUPPORTED_COMMAND)
    if feed is None or feed == 0:
        raise WordError(GrblErrorCode.UNDEFINED_FEED_RATE)
    if not axis_values:
        raise WordError(GrblErrorCode.NO_AXIS_WORDS)
    units = groups.get("units", 200 if modal.units == "G20" else 210)
    distance = groups.get("distance", 910 if modal.distance == "G91" else 900)
    scale = MM_PER_INCH if units == 200 else 1.0
    return JogMove(
        words_mm={axis: value * scale for axis, value in axis_values.items()},
        feed_mm_min=feed * scale,
        incremental=distance == 910,
        machine_coordinates=machine_coordinates,
        line_number=number or None,
    )
