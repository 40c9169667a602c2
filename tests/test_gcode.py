"""The G-code lexer and interpreter: each feature, each bad input, the CLI, and fuzzing."""

from __future__ import annotations

import gc
import json
import math
from functools import reduce
from operator import xor
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

from usbmotion.cli.main import app
from usbmotion.errors import GCodeError, UnsupportedGCodeError
from usbmotion.motion.gcode import (
    GCodeProgram,
    IgnoredWord,
    ToolChange,
    interpret_until_error,
    load_gcode,
    move_record,
    parse_blocks,
    parse_gcode,
    tokenize,
)
from usbmotion.motion.gcode_lexer import Word, word_columns
from usbmotion.motion.moves import Arc, Dwell, Linear, Move, Plane, Rapid

INCH = 25.4


def run(text: str) -> tuple[Move, ...]:
    """The moves of ``text`` followed by M2."""
    return parse_gcode(text + "\nM2\n", file="t.ngc").moves


def rejected(text: str) -> GCodeError:
    with pytest.raises(GCodeError) as info:
        parse_gcode(text, file="t.ngc")
    assert info.value.file == "t.ngc"
    assert str(info.value).startswith(f"t.ngc:{info.value.line}")
    return info.value


def close(a: tuple[float, ...], b: tuple[float, ...]) -> bool:
    return all(math.isclose(p, q, rel_tol=1e-12, abs_tol=1e-9) for p, q in zip(a, b, strict=True))


def checksum(text: str) -> int:
    return reduce(xor, text.encode(), 0)


# --- lexer -----------------------------------------------------------------------------


def test_number_forms_and_case() -> None:
    (block,) = parse_blocks("g1X54.834Y-52.151f120000 i0. J.103 K+1 r-.5")
    assert block.letters == "GXYFIJKR"
    assert block.values == (1.0, 54.834, -52.151, 120000.0, 0.0, 0.103, 1.0, -0.5)
    assert block.numbers[4:] == ("0.", ".103", "+1", "-.5")
    assert block.words[1] == Word("X", 54.834, "54.834")
    assert block.words[1].text == "X54.834"


def test_blanks_anywhere_outside_comments_as_linuxcnc() -> None:
    (block,) = parse_blocks("G 1 X1 2.5 Y - .5\tZ 3")
    assert block.letters == "GXYZ"
    assert block.values == (1.0, 12.5, -0.5, 3.0)


def test_comments_between_words_and_semicolon() -> None:
    (block,) = parse_blocks("G17 G2 (270 360) I0 J7 ; the rest (is) ignored")
    assert block.letters == "GGIJ"
    assert block.comments == ("270 360", " the rest (is) ignored")
    assert word_columns(block) == (1, 5, 18, 21)


def test_blank_comment_and_block_delete_lines() -> None:
    blocks = parse_blocks("\n   \n(only a comment)\n/G1 X(broken\n  /G0 X1\nG0 X2\n")
    assert [b.line for b in blocks] == [3, 6]
    assert blocks[0].letters == "" and blocks[0].comments == ("only a comment",)


def test_line_numbers_including_decimal() -> None:
    blocks = parse_blocks("N1234 S600\nN4567.789 S1200\nn10\tg0 x1\n")
    assert [b.letters for b in blocks] == ["NS", "NS", "NGX"]
    assert blocks[1].values[0] == 4567.789


def test_line_number_must_come_first() -> None:
    error = rejected("G0 X1\nG1 N20 X2\n")
    assert (error.file, error.line, error.column, error.word) == ("t.ngc", 2, 4, "N20")
    assert "first word" in error.message


def test_line_number_must_be_unsigned_digits() -> None:
    error = rejected("N-5 G0 X1\n")
    assert (error.line, error.column, error.word) == (1, 1, "N-5")
    assert "malformed" in error.message


@pytest.mark.parametrize(
    ("line", "column", "word"),
    [
        ("G1 X1.2.3 F100", 4, "X1.2.3"),
        ("G1 X-", 4, "X-"),
        ("G1 X. F1", 4, "X."),
        ("G1 X+-1", 4, "X+-1"),
    ],
)
def test_malformed_number(line: str, column: int, word: str) -> None:
    error = rejected(f"G0 X0\n{line}\nM2\n")
    assert type(error) is GCodeError
    assert (error.line, error.column, error.word) == (2, column, word)
    assert "malformed number" in error.message


