"""The tool table, in LinuxCNC's ``tool.tbl`` format.

One tool a line: ``T<tool> P<pocket> [X<x>] [Y<y>] [Z<z>] [D<diameter>] ... ;comment``,
letters in any case and order, as LinuxCNC writes and reads it. Offsets and diameters are in
the machine's units (mm for usbmotion's machines; ``mm_per_unit`` reads a table written for
an inch machine). Offsets are kept for the linear axes X Y Z U V W (the interpreter applies
those of the machine's axes and refuses a tool whose offset is on an axis the machine
lacks); the rotary A B C words and the lathe words (I J Q) are read and kept out of the
offsets, and a non-zero rotary offset is refused, since applying it is not possible and
ignoring it would put the tool elsewhere than the table says.

A machine with no table, or a table file that does not exist, has every tool at zero length
(LinuxCNC's behaviour with an empty table): :data:`NO_TOOLS`.
"""

from __future__ import annotations

import math
import os
import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path

from usbmotion.errors import ConfigError
from usbmotion.motion.moves import AXIS_ORDER

__all__ = ["NO_TOOLS", "Tool", "ToolTable", "load_tool_table", "parse_tool_table"]

Point = tuple[float, ...]
_ZERO: Point = (0.0,) * len(AXIS_ORDER)

_WORD = re.compile(r"([A-Za-z])\s*([-+]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][-+]?[0-9]+)?)")
_OFFSET_AXES = {letter: axis for axis, letter in enumerate(AXIS_ORDER)}
_OTHER_AXES = "ABC"
_LATHE = {"I": "front angle", "J": "back angle", "Q": "orientation"}


@dataclass(frozen=True, slots=True)
class Tool:
    """One entry of the table.

    Fields:
        number: the tool number (T), 1 or more.
        pocket: the pocket it sits in (P).
        offset_mm: the tool offset, X Y Z U V W in mm (Z is the tool length).
        diameter_mm: the cutter diameter (D), mm.
        comment: the text after ``;``.
        line: the line of the table it was read from.
    """

    number: int
    pocket: int
    offset_mm: Point
    diameter_mm: float
    comment: str
    line: int


@dataclass(frozen=True, slots=True)
class ToolTable:
    """A tool table: tools by number. ``path`` is the file ("" for none); ``exists`` is false
    when there is no table (then every tool has zero length)."""

    tools: Mapping[int, Tool] = field(default_factory=dict)
    path: str = ""
    exists: bool = False

    def offset_mm(self, number: int) -> Point | None:
        """The offset of tool ``number``; zero for tool 0 and for any tool when there is no
        table; ``None`` when the table exists and lacks the tool."""
        if number == 0 or not self.exists:
            return _ZERO
        tool = self.tools.get(number)
        return tool.offset_mm if tool is not None else None

    def describe(self) -> str:
        """``tool table T.tbl (T1, T2, T4)`` for messages."""
        listed = ", ".join(f"T{n}" for n in sorted(self.tools)) or "no tools"
        return f"the tool table {self.path} ({listed})"


NO_TOOLS = ToolTable()
"""No table: every tool has zero length."""


