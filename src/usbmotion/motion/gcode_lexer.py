"""The lexical stage of G-code: text to blocks of words, with no machine semantics.

A line is split by one compiled regular expression into words (a letter and a number),
comments ``( )`` and ``;``, and anything else, which is an error. As in LinuxCNC, letters
are case-insensitive and blanks (space, tab, carriage return) outside comments carry no
meaning, even inside a number (``X1 2.5`` is ``X12.5``). Also handled here, because they
are about characters rather than machine state:

- a line whose first character is ``/`` is deleted (block delete: not read at all);
- a line holding only ``%`` is a program delimiter (:attr:`Block.delimiter`);
- a RepRap checksum ``*NN`` ending the line must equal the XOR of the line's UTF-8 bytes
  before the ``*``; it is then dropped;
- an ``N`` word (line number, also decimal such as ``N4567.789``) may only start a line;
- number forms ``1``, ``-1.5``, ``+2``, ``I0.``, ``J.103``; anything else is malformed;
- a line is at most as long as the controller whose reading is asked for reads one
  (:class:`LineLimit`); LinuxCNC's ``fgets`` into a ``LINELEN`` (255) byte buffer takes 254
  bytes, line break included, and a line that fills them is refused
  (``NCE_COMMAND_TOO_LONG``). So a line holds at most 252 bytes before a ``\n``, 251
  before a ``\r\n``, 253 when it is the last and has no line break (UTF-8 bytes: a
  character outside ASCII in a comment counts for two to four). grbl and Marlin count only
  what they keep of a line, comments left out;
- a line that starts with a Klipper extended command (``SET_VELOCITY_LIMIT VELOCITY=100``,
  ``BED_MESH_CALIBRATE``) is refused naming it, in every reading.

Dialect options (:mod:`usbmotion.motion.dialects`) change what a line may hold:
``commands`` reads a line that starts with ``$`` as one controller command (grbl's
``$H``), ``messages`` names M codes whose text runs to the end of the line (Marlin's
``M117 Printing...``), ``flags`` reads a letter alone as a word, and ``line_limit`` is
whose line length applies.

Expressions (``[``), parameters (``#``), O-words and polar coordinates (``@``, ``^``) are
rejected with :class:`~usbmotion.errors.UnsupportedGCodeError`; every other problem is a
:class:`~usbmotion.errors.GCodeError`. Errors carry the file, the 1-based line and column.

Lines are read lazily by :func:`tokenize`, so an interpreter that stops at ``M2`` never
reads what follows, as LinuxCNC does.
"""

from __future__ import annotations

import gc
import math
import re
from collections.abc import Iterator
from contextlib import contextmanager
from enum import Enum
from functools import reduce
from operator import xor
from typing import NamedTuple

from usbmotion.errors import GCodeError, UnsupportedGCodeError

__all__ = ["Block", "LineLimit", "Word", "parse_blocks", "tokenize", "word_columns"]


class Word(NamedTuple):
    """One word of a block: an upper-case letter and its number.

    ``number`` is the number as written (blanks removed, sign and dots kept, such as
    ``"-.5"`` or ``"90.1"``); ``value`` is its value.
    """

    letter: str
    value: float
    number: str

    @property
    def text(self) -> str:
        """The word as written, with an upper-case letter: ``"G90.1"``, ``"X-.5"``."""
        return self.letter + self.number


class Block(NamedTuple):
    """One line of G-code that holds words, comments or a ``%`` delimiter.

    The words are stored column-wise, which is how the lexer stays fast: word ``i`` is
    ``letters[i]`` (upper case), ``values[i]`` and ``numbers[i]`` (see :class:`Word`;
    :attr:`words` gives them as :class:`Word` tuples). ``line`` is the 1-based line in
    the text, ``comments`` are the texts of ``( )`` and ``;`` comments, ``source`` is the
    line as written (without its line break) and ``delimiter`` is true for a ``%`` line.
    """

    line: int
    letters: str
    values: tuple[float, ...]
    numbers: tuple[str, ...]
    comments: tuple[str, ...]
    source: str
    delimiter: bool

    @property
    def words(self) -> tuple[Word, ...]:
        """The words in the order written."""
        return tuple(map(Word, self.letters, self.values, self.numbers))


