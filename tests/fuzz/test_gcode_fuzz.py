"""Fuzz the G-code interpreter: plausible programs and word soup.

Plausible programs are built from the words the interpreter knows (motion, planes, units,
distance and arc-distance modes, offsets, G28, dwells, feeds, comments, ignored words,
some unsupported ones) with numbers at the edges, plus arcs constructed to be valid so
that the arc code is reached, not only its refusals. Word soup reuses the fragments of
``tests/test_gcode.py``.

For every text the interpreter must, within the hang guard:

- return moves or a :class:`GCodeError` (never another exception), and
  :func:`parse_gcode` must agree with :func:`interpret_until_error`;
- locate an error on a line of the text, at the column of the word it names;
- give a path: the first move starts at the origin, each move starts where the one before
  ended, every coordinate is finite, feeds are finite and positive, dwells are finite and
  not negative;
- give arcs LinuxCNC would accept: a turn count, a centre in the arc's plane whose radius
  to the start and to the end agree within LinuxCNC's tolerance;
- keep the moves of the lines before an error exactly as interpreting those lines alone
  gives them;
- end a valid program at M2, M30 or ``%``, on or after its last move.
"""

from __future__ import annotations

import math

import pytest
from hypothesis import event, given
from hypothesis import strategies as st

from test_gcode import _FRAGMENTS
from usbmotion.errors import GCodeError
from usbmotion.motion.gcode import GCodeProgram, interpret_until_error, parse_gcode
from usbmotion.motion.moves import Arc, Dwell, Linear, Move

from .budget import fuzz_settings, hang_guard

FILE = "fuzz.ngc"
RADIUS_ABS_MM = 2 * 0.001 * math.sqrt(2) * 25.4
"""LinuxCNC's absolute tolerance on the two radii of an arc, the looser (inch) one, mm."""
RADIUS_REL = 0.001
"""LinuxCNC's relative tolerance on the two radii of an arc (SPIRAL_RELATIVE_TOLERANCE)."""

_NUMBER = st.one_of(
    st.integers(-300, 300).map(str),
    st.floats(-500, 500, allow_nan=False).map(lambda v: f"{v:.4f}"),
    st.floats(-5, 5, allow_nan=False).map(lambda v: f"{v:.6f}"),
    st.sampled_from(["0", "-0", ".5", "-.5", "0.0001", "1e3", "99999999", "-99999999",
                     "1000000000", "0.000000001", "+2", "1.", "360"]),
)
_G = st.sampled_from(["G0", "G1", "G2", "G3", "G4", "G17", "G18", "G19", "G20", "G21", "G28",
                      "G28.1", "G90", "G91", "G90.1", "G91.1", "G92", "G92.1", "G92.2",
                      "G92.3", "G94", "G80", "G41", "G54", "G81", "G64", "g1", "G01", "G00"])
_LETTER = st.sampled_from("XYZIJKRPFXYZXYZ")
_OTHER = st.sampled_from(["M3", "M5", "M8", "M9", "S1000", "T1", "M6", "N10", "(note)",
                          "; trailing comment", "M98", "M2", "M30", "%", "/"])


@st.composite
def _block(draw: st.DrawFn) -> str:
    words: list[str] = []
    if draw(st.integers(0, 3)) == 0:
        words.append(draw(_G))
    if draw(st.integers(0, 2)) == 0:
        words.append(draw(_G))
    for _ in range(draw(st.integers(0, 4))):
        words.append(draw(_LETTER) + draw(_NUMBER))
    if draw(st.integers(0, 5)) == 0:
        words.append(draw(_OTHER))
    order = draw(st.permutations(words)) if draw(st.booleans()) else words
    return draw(st.sampled_from([" ", "", "\t"])).join(order)


_SMALL = st.floats(-150, 150, allow_nan=False).map(lambda v: f"{v:.3f}")


@st.composite
def _clean_block(draw: st.DrawFn) -> str:
    """A block a CAM program would hold: no word the interpreter should refuse."""
    kind = draw(st.integers(0, 9))
    if kind == 0:
        return draw(st.sampled_from(["G20", "G21", "G90", "G91", "G17", "G18", "G19", "G94",
                                     "G92.1", "G92.2", "G92.3", "M3 S1000", "(comment)"]))
    if kind == 1:
        return f"G4 P{draw(st.floats(0, 3)):.3f}"
    if kind == 2:
        return f"G92 X{draw(_SMALL)} Y{draw(_SMALL)}"
    if kind == 3:
        return draw(st.sampled_from(["G28", "G28 Z0", "G28.1", "G28 X1 Y2"]))
    axes = draw(st.lists(st.sampled_from("XYZ"), min_size=1, max_size=3, unique=True))
    words = " ".join(f"{axis}{draw(_SMALL)}" for axis in axes)
    motion = draw(st.sampled_from(["G0", "G1", "G1"]))
    feed = draw(st.sampled_from(["", "", f"F{draw(st.integers(1, 3000))}"]))
    return " ".join(part for part in (f"N{10 * kind}", motion, words, feed) if part)