def test_word_without_number() -> None:
    error = rejected("G0 X Y1\n")
    assert (error.line, error.column, error.word) == (1, 4, "X")
    assert "no number" in error.message


def test_signed_number_after_a_number_is_joined_and_malformed_as_linuxcnc() -> None:
    error = rejected("G0 X1 -5\n")
    assert (error.line, error.column, error.word) == (1, 4, "X1-5")
    assert "malformed number" in error.message


def test_unclosed_comment() -> None:
    error = rejected("G0 X1\nG1 X2 (no end F100\nM2\n")
    assert (error.line, error.column, error.word) == (2, 7, "(")
    assert "unclosed comment" in error.message


def test_nested_comment() -> None:
    error = rejected("G0 X1 (a (b) c)\n")
    assert (error.line, error.column) == (1, 10)
    assert "nested comment" in error.message


def test_unknown_letter_and_bad_characters() -> None:
    error = rejected("G0 X1 é2\n")
    assert (error.line, error.column, error.word) == (1, 7, "é")
    assert "unknown word letter" in error.message
    error = rejected("G0 X1 !\n")
    assert (error.column, error.word) == (7, "!")
    assert "unexpected character" in error.message
    assert "block delete" in rejected("G0 X1 /Y2\n").message


def test_checksum_verified_and_dropped() -> None:
    body = "N10 G1 X1 F100"
    (block,) = parse_blocks(f"{body}*{checksum(body)}\n")
    assert block.letters == "NGXF"
    assert block.source == f"{body}*{checksum(body)}"


def test_checksum_mismatch() -> None:
    body = "N11 G1 X2"
    wrong = (checksum(body) + 1) % 256
    error = rejected(f"G0 X0\n{body}*{wrong}\n")
    assert (error.line, error.column, error.word) == (2, len(body) + 1, f"*{wrong}")
    assert "checksum mismatch" in error.message
    assert str(checksum(body)) in error.message


def test_star_inside_comment_is_not_a_checksum() -> None:
    (block,) = parse_blocks("G0 X1 (a*5)\n")
    assert block.comments == ("a*5",)


@pytest.mark.parametrize(
    ("line", "word", "what"),
    [
        ("G1 X[1+2] F100", "X[", "expressions"),
        ("#1=5", "#", "parameters"),
        ("G1 X#1 F100", "X#", "parameters"),
        ("o100 sub", "O100", "O-words"),
        ("G1 @5 ^30", "@", "polar"),
    ],
)
def test_unsupported_syntax(line: str, word: str, what: str) -> None:
    error = rejected(f"G0 X0\n{line}\nM2\n")
    assert isinstance(error, UnsupportedGCodeError)
    assert (error.line, error.word) == (2, word)
    assert what in error.message and what in error.reason


def test_parse_blocks_restores_the_garbage_collector() -> None:
    assert gc.isenabled()
    parse_blocks("G0 X1\n")
    assert gc.isenabled()
    with pytest.raises(GCodeError):
        parse_blocks("G0 X(\n")
    assert gc.isenabled()
    gc.disable()
    try:
        parse_blocks("G0 X1\n")
        assert not gc.isenabled()
    finally:
        gc.enable()


def test_tokenize_is_lazy() -> None:
    blocks = tokenize("G0 X1\nG0 X(\n")
    assert next(blocks).letters == "GX"
    with pytest.raises(GCodeError):
        next(blocks)


def test_crlf_and_bom() -> None:
    blocks = parse_blocks("\ufeffG0 X1\r\nG0 X2\r\n")
    assert [b.values for b in blocks] == [(0.0, 1.0), (0.0, 2.0)]


# --- start state, modal motion, feed --------------------------------------------------------


def test_bare_axis_word_before_any_motion_code_is_an_error() -> None:
    error = rejected("G21 G90\nX10 Y5\nM2\n")
    assert (error.line, error.column, error.word) == (2, 1, "X10")
    assert "no motion mode" in error.message


def test_rapid_needs_no_feed_and_starts_at_zero() -> None:
    (move,) = run("G0 X1 Y2 Z3")
    assert move == Rapid(1, (0.0, 0.0, 0.0), (1.0, 2.0, 3.0))


def test_modal_motion_and_modal_feed() -> None:
    moves = run("G1 X1 F100\nY2\nX3 Y3 F200\nG0 Z5\nX0")
    assert [type(m) for m in moves] == [Linear, Linear, Linear, Rapid, Rapid]
    assert [m.feed_mm_min for m in moves[:3]] == [100.0, 100.0, 200.0]  # type: ignore[union-attr]
    assert moves[1].end == (1.0, 2.0, 0.0)
    assert moves[4].end == (0.0, 3.0, 5.0)