def parse_tool_table(text: str, *, path: str = "<string>", mm_per_unit: float = 1.0) -> ToolTable:
    """Read a tool table's text.

    Parameters:
        text: the table.
        path: the file name, for messages.
        mm_per_unit: mm per unit of the table's numbers (25.4 for a table an inch machine
            wrote).

    Raises:
        ConfigError: a word that is not a letter and a number, an unknown letter, a letter
            twice, a line without T or with a T or P that is not a whole number >= 0 (T
            >= 1), a tool listed twice, a non-zero offset on a rotary axis A, B, C (the
            message names the file, the line, the word and what is allowed).
    """
    tools: dict[int, Tool] = {}
    for number, raw in enumerate(text.splitlines(), start=1):
        code, _, comment = raw.partition(";")
        if not code.strip():
            continue

        def fail(problem: str, line: int = number) -> ConfigError:
            return ConfigError(f"{path}:{line}: {problem}", path=path, key="tool_table",
                               line=line)

        words: dict[str, tuple[float, str]] = {}
        position = 0
        for match in _WORD.finditer(code):
            gap = code[position:match.start()]
            if gap.strip():
                raise fail(f"unexpected {gap.strip()!r}; allowed: words such as T1 P1 Z12.5"
                           " D6 and a ';' comment")
            position = match.end()
            letter, text_value = match.group(1).upper(), match.group(2)
            known = letter in "TPD" or letter in _OFFSET_AXES or letter in _OTHER_AXES
            if not known and letter not in _LATHE:
                raise fail(f"unknown word {letter}{text_value}; allowed letters: T P X Y Z A B C"
                           " U V W D I J Q")
            if letter in words:
                raise fail(f"{letter} appears twice ({letter}{words[letter][1]} and"
                           f" {letter}{text_value}); allowed: once per tool")
            value = float(text_value)
            if not math.isfinite(value):
                raise fail(f"{letter}{text_value} is not a finite number")
            words[letter] = (value, text_value)
        rest = code[position:]
        if rest.strip():
            raise fail(f"unexpected {rest.strip()!r}; allowed: words such as T1 P1 Z12.5 D6"
                       " and a ';' comment")
        if "T" not in words:
            raise fail("a tool line needs T, the tool number")
        tool_number = _whole(words["T"], "T", "tool number", 1, fail)
        pocket = _whole(words.get("P", (0.0, "0")), "P", "pocket", 0, fail)
        for letter in _OTHER_AXES:
            if letter in words and words[letter][0] != 0.0:
                raise fail(f"T{tool_number}: {letter}{words[letter][1]} offsets the rotary"
                           f" axis {letter}, which the interpreter does not move; allowed:"
                           " offsets on X, Y, Z, U, V and W (0 on A, B and C)")
        if tool_number in tools:
            raise fail(f"T{tool_number} is listed twice (also line"
                       f" {tools[tool_number].line}); allowed: once")
        offset = list(_ZERO)
        for letter, axis in _OFFSET_AXES.items():
            if letter in words:
                offset[axis] = words[letter][0] * mm_per_unit
        diameter = words.get("D", (0.0, "0"))[0] * mm_per_unit
        if diameter < 0.0:
            raise fail(f"T{tool_number}: D{words['D'][1]}: a diameter is not negative")
        tools[tool_number] = Tool(tool_number, pocket, tuple(offset), diameter,
                                  comment.strip(), number)
    return ToolTable(tools, path, exists=True)


def _whole(word: tuple[float, str], letter: str, name: str, minimum: int,
           fail: Callable[[str], ConfigError]) -> int:
    value, written = word
    if value != math.floor(value) or value < minimum:
        raise fail(f"{letter}{written}: a {name} is a whole number >= {minimum}")
    return int(value)


def load_tool_table(path: str | os.PathLike[str], *, mm_per_unit: float = 1.0) -> ToolTable:
    """Read a tool table file; a file that does not exist is no table (zero lengths).

    Raises:
        ConfigError: the file cannot be read or is malformed (see :func:`parse_tool_table`).
    """
    file = Path(path)
    try:
        text = file.read_text(encoding="utf-8")
    except FileNotFoundError:
        return ToolTable(path=str(file))
    except (OSError, UnicodeDecodeError) as error:
        raise ConfigError(f"{file}: cannot read the tool table: {error}", path=str(file),
                          key="tool_table") from error
    return parse_tool_table(text, path=str(file), mm_per_unit=mm_per_unit)


def with_tool_length(text: str, tool: int, length_mm: float, *, comment: str) -> str:
    """A tool table's text with tool ``tool``'s length (its Z offset) set to ``length_mm``:
    its line's Z word replaced (or added after its other words), every other line and word
    as it was; a tool the table lacks gets a line of its own (``T3 P3 Z12.345 ;comment``)
    at the end. LinuxCNC's touch-off writes its table the same way.

    Raises:
        ConfigError: the text is not a tool table (:func:`parse_tool_table`).
    """
    table = parse_tool_table(text)
    written = f"Z{length_mm:.4f}"
    lines = text.splitlines()
    entry = table.tools.get(tool)
    if entry is None:
        if lines and not lines[-1].strip():
            lines.pop()
        lines.append(f"T{tool} P{tool} {written} ;{comment}")
        return "\n".join(lines) + "\n"
    code, semicolon, rest = lines[entry.line - 1].partition(";")
    replaced, count = re.subn(r"(?i)\bZ\s*[-+]?(\d+\.?\d*|\.\d+)", written, code)
    code = replaced if count else code.rstrip() + f" {written}" + (" " if semicolon else "")
    lines[entry.line - 1] = code + semicolon + rest
    return "\n".join(lines) + ("\n" if text.endswith("\n") or not text else "")
