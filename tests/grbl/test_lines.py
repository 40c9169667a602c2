"""The pre-parser, words, jogs and message texts, piece by piece."""

from __future__ import annotations

import pytest

from usbmotion.grbl.codes import GrblErrorCode
from usbmotion.grbl.interface import ModalState
from usbmotion.grbl.lines import PreParser, WordError, line_effects, line_number, parse_jog
from usbmotion.grbl.reports import coordinate, message, setting_value


def pre_parse(data: bytes) -> list[tuple[str, bool]]:
    parser = PreParser()
    return [line for line in map(parser.feed, data) if line is not None]


@pytest.mark.parametrize(("data", "lines"), [
    (b"g1 x1.5 (a (comment) y2\n", [("G1X1.5Y2", False)]),  # ( ends at the first )
    (b"G0 X1 ; to the end ) X2\n", [("G0X1", False)]),
    (b"/G0X1\t\n", [("G0X1", False)]),
    (b"\r\n", [("", False), ("", False)]),
    (b"X" * 79 + b"\n", [("X" * 79, False)]),
    (b"X" * 80 + b"\n" + b"G0\n", [("X" * 79, True), ("G0", False)]),
])
def test_the_pre_parser_keeps_what_grbl_keeps(data: bytes, lines: list[tuple[str, bool]]) -> None:
    assert pre_parse(data) == lines


def test_line_number_and_effects() -> None:
    assert line_number("N42G1X1") == 42
    assert line_number("G1X1") is None
    effects = line_effects("G4P0.5")
    assert effects.sync and not effects.offsets
    assert line_effects("G92X0").offsets
    assert line_effects("M30").end and line_effects("M0").pause
    assert not line_effects("G1X1").sync
    assert not line_effects("G1X").sync  # not words: the machine rejects it


def test_a_jog_in_inches_is_put_in_millimetres() -> None:
    move = parse_jog("G20G91X1Y-0.5F10N7", ("X", "Y", "Z"), ModalState())
    assert dict(move.words_mm) == {"X": 25.4, "Y": -12.7}
    assert move.feed_mm_min == pytest.approx(254.0)
    assert move.incremental and not move.machine_coordinates
    assert move.line_number == 7


def test_a_jog_takes_the_parsers_units_and_distance_mode_unless_told() -> None:
    modal = ModalState(units="G20", distance="G91")
    move = parse_jog("G21G90G53X1F100", ("X",), modal)
    assert dict(move.words_mm) == {"X": 1.0} and not move.incremental
    assert move.machine_coordinates
    assert parse_jog("X1F100", ("X",), modal).words_mm["X"] == pytest.approx(25.4)


@pytest.mark.parametrize(("text", "code"), [
    ("X1", GrblErrorCode.UNDEFINED_FEED_RATE),
    ("F100", GrblErrorCode.NO_AXIS_WORDS),
    ("G0X1F100", GrblErrorCode.INVALID_JOG_COMMAND),
    ("G4X1F100", GrblErrorCode.INVALID_JOG_COMMAND),
    ("G54X1F100", GrblErrorCode.INVALID_JOG_COMMAND),
    ("G53G53X1F100", GrblErrorCode.MODAL_GROUP_VIOLATION),
    ("X1T1F100", GrblErrorCode.UNUSED_WORDS),
    ("X1Q1F100", GrblErrorCode.UNSUPPORTED_COMMAND),
    ("X1F100N0.5", GrblErrorCode.INVALID_LINE_NUMBER),
    ("X1F100N-1", GrblErrorCode.NEGATIVE_VALUE),
    ("X1FF", GrblErrorCode.BAD_NUMBER_FORMAT),
    ("1X1F100", GrblErrorCode.EXPECTED_COMMAND_LETTER),
])
def test_jog_errors_have_grbls_numbers(text: str, code: GrblErrorCode) -> None:
    with pytest.raises(WordError) as raised:
        parse_jog(text, ("X", "Y", "Z"), ModalState())
    assert raised.value.code is code


def test_a_message_cannot_break_out_of_its_brackets() -> None:
    assert message("bad]\r\nok\r\n[x") == "[MSG:bad) ok (x]"
    assert message("déjà vu") == "[MSG:d?j? vu]"


def test_numbers_print_as_grbl_prints_them() -> None:
    assert coordinate(-0.0001) == "0.000"
    assert coordinate(-1.2346) == "-1.235"
    assert coordinate(25.4, inches=True) == "1.0000"
    assert setting_value(110, 500) == "500.000"
    assert setting_value(22, 1.0) == "1"