def test_feed_move_with_zero_feed_is_an_error() -> None:
    error = rejected("G0 X1\nG1 X2\nM2\n")
    assert (error.line, error.column, error.word) == (2, 1, "G1")
    assert "feed rate 0" in error.message
    error = rejected("G1 X1 F100\nF0\nX2\nM2\n")
    assert (error.line, error.column, error.word) == (3, 1, "X2")


def test_f_on_the_move_line_counts() -> None:
    (move,) = run("G1 X1 F250")
    assert isinstance(move, Linear) and move.feed_mm_min == 250.0


def test_motion_code_without_axes_moves_nowhere() -> None:
    moves = run("G0 X1\nG1 F100")
    assert moves[1] == Linear(2, (1.0, 0.0, 0.0), (1.0, 0.0, 0.0), 100.0)


def test_g80_cancels_motion_mode() -> None:
    error = rejected("G1 X1 F100\nG80\nX2\nM2\n")
    assert (error.line, error.word) == (3, "X2")
    error = rejected("G80 X1\nM2\n")
    assert "G80" in error.message


def test_negative_feed_is_an_error() -> None:
    error = rejected("G1 X1 F-100\n")
    assert (error.column, error.word) == (7, "F-100")


def test_number_out_of_range() -> None:
    error = rejected("G0 X12345678901234\n")
    assert "out of range" in error.message


# --- distance modes, units, offsets ---------------------------------------------------------


def test_g91_incremental() -> None:
    moves = run("G91 G1 X1 Y-1 F100\nX1\nZ2\nG90 X0")
    assert [m.end for m in moves] == [
        (1.0, -1.0, 0.0),
        (2.0, -1.0, 0.0),
        (2.0, -1.0, 2.0),
        (0.0, -1.0, 2.0),
    ]


def test_units_switching_mid_program() -> None:
    moves = run("G20 G0 X1\nG21 G0 Y1\nG20\nG1 Z-.5 F10\nG21 G1 X0")
    assert close(moves[0].end, (INCH, 0.0, 0.0))
    assert close(moves[1].end, (INCH, 1.0, 0.0))
    assert close(moves[2].end, (INCH, 1.0, -0.5 * INCH))
    assert isinstance(moves[2], Linear) and math.isclose(moves[2].feed_mm_min, 10 * INCH)
    # G21 keeps the physical feed: 254 mm/min.
    assert isinstance(moves[3], Linear) and math.isclose(moves[3].feed_mm_min, 10 * INCH)


def test_f_is_read_before_units_change_on_the_same_line() -> None:
    # LinuxCNC's order of execution: F (step 4) before G20 (step 16), so F10 is mm/min.
    (move,) = run("G20 G1 X1 F10")
    assert isinstance(move, Linear) and move.feed_mm_min == 10.0
    assert close(move.end, (INCH, 0.0, 0.0))


def test_g92_offsets() -> None:
    moves = run(
        "G0 X10 Y5\nG92 X0 Y0\nG0 X1 Y1\nG92.2\nG0 X1\nG92.3\nG0 X2\nG92.1\nG0 X3\n"
        "G91 G92 X0\nG0 X1"
    )
    ends = [m.end for m in moves]
    assert ends[1] == (11.0, 6.0, 0.0)  # offset (10, 5)
    assert ends[2] == (1.0, 6.0, 0.0)  # G92.2: offset cleared
    assert ends[3] == (12.0, 6.0, 0.0)  # G92.3: offset restored
    assert ends[4] == (3.0, 6.0, 0.0)  # G92.1: cleared for good
    assert ends[5] == (4.0, 6.0, 0.0)  # G92 in G91 is absolute; G91 move from 3


def test_g92_with_inches() -> None:
    moves = run("G20 G0 X1\nG92 X0\nG0 X1")
    assert close(moves[1].end, (2 * INCH, 0.0, 0.0))


def test_g92_needs_axis_words() -> None:
    error = rejected("G92\n")
    assert (error.line, error.word) == (1, "G92")
    assert "axis word" in error.message