# One token per match: blanks, then a word (letter, number), a ( ) comment, a ; comment,
# or one character that is none of these. The number may be empty or malformed here; it
# is checked by float() on the fast path and by _word_value() on the careful one.
_TOKEN = re.compile(
    r"[ \t\r]*(?:"
    r"([A-Za-z])[ \t\r]*([-+0-9.]*(?:[ \t\r]+[-+0-9.]+)*)"
    r"|\(([^()]*)\)"
    r"|;(.*)"
    r"|([^ \t\r])"
    r")"
)
# The fast path's token: a word, or one character that is not part of a word (which
# makes float("") fail and sends the line to the careful path). Blanks between tokens are
# skipped by findall.
_FAST_TOKEN = re.compile(r"([A-Za-z])[ \t\r]*([-+0-9.]*(?:[ \t\r]+[-+0-9.]+)*)|([^ \t\r])")
# Anything that needs the careful path: comments, block delete, delimiter, checksum,
# line numbers (N) and O-words.
_SPECIAL = re.compile(r"[();/%*NnOo]")
_LINE_NUMBER = re.compile(r"[0-9]+(?:\.[0-9]+)?")
_CHECKSUM_DIGITS = re.compile(r"[0-9]+")
_BLANKS = " \t\r"
LINE_BUFFER_BYTES = 254
"""LinuxCNC's fgets reads at most LINELEN - 1 = 254 bytes of a line, its break included; a
line that fills them is too long."""
GRBL_LINE_CHARS = 79
"""grbl 1.1 keeps at most LINE_BUFFER_SIZE - 1 = 79 characters of a line (``protocol.c``);
one more is its ``error:11``."""
MARLIN_COMMAND_CHARS = 95
"""Marlin keeps at most MAX_CMD_SIZE - 1 = 95 characters of a command (``queue.cpp``) and
drops the rest of the line."""
_LONGEST_FAST_LINE = 251  # longer lines take the careful path
_GRBL_DROPPED = re.compile(r"\([^)]*\)?|;.*|[\x00-\x20/]")
"""What grbl's pre-parser drops: a ( ) comment (to the end of the line when unclosed), a ;
comment, blanks and control characters, and '/'."""
_MARLIN_DROPPED = re.compile(r"\([^)]*\)?|;.*")
"""What Marlin does not keep of a line: a ; comment, and a ( ) comment (PAREN_COMMENTS)."""
_KLIPPER_COMMAND = re.compile(r"[ \t]*(?:[Nn][ \t]*[0-9]+[ \t]*)?([A-Za-z_][A-Za-z0-9_]*)"
                              r"(?=[ \t;#*]|$)")
"""The first name of a line (after a line number): a Klipper extended command when it is one
(:func:`_klipper_command`)."""
_KLIPPER_REASON = ("a Klipper extended command (a name, then NAME=value parameters): Klipper's"
                   " own commands and macros are not G-code, and no dialect reads them")


class LineLimit(Enum):
    """Whose line length applies: what of a line counts, and how much of it a controller reads.

    ``LINUXCNC``: the whole line in bytes, its break included, within LinuxCNC's 254-byte
    read (``LINELEN``). ``GRBL``: the characters grbl's pre-parser keeps (comments, blanks,
    control characters and ``/`` dropped), at most 79. ``MARLIN``: the characters before a
    ``;`` comment, ``( )`` comments left out (as Marlin reads them with ``PAREN_COMMENTS``),
    at most 95 (Marlin silently drops the rest of a longer command; it is refused here).
    """

    LINUXCNC = "linuxcnc"
    GRBL = "grbl"
    MARLIN = "marlin"

    @property
    def chars(self) -> int:
        """The longest line that needs no counting (an ASCII line of this many characters
        is within the limit whatever it holds)."""
        return {LineLimit.LINUXCNC: _LONGEST_FAST_LINE, LineLimit.GRBL: GRBL_LINE_CHARS,
                LineLimit.MARLIN: MARLIN_COMMAND_CHARS}[self]