@st.composite
def _valid_arc(draw: st.DrawFn) -> str:
    """A move to a start, then an arc ending on the circle through it (G17, mm or inch)."""
    x0 = draw(st.integers(-100, 100))
    y0 = draw(st.integers(-100, 100))
    radius = draw(st.floats(0.5, 80))
    start_angle = draw(st.floats(0, 2 * math.pi))
    sweep = draw(st.floats(-2 * math.pi, 2 * math.pi))
    cx = x0 - radius * math.cos(start_angle)
    cy = y0 - radius * math.sin(start_angle)
    x1 = cx + radius * math.cos(start_angle + sweep)
    y1 = cy + radius * math.sin(start_angle + sweep)
    direction = "G2" if sweep < 0 else "G3"
    feed = draw(st.sampled_from(["F100", "F1200", ""]))
    if draw(st.booleans()) or not 0.01 < abs(sweep) < 2 * math.pi - 0.01:
        centre = f"I{cx - x0:.4f} J{cy - y0:.4f}"
    else:
        sign = "" if abs(sweep) <= math.pi else "-"
        centre = f"R{sign}{radius:.4f}"
    extra = draw(st.sampled_from(["", " Z-1.5", " P2", " Z3 P3"]))
    return (f"G17 G90 G91.1 G0 X{x0} Y{y0}\n"
            f"{direction} X{x1:.4f} Y{y1:.4f} {centre}{extra} {feed}")


@st.composite
def _program(draw: st.DrawFn) -> str:
    """Half clean (a CAM-like program that should run), half noisy (words at random)."""
    clean = draw(st.booleans())
    blocks: list[str] = []
    opening = draw(st.sampled_from(["", "G21 G90 G17 F600", "G20 G91 F10", "%", "F300"]))
    if opening:
        blocks.append(opening)
    if clean:
        blocks.append("F300")
    for _ in range(draw(st.integers(0, 12))):
        if draw(st.integers(0, 3)) == 0:
            blocks.append(draw(_valid_arc()))
        else:
            blocks.append(draw(_clean_block()) if clean else draw(_block()))
    if clean:
        ending = "%" if opening == "%" else draw(st.sampled_from(["M2", "M30", "M2\nG0 X5"]))
    else:
        ending = draw(st.sampled_from(["M2", "M30", "", "%", "M2\nG0 X5"]))
    blocks.append(ending)
    newline = draw(st.sampled_from(["\n", "\r\n"]))
    return newline.join(blocks) + (newline if draw(st.booleans()) else "")


def _points(move: Move) -> list[float]:
    if isinstance(move, Dwell):
        return list(move.position)
    return [*move.start, *move.end]


def _start(move: Move) -> tuple[float, float, float]:
    return move.position if isinstance(move, Dwell) else move.start


def _end(move: Move) -> tuple[float, float, float]:
    return move.position if isinstance(move, Dwell) else move.end


def _check_arc(arc: Arc) -> None:
    first, second, normal = arc.plane.axes
    assert arc.rotation != 0
    assert arc.centre[normal] == arc.start[normal]
    r1 = math.hypot(arc.start[first] - arc.centre[first], arc.start[second] - arc.centre[second])
    r2 = math.hypot(arc.end[first] - arc.centre[first], arc.end[second] - arc.centre[second])
    assert r1 > 0 and r2 > 0, arc
    difference = abs(r1 - r2)
    assert difference <= RADIUS_ABS_MM or difference / max(r1, r2) <= RADIUS_REL + 1e-12, arc
    assert all(math.isfinite(c) for c in arc.centre)


def _check_path(program: GCodeProgram, lines: int) -> None:
    position = (0.0, 0.0, 0.0)
    previous_line = 1
    for move in program.moves:
        assert all(math.isfinite(c) for c in _points(move)), move
        assert _start(move) == position, (move, position)
        position = _end(move)
        assert previous_line <= move.line <= lines, move
        previous_line = move.line
        if isinstance(move, Linear | Arc):
            assert math.isfinite(move.feed_mm_min) and move.feed_mm_min > 0, move
        if isinstance(move, Dwell):
            assert math.isfinite(move.seconds) and move.seconds >= 0, move
        if isinstance(move, Arc):
            _check_arc(move)


def _check_error(error: GCodeError, text_lines: list[str]) -> None:
    assert isinstance(error, GCodeError)
    assert error.file == FILE
    assert 1 <= error.line <= max(1, len(text_lines)), (error, len(text_lines))
    assert str(error).startswith(f"{FILE}:{error.line}")
    if error.column and error.word:
        source = text_lines[error.line - 1]
        assert 1 <= error.column <= len(source), error
        assert source[error.column - 1].upper() == error.word[0].upper(), (error, source)


def _check(text: str) -> None:
    text_lines = text.replace("\r\n", "\n").split("\n")
    if text_lines and text_lines[-1] == "" and len(text_lines) > 1:
        text_lines.pop()
    with hang_guard():
        program, error = interpret_until_error(text, file=FILE)
        assert isinstance(program, GCodeProgram)
        _check_path(program, max(1, len(text_lines)))
        event("valid program" if error is None else "program with an error")
        if any(isinstance(move, Arc) for move in program.moves):
            event("has an arc")
        if error is None:
            assert program.ended_by in ("M2", "M30", "%"), program.ended_by
            assert all(move.line <= program.end_line for move in program.moves)
            assert parse_gcode(text, file=FILE) == program
            return
        _check_error(error, text_lines)
        assert program.ended_by == ""
        with pytest.raises(GCodeError) as again:
            parse_gcode(text, file=FILE)
        assert (again.value.line, again.value.column, again.value.message) == (
            error.line, error.column, error.message)
        before = "\n".join(text_lines[: error.line - 1])
        prefix, _ = interpret_until_error(before, file=FILE)
        assert program.moves[: len(prefix.moves)] == prefix.moves
        assert all(move.line == error.line for move in program.moves[len(prefix.moves):])


@fuzz_settings()
@given(_program())
def test_plausible_programs_give_a_path_or_a_located_error(text: str) -> None:
    _check(text)


@fuzz_settings()
@given(st.lists(_FRAGMENTS, max_size=60))
def test_word_soup_gives_a_path_or_a_located_error(fragments: list[str]) -> None:
    _check("".join(fragments))