def test_g28_goes_through_the_intermediate_point_to_zero() -> None:
    moves = run("G0 X10 Y10 Z5\nG28 Z10\nG28\nG0 X4 Y4 Z4\nG91 G28 X1")
    assert moves[1] == Rapid(2, (10.0, 10.0, 5.0), (10.0, 10.0, 10.0))
    assert moves[2] == Rapid(2, (10.0, 10.0, 10.0), (10.0, 10.0, 0.0))  # only Z homed
    assert moves[3] == Rapid(3, (10.0, 10.0, 0.0), (10.0, 10.0, 0.0))  # no intermediate
    assert moves[4] == Rapid(3, (10.0, 10.0, 0.0), (0.0, 0.0, 0.0))  # all axes
    assert moves[6] == Rapid(5, (4.0, 4.0, 4.0), (5.0, 4.0, 4.0))  # incremental
    assert moves[7] == Rapid(5, (5.0, 4.0, 4.0), (0.0, 4.0, 4.0))


def test_g28_1_and_g30_store_positions() -> None:
    moves = run("G0 X3 Y2 Z1\nG28.1\nG0 X0 Y0 Z0\nG28\nG30")
    assert moves[-3].end == (3.0, 2.0, 1.0)  # G28 to the stored position
    assert moves[-1].end == (0.0, 0.0, 0.0)  # G30 position was never set


def test_g28_and_a_motion_code_cannot_share_axis_words() -> None:
    error = rejected("G28 G1 X1 F100\n")
    assert (error.column, error.word) == (5, "G1")
    assert "separate lines" in error.message


# --- arcs -----------------------------------------------------------------------------------


def test_full_circle_in_each_plane() -> None:
    xy, xz, yz = run("G0 X1 Y1 Z1\nG17 G2 I.5 J.5 F100\nG18 G2 I.5 K.5\nG19 G3 J.5 K.5")[1:]
    assert xy == Arc(2, (1, 1, 1), (1, 1, 1), (1.5, 1.5, 1.0), Plane.XY, -1, 100.0)
    assert xz == Arc(3, (1, 1, 1), (1, 1, 1), (1.5, 1.0, 1.5), Plane.XZ, -1, 100.0)
    assert yz == Arc(4, (1, 1, 1), (1, 1, 1), (1.0, 1.5, 1.5), Plane.YZ, 1, 100.0)
    assert xy.clockwise and not yz.clockwise


def test_quarter_arcs_cw_and_ccw() -> None:
    cw, ccw = run("G0 X10\nG2 X0 Y-10 I-10 F60\nG3 X10 Y0 I0 J10")[1:]
    assert isinstance(cw, Arc) and isinstance(ccw, Arc)
    assert cw.end == (0.0, -10.0, 0.0) and cw.centre == (0.0, 0.0, 0.0) and cw.rotation == -1
    assert ccw.centre == (0.0, 0.0, 0.0) and ccw.rotation == 1


def test_helix_and_p_turns() -> None:
    (arc,) = run("G2 X0 Y0 Z-6 I5 P3 F100")
    assert isinstance(arc, Arc)
    assert arc.end == (0.0, 0.0, -6.0)
    assert arc.centre == (5.0, 0.0, 0.0)  # the normal coordinate is the start's
    assert arc.rotation == -3
    (arc,) = run("G19 G3 Y0 Z0 X4 J2 P2 F100")
    assert isinstance(arc, Arc) and arc.rotation == 2 and arc.end == (4.0, 0.0, 0.0)


@pytest.mark.parametrize("p", ["1.5", "0", "-1"])
def test_p_turns_must_be_a_whole_number_of_one_or_more(p: str) -> None:
    error = rejected(f"G2 X0 Y0 I5 P{p} F100\n")
    assert (error.column, error.word) == (13, f"P{p}")
    assert "turns" in error.message


def test_arc_centre_absolute_g90_1_and_incremental_g91_1() -> None:
    moves = run("G0 X10 Y10\nG90.1 G2 X20 Y10 I15 J10 F100\nG91.1 G3 X10 Y10 I-5 J0")
    assert isinstance(moves[1], Arc) and moves[1].centre == (15.0, 10.0, 0.0)
    assert isinstance(moves[2], Arc) and moves[2].centre == (15.0, 10.0, 0.0)


def test_absolute_arc_centre_needs_both_words() -> None:
    error = rejected("G0 X10\nG90.1 G2 X0 I5 F100\nM2\n")
    assert (error.line, error.word) == (2, "G2")
    assert "J word missing" in error.message


def test_absolute_arc_centre_is_in_program_coordinates() -> None:
    moves = run("G0 X10\nG92 X0\nG90.1 G2 X10 I5 J0 F100")
    assert isinstance(moves[1], Arc) and moves[1].centre == (15.0, 0.0, 0.0)