_MESSAGE = re.compile(
    r"[ \t\r]*(?:[Nn][0-9.]*[ \t\r]*)?[Mm][ \t\r]*0*([0-9]+)(?![0-9.])[ \t\r]*(.*)"
)
_NOTHING: tuple[str, ...] = ()
_new = tuple.__new__


def tokenize(text: str, *, file: str = "<string>", commands: bool = False,
             messages: frozenset[int] = frozenset(), flags: bool = False,
             line_limit: LineLimit = LineLimit.LINUXCNC) -> Iterator[Block]:
    """Read G-code text lazily into blocks, one per line that holds anything.

    Blank lines and block-deleted lines (first character ``/``) yield nothing.

    Parameters:
        text: the program; ``\\n`` or ``\\r\\n`` line breaks; a leading BOM is skipped.
        file: the name used in errors.
        commands: a line whose first character (after blanks) is ``$`` is a controller
            command: a block of one word, letter ``$``, whose number is the text after
            the ``$`` with blanks removed (``"H"``, ``"J=G91X1F100"``) and value 0.
        messages: M codes whose text runs to the end of the line: such a line is a block
            of its N word (if any) and the M word, the text its one comment.
        flags: a letter with no number is a word of value 0 and number ``""`` (Marlin's
            ``G28 X Y``) instead of an error.
        line_limit: whose line length applies (:class:`LineLimit`; LinuxCNC's by default).

    Raises:
        GCodeError: a malformed number, an unclosed or nested comment, a checksum
            mismatch, an ``N`` word that is not first, an unexpected character, a line
            longer than the controller reads (names its length and the limit).
        UnsupportedGCodeError: expressions, parameters, O-words, polar coordinates, a
            Klipper extended command.
    """
    ending_bytes = 1
    if "\r" in text:
        if "\r\n" in text:
            ending_bytes = 2
        text = text.replace("\r\n", "\n")
    if text.startswith("\ufeff"):
        text = text[1:]
    findall = _FAST_TOKEN.findall
    special = _SPECIAL.search
    line_number_ok = _LINE_NUMBER.fullmatch
    new = _new
    block_type = Block
    nothing = _NOTHING
    lines = text.split("\n")
    last = len(lines)
    longest = line_limit.chars
    for number, raw in enumerate(lines, 1):
        if not raw:
            continue
        if len(raw) > longest or (len(raw) > longest // 4 and not raw.isascii()):
            _check_length(raw, number, 0 if number == last else ending_bytes, file, line_limit)
        if messages:
            message = _message_block(raw, number, messages)
            if message is not None:
                yield message
                continue
        first = special(raw)
        if len(raw) <= _LONGEST_FAST_LINE and (
            first is None or (first.start() == 0 and raw[0] in "Nn" and special(raw, 1) is None)
        ):
            tokens = findall(raw)
            if not tokens:
                continue
            letters, numbers, _others = zip(*tokens, strict=True)
            try:
                # A token that is not a word has an empty number, and float("") fails.
                values = tuple(map(float, numbers))
            except ValueError:
                pass
            else:
                if first is None or line_number_ok(numbers[0]) is not None:
                    yield new(
                        block_type,
                        (number, "".join(letters).upper(), values, numbers, nothing, raw, False),
                    )
                    continue
        block = _read_line_carefully(raw, number, file, commands=commands, flags=flags)
        if block is not None:
            yield block


def parse_blocks(text: str, *, file: str = "<string>") -> list[Block]:
    """Read the whole of a G-code text into blocks (see :func:`tokenize`).

    The cyclic garbage collector is paused meanwhile: blocks hold no reference cycles,
    and with it running, its full collections over a growing list of long-lived blocks
    take about a third of the time. It is resumed (if it was enabled) before returning.

    Raises:
        GCodeError: as :func:`tokenize`, for the first bad line in the text.
    """
    with _collector_paused():
        return list(tokenize(text, file=file))


@contextmanager
def _collector_paused() -> Iterator[None]:
    if not gc.isenabled():
        yield
        return
    gc.disable()
    try:
        yield
    finally:
        gc.enable()


def word_columns(block: Block) -> tuple[int, ...]:
    """The 1-based column of each word's letter in ``block.source``, in word order."""
    code = _without_checksum(block.source)
    return tuple(match.start(1) + 1 for match in _TOKEN.finditer(code) if match.group(1))


def _check_length(raw: str, number: int, ending_bytes: int, file: str,
                  limit: LineLimit) -> None:
    """Refuse a line that the controller of ``limit`` would find too long."""
    if limit is LineLimit.LINUXCNC:
        _check_linuxcnc_length(raw, number, ending_bytes, file)
        return
    grbl = limit is LineLimit.GRBL
    dropped = _GRBL_DROPPED if grbl else _MARLIN_DROPPED
    longest = GRBL_LINE_CHARS if grbl else MARLIN_COMMAND_CHARS
    kept = 0
    position = 0
    for match in (*dropped.finditer(raw), None):
        end = len(raw) if match is None else match.start()
        for index in range(position, end):
            kept += len(raw[index].encode("utf-8"))
            if kept > longest:
                _refuse_long_line(raw, number, file, index, grbl)
        if match is None:
            return
        position = match.end()


def _refuse_long_line(raw: str, number: int, file: str, index: int, grbl: bool) -> None:
    """Refuse a grbl or Marlin line whose kept characters go past the limit at ``index``."""
    if grbl:
        kept = len(_GRBL_DROPPED.sub("", raw).encode("utf-8"))
        counted = "characters as grbl keeps them (comments, blanks and '/' dropped)"
        reader = (f"grbl reads a line into an {GRBL_LINE_CHARS + 1}-character buffer"
                  " (LINE_BUFFER_SIZE) and answers a longer one with error:11, so a line"
                  f" keeps at most {GRBL_LINE_CHARS}")
    else:
        kept = len(_MARLIN_DROPPED.sub("", raw).encode("utf-8"))
        counted = "characters besides its comments"
        reader = (f"Marlin reads a command into a {MARLIN_COMMAND_CHARS + 1}-character"
                  " buffer (MAX_CMD_SIZE) and drops the rest of a longer line, so a line"
                  f" keeps at most {MARLIN_COMMAND_CHARS}")
    raise GCodeError(f"line too long: {kept} {counted}; {reader}: split it",
                     file=file, line=number, column=index + 1, word="")


def _check_linuxcnc_length(raw: str, number: int, ending_bytes: int, file: str) -> None:
    """Refuse a line that LinuxCNC's reader would find too long."""
    size = len(raw.encode("utf-8")) + ending_bytes
    if size < LINE_BUFFER_BYTES:
        return
    longest = LINE_BUFFER_BYTES - 1 - ending_bytes
    ending = {0: "as the last line, with no line break", 1: "before a \\n line break",
              2: "before a \\r\\n line break"}[ending_bytes]
    raise GCodeError(
        f"line too long: {size - ending_bytes} bytes; LinuxCNC reads a line into a"
        f" {LINE_BUFFER_BYTES + 1}-byte buffer (LINELEN), so a line holds at most {longest}"
        f" bytes {ending}: split it or shorten its comments",
        file=file, line=number, column=longest + 1, word="",
    )


def _message_block(raw: str, number: int, messages: frozenset[int]) -> Block | None:
    """The block of a message line (``M117 text``), or ``None`` when it is not one."""
    match = _MESSAGE.match(raw)
    if match is None or int(match.group(1)) not in messages:
        return None
    head = raw[: match.start(2)]
    letters: list[str] = []
    values: list[float] = []
    numbers: list[str] = []
    for token in _TOKEN.finditer(head):
        letter, digits = token.group(1), token.group(2)
        if letter is not None:
            text = "".join(digits.split())
            letters.append(letter.upper())
            values.append(float(text) if letter in "Nn" and text else float(match.group(1)))
            numbers.append(text)
    return Block(number, "".join(letters), tuple(values), tuple(numbers),
                 (match.group(2),), raw, False)


def _read_line_carefully(raw: str, number: int, file: str, *, commands: bool = False,
                         flags: bool = False) -> Block | None:
    stripped = raw.strip(_BLANKS)
    if not stripped or stripped[0] == "/":
        return None
    if stripped == "%":
        return Block(number, "", (), (), (), raw, True)
    if commands and stripped[0] == "$":
        command = "".join(stripped[1:].split())
        return Block(number, "$", (0.0,), (command,), (), raw, False)
    _refuse_klipper_command(raw, number, file)
    code = _checked_code(raw, number, file)
    letters: list[str] = []
    values: list[float] = []
    numbers: list[str] = []
    comments: list[str] = []
    for match in _TOKEN.finditer(code):
        letter, digits, paren, semicolon, other = match.groups()
        if letter is not None:
            column = match.start(1) + 1
            upper = letter.upper()
            if upper == "O":
                word = upper + "".join(digits.split())
                reason = "subroutines and control flow (O-words) are not supported"
                raise UnsupportedGCodeError(
                    f"{word}: {reason}",
                    file=file,
                    line=number,
                    column=column,
                    word=word,
                    reason=reason,
                )
            value, text = _word_value(upper, digits, code, match.end(), number, column, file,
                                      flags=flags)
            if upper == "N":
                if letters:
                    raise GCodeError(
                        f"line number N{text} must be the first word of the line",
                        file=file,
                        line=number,
                        column=column,
                        word="N" + text,
                    )
                if _LINE_NUMBER.fullmatch(text) is None:
                    raise GCodeError(
                        f"line number N{text} is malformed: expected digits, optionally "
                        "with a decimal part, such as N120 or N4567.789",
                        file=file,
                        line=number,
                        column=column,
                        word="N" + text,
                    )
            letters.append(upper)
            values.append(value)
            numbers.append(text)
        elif other is not None:
            raise _bad_character(other, code, match.start(5), number, file)
        else:
            comments.append(paren if paren is not None else semicolon)
    if not letters and not comments:
        return None
    return Block(
        number, "".join(letters), tuple(values), tuple(numbers), tuple(comments), raw, False
    )


def _refuse_klipper_command(raw: str, number: int, file: str) -> None:
    """Refuse a line that starts with a Klipper extended command (``GET_POSITION``,
    ``SET_VELOCITY_LIMIT VELOCITY=100``): a name of letters, digits and underscores whose
    first two characters are not digits (``klippy/gcode.py``), here one with an underscore or
    three letters first, which no run of G-code words can be."""
    match = _KLIPPER_COMMAND.match(raw)
    if match is None:
        return
    name = match.group(1)
    if "_" not in name and not (len(name) >= 3 and name[:3].isalpha()):
        return
    if len(name) > 1 and name[1].isdigit():
        return
    raise UnsupportedGCodeError(f"{name}: {_KLIPPER_REASON}", file=file, line=number,
                                column=match.start(1) + 1, word=name, reason=_KLIPPER_REASON)


def _word_value(
    letter: str, digits: str, code: str, end: int, line: int, column: int, file: str, *,
    flags: bool = False,
) -> tuple[float, str]:
    text = digits
    if " " in text or "\t" in text or "\r" in text:
        text = "".join(text.split())
    if not text:
        following = code[end : end + 1]
        if flags and following not in ("[", "#") and letter not in "GMN":
            return 0.0, ""
        if following in ("[", "#"):
            reason = (
                "expressions in brackets are not supported"
                if following == "["
                else "parameters (#) are not supported"
            )
            raise UnsupportedGCodeError(
                f"{letter}{following}...: {reason}; write the number itself",
                file=file,
                line=line,
                column=column,
                word=letter + following,
                reason=reason,
            )
        raise GCodeError(
            f"{letter} has no number: a word is a letter followed by a number, such as {letter}1.5",
            file=file,
            line=line,
            column=column,
            word=letter,
        )
    try:
        value = float(text)
    except ValueError:
        raise GCodeError(
            f"malformed number {text!r} in {letter}{text}: expected "
            "digits with at most one '.', optionally signed, such as 1.5, -.5, +2 or 3.",
            file=file,
            line=line,
            column=column,
            word=letter + text,
        ) from None
    if not math.isfinite(value):
        raise GCodeError(
            f"number {letter}{text} is too large to represent",
            file=file,
            line=line,
            column=column,
            word=letter + text,
        )
    return value, text


def _checksum_split(raw: str) -> tuple[str, str] | None:
    """``(code, digits)`` if the line ends with a checksum ``*NN``, else ``None``."""
    star = raw.rfind("*")
    if star < 0:
        return None
    digits = raw[star + 1 :].strip(_BLANKS)
    code = raw[:star]
    if _CHECKSUM_DIGITS.fullmatch(digits) is None:
        return None
    if ";" in code or code.count("(") > code.count(")"):
        return None  # the '*' is inside a comment
    return code, digits


def _without_checksum(raw: str) -> str:
    split = _checksum_split(raw)
    return raw if split is None else split[0]


def _checked_code(raw: str, line: int, file: str) -> str:
    split = _checksum_split(raw)
    if split is None:
        return raw
    code, digits = split
    actual = reduce(xor, code.encode("utf-8"), 0)
    if actual != int(digits):
        column = len(code) + 1
        raise GCodeError(
            f"checksum mismatch: the line ends with *{digits} but the XOR of its bytes "
            f"before '*' is {actual}",
            file=file,
            line=line,
            column=column,
            word="*" + digits,
        )
    return code


def _bad_character(char: str, code: str, index: int, line: int, file: str) -> GCodeError:
    column = index + 1

    def error(message: str, *, at: int = column) -> GCodeError:
        return GCodeError(message, file=file, line=line, column=at, word=char)

    def unsupported(reason: str) -> UnsupportedGCodeError:
        return UnsupportedGCodeError(
            f"{char!r}: {reason}", file=file, line=line, column=column, word=char, reason=reason
        )

    if char == "(":
        close = code.find(")", index + 1)
        if close < 0:
            return error("unclosed comment: '(' has no ')' on this line")
        nested = code.find("(", index + 1, close)
        return error(
            f"nested comment: '(' is inside the comment opened at "
            f"column {column}; comments cannot nest",
            at=nested + 1,
        )
    if char == ")":
        return error("')' closes no comment")
    if char == "#":
        return unsupported("parameters (#) are not supported")
    if char == "[":
        return unsupported("expressions in brackets are not supported")
    if char in "@^":
        return unsupported("polar coordinates are not supported")
    if char == "%":
        return error("'%': a program delimiter must stand alone on its line")
    if char == "$" and not code[:index].strip(_BLANKS):
        return error("unexpected character '$': a line starting with '$' is a grbl controller"
                     " command, which only the grbl dialect reads ($H)")
    if char == "/":
        return error("'/': block delete is only allowed as the first character of a line")
    if char == "*":
        return error("'*': a checksum is '*' followed by digits at the end of the line")
    if char.isalpha():
        return error(f"unknown word letter {char!r}: words start with A-Z")
    return error(f"unexpected character {char!r}")