def test_arc_in_inches() -> None:
    (arc,) = run("G20\nG3 X2 Y0 I1 F1")
    assert isinstance(arc, Arc)
    assert close(arc.end, (2 * INCH, 0.0, 0.0)) and close(arc.centre, (INCH, 0.0, 0.0))
    assert math.isclose(arc.feed_mm_min, INCH)


def test_modal_arc_line_with_only_centre_words() -> None:
    moves = run("G0 X1\nG2 X2 I.5 F10\nI-.5")
    assert isinstance(moves[2], Arc) and moves[2].end == moves[2].start == (2.0, 0.0, 0.0)


def test_radius_format_arcs() -> None:
    small, large = run("G2 X10 R5 F100\nG3 X0 R-5")
    assert isinstance(small, Arc) and isinstance(large, Arc)
    assert close(small.centre, (5.0, 0.0, 0.0))  # a semicircle
    quarter, over = run("G2 X10 Y10 R10 F100\nG2 X20 Y0 R-10")
    assert isinstance(quarter, Arc) and isinstance(over, Arc)
    assert close(quarter.centre, (10.0, 0.0, 0.0))  # R>0: the short way round
    assert close(over.centre, (20.0, 10.0, 0.0))  # R<0: the long way round (270 degrees)


def test_radius_arc_in_yz_matches_linuxcnc() -> None:
    # simple_arc2: G19 G3 Y-20 R20 from (0, 10, 0): centre (Y-5, Z-13.2287565553).
    arc = run("G1 X0 Y10 F1000\nG19 G3 Y-20 R20")[1]
    assert isinstance(arc, Arc)
    assert math.isclose(arc.centre[1], -5.0) and math.isclose(arc.centre[2], -13.2287565553)


def test_radius_too_small_to_reach_the_end() -> None:
    error = rejected("G0 X0\nG2 X10 R4.9 F100\n")
    assert (error.line, error.column, error.word) == (2, 8, "R4.9")
    assert "too small" in error.message


def test_radius_just_short_of_half_the_chord_is_a_semicircle() -> None:
    (arc,) = run("G2 X10 R4.999 F100")  # within 0.00127 mm of 5
    assert isinstance(arc, Arc) and close(arc.centre, (5.0, 0.0, 0.0))


def test_radius_arc_full_circle_and_zero_radius_are_errors() -> None:
    assert "full circle" in rejected("G0 X1\nG2 X1 Y0 R5 F100\n").message
    assert "cannot be zero" in rejected("G2 X1 R0 F100\n").message
    error = rejected("G2 Z1 R5 F100\n")
    assert "no X or Y end point" in error.message


def test_arc_with_no_centre_words() -> None:
    error = rejected("G0 X0\ng2f1x1\n")
    assert isinstance(error, GCodeError) and not isinstance(error, UnsupportedGCodeError)
    assert (error.file, error.line, error.column, error.word) == ("t.ngc", 2, 1, "G2")
    assert "R, I, J and K are all missing" in error.message


def test_arc_with_both_forms_or_the_wrong_plane_letter() -> None:
    assert "both R and I/J/K" in rejected("G2 X1 I1 R1 F1\n").message
    error = rejected("G2 X1 I.5 K1 F1\n")
    assert (error.word, error.column) == ("K1", 11)
    assert "XY plane" in error.message
    assert "XZ plane" in rejected("G18 G2 X1 I.5 J1 F1\n").message


def test_arc_with_zero_feed() -> None:
    error = rejected("G2 X1 I.5\n")
    assert "feed rate 0" in error.message and error.word == "G2"


def test_zero_radius_arc() -> None:
    error = rejected("G2 X1 I0 J0 F1\n")
    assert "zero-radius" in error.message


@pytest.mark.parametrize(
    ("units", "end", "i", "accepted"),
    [
        ("G21", 50.0, 24.986, True),  # 0.028 mm apart: inside 0.0283 mm
        ("G21", 50.0, 24.985, False),  # 0.030 mm and 0.12 %: outside
        ("G21", 6000.0, 3001.4, True),  # 2.8 mm but only 0.093 %
        ("G21", 6000.0, 3001.5, False),  # 3 mm: beyond 100 x 0.0283 mm
        ("G20", 5.0, 2.4986, True),  # 0.0028 inch: inside 0.00283 inch
        ("G20", 5.0, 2.4985, False),
    ],
)
def test_arc_radius_tolerance(units: str, end: float, i: float, accepted: bool) -> None:
    text = f"{units} G0 X0 Y0\nG2 X{end} I{i} F1\nM2\n"
    program, error = interpret_until_error(text, file="t.ngc")
    if accepted:
        assert error is None
        arc = program.moves[1]
        assert isinstance(arc, Arc)
        scale = INCH if units == "G20" else 1.0
        assert math.isclose(arc.centre[0], i * scale)  # the programmed centre is kept
    else:
        assert error is not None and error.line == 2
        assert "differs from the radius" in error.message
        assert len(program.moves) == 1


# --- dwell, program structure ----------------------------------------------------------------


def test_dwell() -> None:
    moves = run("G0 X1\nG4 P1.5")
    assert moves[1] == Dwell(2, (1.0, 0.0, 0.0), 1.5)
    assert "needs P" in rejected("G4\n").message
    assert "negative" in rejected("G4 P-1\n").message
    assert "both use P" in rejected("G4 G2 X1 I1 P1 F1\n").message


def test_program_end_stops_reading() -> None:
    program = parse_gcode("G0 X1\nM30\nthis is not G-code (\n")
    assert (program.ended_by, program.end_line) == ("M30", 2)
    program = parse_gcode("G0 X1 M2\n")
    assert program.ended_by == "M2" and len(program.moves) == 1


def test_percent_delimiters() -> None:
    program = parse_gcode("\n%\nG0 X1\n%\nG0 X(\n")
    assert (program.ended_by, program.end_line) == ("%", 4)
    error = rejected("%\nG0 X1\n")
    assert "closing '%'" in error.message
    error = rejected("G0 X1\n%\n")
    assert (error.line, error.column, error.word) == (2, 1, "%")
    assert "opens with a '%'" in error.message


def test_missing_program_end_keeps_the_moves() -> None:
    program, error = interpret_until_error("G0 X1\nG0 X2\n\n", file="t.ngc")
    assert error is not None and error.line == 3 and error.column == 0
    assert "without M2, M30" in error.message
    assert [m.end for m in program.moves] == [(1.0, 0.0, 0.0), (2.0, 0.0, 0.0)]
    assert program.ended_by == "" and program.end_line == 0


def test_interpret_until_error_keeps_moves_before_the_error() -> None:
    program, error = interpret_until_error("G0 X1\nG1 X2 F10\nG41 X3\nG0 X4\nM2\n")
    assert isinstance(error, UnsupportedGCodeError)
    assert (error.line, error.column, error.word) == (3, 1, "G41")
    assert len(program.moves) == 2
    assert str(error) == f"<string>:3:1: {error.message}"


# --- group conflicts, repeated and unused words ------------------------------------------------


def test_two_motion_codes_in_one_block() -> None:
    error = rejected("G0 X0\nG0 G1 X1 F100\n")
    assert (error.line, error.column, error.word) == (2, 4, "G1")
    assert "motion group" in error.message


def test_g80_beside_another_motion_code_is_dropped() -> None:
    (move,) = run("G80 G0 X1")
    assert isinstance(move, Rapid)


def test_two_codes_of_another_group() -> None:
    error = rejected("G20 G21 G0 X1\n")
    assert error.word == "G21" and "units group" in error.message
    error = rejected("G0 X1 M3 M4\n")
    assert error.word == "M4" and "spindle group" in error.message


def test_repeated_word() -> None:
    error = rejected("G0 X0\nG1 X1 Y2 X3 F100\n")
    assert (error.line, error.column, error.word) == (2, 10, "X3")
    assert "X appears twice" in error.message


@pytest.mark.parametrize(
    ("line", "word", "what"),
    [
        ("G0 X1 I2", "I2", "I word with no G2 or G3"),
        ("G0 X1 R2", "R2", "R word with no G2, G3, canned cycle or G10 L2"),
        ("G0 X1 P2", "P2", "P word"),
        ("G0 X1 Q2", "Q2", "Q word"),
        ("M61", "M61", "needs Q"),
    ],
)
def test_words_nothing_uses(line: str, word: str, what: str) -> None:
    error = rejected(line + "\nM2\n")
    assert error.word == word and what in error.message


def test_code_numbers() -> None:
    assert "at most one decimal" in rejected("G1.05 X1\n").message
    assert "whole numbers" in rejected("M3.5\n").message
    moves = run("G01 X1 F10\nG00 X2\nG1.0 X3")
    assert [type(m) for m in moves] == [Linear, Rapid, Linear]


# --- unsupported and ignored words ---------------------------------------------------------


@pytest.mark.parametrize(
    ("line", "word", "what"),
    [
        ("G41 D1", "G41", "cutter radius compensation"),
        ("G42.1 D1", "G42.1", "cutter radius compensation"),
        ("G43.2 H1", "G43.2", "adding to the tool length offset"),
        ("G84 X1 Y1 Z-1 R1", "G84", "tapping"),
        ("G86 X1 Y1 Z-1 R1", "G86", "boring cycles"),
        ("G10 L1 P1 Z1", "L1", "only G10 L2 and G10 L20"),
        ("G52 X1", "G52", "local coordinate offsets"),
        ("G33 Z-1 K1", "G33", "spindle-synchronized"),
        ("G38.2 Z-1 F10", "G38.2", "probing"),
        ("G5 X1 I1 J1 P1 Q1", "G5", "spline"),
        ("G7", "G7", "lathe"),
        ("G12 X1", "G12", "not a G code LinuxCNC knows"),
        ("G0 A90", "A90", "the machine has no axis A"),
        ("G0 B1", "B1", "the machine has no axis B"),
        ("G0 C1", "C1", "the machine has no axis C"),
        ("G0 U1", "U1", "axis U"),
        ("G0 V1", "V1", "axis V"),
        ("G0 W1", "W1", "axis W"),
        ("G1 X1 E0.5 F10", "E0.5", "extruder"),
        ("M98 P100", "M98", "subroutine"),
        ("M62 P1", "M62", "I/O"),
        ("M100", "M100", "user-defined"),
        ("M10", "M10", "not an M code"),
    ],
)
def test_unsupported_words(line: str, word: str, what: str) -> None:
    program, error = interpret_until_error(f"G0 X5\n{line}\nM2\n", file="u.ngc")
    assert isinstance(error, UnsupportedGCodeError)
    assert (error.file, error.line, error.word) == ("u.ngc", 2, word)
    assert error.column == line.upper().index(word) + 1
    assert what in error.message and what in error.reason
    assert error.message == f"{word}: {error.reason}"
    assert len(program.moves) == 1


def test_ignored_words_are_listed() -> None:
    program = parse_gcode(
        "G21 G54 G40 G49 G94 G17 G61\n"
        "T1 M6\n"
        "S12000 M3 M8\n"
        "G64 P0.01 Q0.01\n"
        "G0 X1 D1 H1\n"
        "M0\n"
        "M5 M9 M1\n"
        "M2\n"
    )
    assert [(w.word, w.line, w.column) for w in program.ignored] == [
        ("G40", 1, 9),
        ("G61", 1, 25),
        ("S12000", 3, 1),
        ("M3", 3, 8),
        ("M8", 3, 11),
        ("G64", 4, 1),
        ("P0.01", 4, 5),
        ("Q0.01", 4, 11),
        ("D1", 5, 7),
        ("H1", 5, 10),
        ("M0", 6, 1),
        ("M5", 7, 1),
        ("M9", 7, 4),
        ("M1", 7, 7),
    ]
    assert all(isinstance(w, IgnoredWord) and w.meaning for w in program.ignored)
    assert program.ignored[2].meaning == "spindle speed"
    assert len(program.moves) == 1
    assert program.tool_changes == (ToolChange(2, 1, 0, True),)  # G54, G49, T1 M6 act


def test_ignored_words_of_a_rejected_line_are_not_listed() -> None:
    program, error = interpret_until_error("S100 G1 X1\nM2\n")
    assert error is not None and program.ignored == ()


# --- files and the JSON schema ------------------------------------------------------------


def test_load_gcode_reads_latin1_files(tmp_path: Path) -> None:
    path = tmp_path / "part.ngc"
    path.write_bytes("(Ø 6 mm cutter)\nG0 X1\nM2\n".encode("latin-1"))
    program = load_gcode(path)
    assert program.file == str(path) and len(program.moves) == 1
    path.write_bytes(b"G0 X1\nG1 X2\nM2\n")
    with pytest.raises(GCodeError) as info:
        load_gcode(path)
    assert info.value.file == str(path) and info.value.line == 2


def test_move_records() -> None:
    moves = run("G0 X1\nG1 Y1 F60\nG18 G2 X1 Y1 I0 K1\nG4 P2")
    records = [move_record(m) for m in moves]
    assert records[0] == {
        "line": 1,
        "type": "rapid",
        "start": [0.0, 0.0, 0.0],
        "end": [1.0, 0.0, 0.0],
    }
    assert records[1]["type"] == "linear" and records[1]["feed"] == 60.0
    assert records[2] == {
        "line": 3,
        "type": "arc",
        "start": [1.0, 1.0, 0.0],
        "end": [1.0, 1.0, 0.0],
        "plane": "XZ",
        "direction": "cw",
        "rotation": -1,
        "centre": [1.0, None, 1.0],
        "feed": 60.0,
    }
    assert records[3] == {"line": 4, "type": "dwell", "seconds": 2.0, "position": [1.0, 1.0, 0.0]}
    assert json.loads(json.dumps(records)) == records


# --- the command ------------------------------------------------------------------------------


def test_cli_prints_moves_as_json_lines(tmp_path: Path) -> None:
    path = tmp_path / "ok.ngc"
    path.write_text("G21\nG0 X1 Y2\nG2 X3 Y2 I1 F100\nS1000 M3\nM2\n")
    result = CliRunner().invoke(app, ["gcode", "moves", str(path)])
    assert result.exit_code == 0, result.stderr
    records = [json.loads(line) for line in result.stdout.splitlines()]
    assert [r["type"] for r in records] == ["rapid", "arc"]
    assert records[1]["centre"] == [2.0, 2.0, None] and records[1]["line"] == 3
    assert f"{path}:4: ignored S1000" in result.stderr
    quiet = CliRunner().invoke(app, ["gcode", "moves", "--quiet", str(path)])
    assert quiet.exit_code == 0 and quiet.stderr == ""


def test_cli_prints_moves_before_the_error_then_exits_1(tmp_path: Path) -> None:
    path = tmp_path / "bad.ngc"
    path.write_text("G0 X1\nG1 X2 F100\nG2 X3\nG0 X4\nM2\n")
    result = CliRunner().invoke(app, ["gcode", "moves", str(path)])
    assert result.exit_code == 1
    assert [json.loads(line)["line"] for line in result.stdout.splitlines()] == [1, 2]
    assert result.stderr.startswith(f"{path}:3: G2 arc with no centre")
    assert "Traceback" not in result.stderr


def test_cli_missing_file_exits_2(tmp_path: Path) -> None:
    result = CliRunner().invoke(app, ["gcode", "moves", str(tmp_path / "nope.ngc")])
    assert result.exit_code == 2
    assert "cannot read" in result.stderr and "nope.ngc" in result.stderr
    assert result.stdout == ""


# --- fuzzing ----------------------------------------------------------------------------------

_WORD_TEXT = (
    "G0 G1 G2 G3 G4 G17 G18 G19 G20 G21 G28 G28.1 G30 G80 G90 G91 G90.1 G91.1 G92 G92.1 "
    "G92.2 G92.3 G41 G54 G64 G81 G99 G1.5 M2 M3 M6 M30 M98 M3.5 N10 N1.5 X Y Z I J K R P "
    "Q F S T A E L O D H ( ) (c) ; % / * # [ ] @ - + . 0 1 5 10 -2.5 .5 1e5 99999999999 é !"
)
_FRAGMENTS = st.sampled_from([*_WORD_TEXT.split(), " ", "\t", "\n", "\r\n"])


@settings(max_examples=400, deadline=None)
@given(st.lists(_FRAGMENTS, max_size=60))
def test_any_text_gives_moves_or_a_gcode_error(fragments: list[str]) -> None:
    text = "".join(fragments)
    program, error = interpret_until_error(text, file="fuzz.ngc")
    assert isinstance(program, GCodeProgram)
    for move in program.moves:
        coordinates = [*move.start, *move.end] if not isinstance(move, Dwell) else move.position
        assert all(math.isfinite(c) for c in coordinates)
    if error is not None:
        assert isinstance(error, GCodeError)
        assert error.file == "fuzz.ngc" and error.line >= 1 and error.column >= 0
        with pytest.raises(GCodeError):
            parse_gcode(text, file="fuzz.ngc")
    else:
        assert parse_gcode(text, file="fuzz.ngc") == program


@settings(max_examples=200, deadline=None)
@given(st.text(max_size=80))
def test_arbitrary_unicode_text_gives_moves_or_a_gcode_error(text: str) -> None:
    _program, error = interpret_until_error(text)
    assert error is None or isinstance(error, GCodeError)
