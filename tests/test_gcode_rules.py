"""G-code as its controllers keep it: G and M codes named as LinuxCNC names them, the G92
offset at a program's end and a reset in each dialect, each dialect's line length, Klipper's
commands and Marlin's M17 by name, and ``usbmotion gcode moves --machine``."""

from __future__ import annotations

import ast
import json
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

from usbmotion.cli.main import app
from usbmotion.errors import GCodeError, UnsupportedGCodeError
from usbmotion.grbl.lines import PreParser
from usbmotion.motion.dialects import RULES, Dialect
from usbmotion.motion.gcode import (
    NO_MOTION,
    GCode,
    GCodeStream,
    MachineAxes,
    MCode,
    MGroup,
    ModalGroup,
    interpret_setting,
    interpret_until_error,
    parse_gcode,
)
from usbmotion.motion.gcode_lexer import LineLimit
from usbmotion.motion.moves import Linear, Rapid
from usbmotion.motion.offsets import NO_OFFSETS, format_parameter_file, parse_parameter_file

ROOT = Path(__file__).resolve().parent.parent
MOTION = ROOT / "src" / "usbmotion" / "motion"
DEFAULT = ROOT / "src" / "usbmotion" / "data" / "machine.toml"
PLOTTER = ROOT / "examples" / "plotter.toml"
HOMED = MachineAxes(axes="XYZ", home_mm=(1.0, 2.0, 90.0), homing_order=("Z", "XY"))


def _xyz(x: float, y: float, z: float) -> tuple[float, ...]:
    return (x, y, z, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)


# --- names ----------------------------------------------------------------------------------


def test_g_codes_and_groups_carry_linuxcncs_names_and_numbers() -> None:
    assert (GCode.G_0, GCode.G_1, GCode.G_53, GCode.G_90_1, GCode.G_92_3) == (0, 10, 530, 901,
                                                                             923)
    assert GCode.G_59_3.text == "G59.3" and GCode.G_0.text == "G0"
    groups = {group.name: group.value for group in ModalGroup}
    assert groups == {"MODAL_0": 0, "MOTION": 1, "SET_PLANE": 2, "DISTANCE_MODE": 3,
                      "IJK_DISTANCE_MODE": 4, "FEED_MODE": 5, "LENGTH_UNITS": 6,
                      "CUTTER_COMP": 7, "TOOL_LENGTH_OFFSET": 8, "RETRACT_MODE": 10,
                      "COORD_SYSTEM": 12, "CONTROL_MODE": 13, "SPINDLE_MODE": 14,
                      "LATHE_DIAMETER_MODE": 15, "G92_IS_APPLIED": 16}
    assert (MCode.M_30, MGroup.STOPPING, MGroup.TOOL_CHANGE) == (30, 4, 6)
    assert RULES[Dialect.GRBL].start_motion is GCode.G_0 and NO_MOTION == -1


def test_a_line_holds_one_code_of_each_group_named_in_the_message() -> None:
    with pytest.raises(GCodeError) as caught:
        parse_gcode("G17 G18\nM2\n")
    assert "G18 and G17 are both in the plane selection group" in caught.value.message
    with pytest.raises(GCodeError) as caught:
        parse_gcode("M8 M9\nM2\n")
    assert "M9 and M8 are both in the coolant group" in caught.value.message


def test_g92_1_to_g92_3_are_their_own_group_after_g92_as_in_linuxcnc_2_9() -> None:
    program = parse_gcode("G0 X10\nG92 X0 G92.2\nG0 X1\nG92.3\nG0 X1\nM2\n")
    assert [move.end[0] for move in program.moves] == [10.0, 1.0, 11.0]
    with pytest.raises(GCodeError, match=r"G92\.3 and G92\.2 are both in the G92 applied"):
        parse_gcode("G92.2 G92.3\nM2\n")


_CODE_VALUES = frozenset(code.value for code in GCode if code.value >= 10)


def _bare_codes(source: str) -> list[str]:
    """Comparisons and modal-group look-ups written with bare numbers: an int literal that
    is a G code (x10) compared, or any int literal used as the key of a ``*codes``/``*where``
    table (``g_codes.get(0)``, ``m_where[4]``)."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Compare) and any(
                isinstance(sub, ast.Constant) and type(sub.value) is int
                and sub.value in _CODE_VALUES
                for side in (node.left, *node.comparators) for sub in ast.walk(side)):
            found.append(f"{node.lineno}: {ast.unparse(node)}")
        key: ast.expr | None = None
        table: ast.expr | None = None
        if (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute)
                and node.func.attr == "get" and node.args):
            key, table = node.args[0], node.func.value
        elif isinstance(node, ast.Subscript):
            key, table = node.slice, node.value
        if (isinstance(key, ast.Constant) and type(key.value) is int
                and isinstance(table, ast.Name) and table.id.endswith(("codes", "where"))):
            found.append(f"{node.lineno}: {ast.unparse(node)}")
    return found


def test_the_scanner_finds_bare_code_numbers() -> None:
    assert _bare_codes("if g_codes.get(0) == 530:\n    pass\n") == [
        "1: g_codes.get(0) == 530", "1: g_codes.get(0)"]
    assert _bare_codes("x = m_where[4]\ny = motion in (20, 30)\n") == [
        "1: m_where[4]", "2: motion in (20, 30)"]
    assert _bare_codes("if code == GCode.G_53 and len(m_codes) == 4:\n    pass\n") == []


@pytest.mark.parametrize("module", sorted(path.name for path in MOTION.glob("*.py")
                                          if path.name != "gcode_codes.py"))
def test_motion_names_its_codes(module: str) -> None:
    assert _bare_codes((MOTION / module).read_text()) == []


# --- the G92 offset at a program's end ------------------------------------------------------


@pytest.mark.parametrize("end", ["M2\n", "M30\n", "%\n"])
def test_a_program_end_suspends_g92_keeping_its_values(end: str) -> None:
    text = ("%\n" if end == "%\n" else "") + "G0 X10 Y5\nG92 X0 Y0\nG0 X1\n" + end
    program = parse_gcode(text)
    assert program.moves[-1].end == (11.0, 5.0, 0.0)
    offsets = program.offsets
    assert offsets.g92 == _xyz(10.0, 5.0, 0.0) and offsets.g92_enabled is False
    kept = parse_parameter_file(format_parameter_file(offsets))
    assert kept == offsets
    assert "5210\t0.000000\n5211\t10.000000\n5212\t5.000000\n" in format_parameter_file(offsets)
    # The next job is not shifted; G92.3 brings the stored offset back.
    assert parse_gcode("G0 X1\nM2\n", offsets=offsets).moves[0].end == (1.0, 0.0, 0.0)
    again = parse_gcode("G92.3\nG0 X1 Y0\nM2\n", offsets=offsets)
    assert again.moves[0].end == (11.0, 5.0, 0.0)
    assert again.offsets.g92_enabled is False


def test_a_g92_kept_in_the_parameter_file_applies_until_the_program_ends() -> None:
    offsets = parse_parameter_file("5210 1\n5211 3\n")
    program = parse_gcode("G0 X1\nM2\n", offsets=offsets)
    assert program.moves[0].end == (4.0, 0.0, 0.0)
    assert program.offsets.g92 == _xyz(3.0, 0.0, 0.0) and not program.offsets.g92_enabled


def test_a_program_end_resets_what_linuxcnc_lists_and_a_stream_goes_on_from_there() -> None:
    stream = GCodeStream(offsets=NO_OFFSETS.with_g5x(2, _xyz(100.0, 0.0, 0.0)))
    for line in ("G55 G91 G18 G1 X1 F100", "G81 R1 Y-1", "M2"):
        stream.feed(line)
    modes = stream.modes()
    assert (modes.coordinate_system, modes.plane, modes.incremental) == (1, 17, False)
    assert modes.motion_x10 == GCode.G_1 and modes.feed_mm_min == 100.0
    stream.restart(stream.position)
    (move,) = stream.feed("X5")
    assert isinstance(move, Linear) and move.end == (5.0, 1.0, 0.0)  # G1, G90, G54


@pytest.mark.parametrize("dialect", [Dialect.GRBL, Dialect.MARLIN])
def test_grbl_and_marlin_never_keep_g92(dialect: Dialect) -> None:
    stored = parse_parameter_file("5210 1\n5211 3\n5212 4\n")
    # A program starts without the stored G92, and leaves the parameter file's as it was.
    program = parse_gcode("G0 X1\nG92 X0\nG0 X2\n", offsets=stored, dialect=dialect)
    assert [move.end for move in program.moves] == [(1.0, 0.0, 0.0), (3.0, 0.0, 0.0)]
    assert (program.offsets.g92, program.offsets.g92_enabled) == (stored.g92, True)
    ended = parse_gcode("G0 X1\nG92 X0\nM2\n", dialect=dialect)
    assert ended.offsets == NO_OFFSETS
    # A stream's G92 lasts until its program ends, and is never part of its offsets.
    stream = GCodeStream(dialect=dialect)
    stream.feed("G0 X10")
    stream.feed("G92 X0")
    stream.restart(stream.position)
    stream.feed("G0 X1")
    assert stream.position == (11.0, 0.0, 0.0) and stream.result().offsets == NO_OFFSETS
    stream.feed("M2")
    stream.restart(stream.position)
    stream.feed("G0 X1")
    assert stream.position == (1.0, 0.0, 0.0)
    assert stream.modes().offset_mm == (0.0, 0.0, 0.0)


def test_marlin_homing_clears_the_g92_shift_of_the_axes_it_homes() -> None:
    text = "G0 X10 Y10\nG92 X0 Y0\nG28 X\nG0 X5 Y5\n"
    program = parse_gcode(text, machine=HOMED, dialect=Dialect.MARLIN)
    assert program.moves[-1].end == (5.0, 15.0, 0.0)  # X's shift gone, Y's kept
    grbl = parse_gcode("G0 X10\nG92 X0\n$HX\nG0 X5\n", machine=HOMED, dialect=Dialect.GRBL)
    assert grbl.moves[-1].end == (15.0, 0.0, 0.0)  # grbl's homing keeps G92


def test_a_g92_setting_is_refused_where_no_setting_keeps_it() -> None:
    start = (10.0, 0.0, 0.0)
    assert interpret_setting("G92 X0", start=start).g92 == _xyz(10.0, 0.0, 0.0)
    for dialect in (Dialect.GRBL, Dialect.MARLIN):
        with pytest.raises(GCodeError) as caught:
            interpret_setting("G92 X0", start=start, dialect=dialect)
        message = caught.value.message
        assert caught.value.word == "G92" and f"the {dialect.value} dialect" in message
        assert "G10 L20 P1" in message
    assert interpret_setting("G10 L20 P1 X0", start=start, dialect=Dialect.GRBL).g5x[0] == (
        _xyz(10.0, 0.0, 0.0))


def test_a_grbl_reset_clears_what_grbls_reset_clears() -> None:
    stream = GCodeStream(dialect=Dialect.GRBL)
    for line in ("G10 L2 P2 X100", "G55 G20 G91 G17 G1 X1 F10", "G43.1 Z1", "G92 X0",
                 "G28.1"):
        stream.feed(line)
    # G55 at X100, G91 X1 inch to machine 25.4, G92 reading 0 there: an offset of 25.4.
    assert stream.modes().offset_mm == pytest.approx((25.4, 0.0, 25.4))
    stream.reset(stream.position)
    modes = stream.modes()
    assert (modes.coordinate_system, modes.inches, modes.incremental) == (1, False, False)
    assert (modes.motion_x10, modes.feed_mm_min, modes.offset_mm) == (GCode.G_0, 0.0,
                                                                      (0.0, 0.0, 0.0))
    stream.feed("G55 X1")  # G10 L2 and the G28 position stay
    assert stream.position == (101.0, 0.0, 0.0)
    offsets = stream.result().offsets
    assert offsets.g28 == _xyz(25.4, 0.0, 0.0) and offsets.g92 == NO_OFFSETS.g92


def test_a_linuxcnc_abort_keeps_the_modal_state_and_g92() -> None:
    stream = GCodeStream()
    for line in ("G91 G1 X1 F100", "G92 X0"):
        stream.feed(line)
    stream.reset(stream.position)
    (move,) = stream.feed("X1")
    assert isinstance(move, Linear) and move.end == (2.0, 0.0, 0.0)
    assert stream.modes().offset_mm == (1.0, 0.0, 0.0)


def test_a_reset_drops_the_program_and_takes_lines_after_an_end() -> None:
    stream = GCodeStream(dialect=Dialect.MARLIN)
    stream.feed("G1 X1 F100")
    stream.feed("M2")
    with pytest.raises(GCodeError, match="program ended"):
        stream.feed("G0 X2")
    stream.reset((5.0, 0.0, 0.0))
    assert stream.moves == [] and stream.ended_by == ""
    with pytest.raises(GCodeError, match="no motion mode"):
        stream.feed("X2")  # Marlin starts with no motion mode; M2 had left G1
    (move,) = stream.feed("G0 X2")
    assert move == Rapid(5, (5.0, 0.0, 0.0), (2.0, 0.0, 0.0))


# --- line length ----------------------------------------------------------------------------


def _words(count: int) -> str:
    """A grbl line of ``count`` kept characters: ``G1F100X1.000...``."""
    head = "G1F100X1."
    return head + "0" * (count - len(head))


@pytest.mark.parametrize(("kept", "accepted"), [(79, True), (80, False)])
def test_grbl_keeps_79_characters_of_a_line(kept: int, accepted: bool) -> None:
    line = _words(kept)
    spaced = " ".join(line) + " (" + "c" * 300 + ") ; and more"
    for text in (line, spaced):
        program, error = interpret_until_error(f"G21\n{text}\n", dialect=Dialect.GRBL)
        if accepted:
            assert error is None and len(program.moves) == 1
        else:
            assert isinstance(error, GCodeError) and error.line == 2
            assert f"line too long: {kept} characters as grbl keeps them" in error.message
            assert "keeps at most 79" in error.message and "error:11" in error.message
            assert text[error.column - 1] == line[79]
    # The same comment-long line is too long for LinuxCNC.
    with pytest.raises(GCodeError, match="LINELEN"):
        parse_gcode(f"{' '.join(_words(20))} ({'c' * 300})\nM2\n")


@pytest.mark.parametrize(("kept", "accepted"), [(95, True), (96, False)])
def test_marlin_keeps_95_characters_of_a_command(kept: int, accepted: bool) -> None:
    head = "G1 F100 X1."
    line = head + "0" * (kept - len(head))
    for text in (line + ";" + "c" * 300, line + "(" + "c" * 40 + ")"):
        program, error = interpret_until_error(f"{text}\n", dialect=Dialect.MARLIN)
        if accepted:
            assert error is None and len(program.moves) == 1
        else:
            assert isinstance(error, GCodeError) and error.line == 1
            assert f"line too long: {kept} characters besides its comments" in error.message
            assert "MAX_CMD_SIZE" in error.message and error.column == 96
    # Marlin keeps the spaces: 50 words of two characters and a space are 149 characters.
    _, error = interpret_until_error("M117 " + "ab " * 50 + "\n", dialect=Dialect.MARLIN)
    assert isinstance(error, GCodeError) and "too long" in error.message


def _lines(shortest: int, longest: int) -> st.SearchStrategy[str]:
    """Lines around a limit: characters both controllers keep, and what they drop."""
    pieces = st.sampled_from(["G", "X", "1", "1", "1", "\u00e9", " ", "\t", "/", "(cc)"])
    body = st.lists(pieces, min_size=shortest, max_size=longest).map("".join)
    return st.tuples(body, st.sampled_from(["", "", ";c (c)", "(c"])).map("".join)


@settings(max_examples=300, deadline=None)
@given(_lines(95, 130))
def test_the_grbl_limit_is_grbls_own_pre_parser(text: str) -> None:
    """The lexer's grbl limit against the grbl front's pre-parser, byte by byte."""
    parser = PreParser()
    outcome = None
    for byte in (text + "\n").encode("utf-8"):
        outcome = parser.feed(byte)
    assert outcome is not None
    _, error = interpret_until_error(text, dialect=Dialect.GRBL)
    assert (error is not None and "too long" in error.message) == outcome[1]


def _marlin_kept(data: bytes) -> bytes:
    """The bytes of a line Marlin's reader keeps (``queue.cpp``, ``process_stream_char``,
    with PAREN_COMMENTS) if its buffer were endless; its 96-byte buffer keeps 95 of them."""
    kept, state = bytearray(), "normal"
    for byte in data:
        if state == "paren":
            state = "normal" if byte == ord(")") else state
        elif byte == ord(";"):
            break
        elif byte == ord("("):
            state = "paren"
        else:
            kept.append(byte)
    return bytes(kept)


@settings(max_examples=300, deadline=None)
@given(_lines(70, 110))
def test_the_marlin_limit_is_marlins_reader(text: str) -> None:
    _, error = interpret_until_error(text, dialect=Dialect.MARLIN)
    truncated = len(_marlin_kept(text.encode("utf-8"))) > 95
    assert (error is not None and "too long" in error.message) == truncated


def test_each_dialect_names_its_line_limit() -> None:
    assert [RULES[d].line_limit for d in Dialect] == [LineLimit.LINUXCNC, LineLimit.GRBL,
                                                      LineLimit.MARLIN]


# --- names in messages ----------------------------------------------------------------------


def test_a_missing_end_names_the_dialects_that_need_none(tmp_path: Path) -> None:
    with pytest.raises(GCodeError) as caught:
        parse_gcode("G0 X1\n")
    assert "--dialect grbl" in caught.value.message
    assert "--dialect marlin" in caught.value.message
    for dialect in (Dialect.GRBL, Dialect.MARLIN):
        assert parse_gcode("G0 X1\n", dialect=dialect).ended_by == "end of text"


@pytest.mark.parametrize("dialect", list(Dialect))
@pytest.mark.parametrize(("line", "name"), [
    ("GET_POSITION", "GET_POSITION"),
    ("SET_VELOCITY_LIMIT VELOCITY=100", "SET_VELOCITY_LIMIT"),
    ("BED_MESH_CALIBRATE", "BED_MESH_CALIBRATE"),
    ("N12 bed_mesh_calibrate ; levelled", "bed_mesh_calibrate"),
    ("PAUSE", "PAUSE"),
])
def test_a_klipper_command_is_refused_by_name(dialect: Dialect, line: str, name: str) -> None:
    with pytest.raises(UnsupportedGCodeError) as caught:
        parse_gcode(f"G21\n{line}\nM2\n", dialect=dialect)
    error = caught.value
    assert error.word == name and error.line == 2 and "Klipper" in error.message
    assert error.message.startswith(f"{name}: a Klipper extended command")
    assert "has no number" not in error.message


def test_words_are_not_taken_for_klipper_commands() -> None:
    program = parse_gcode("G0 X1\nG28 X Y\nM84 X Y\n", machine=HOMED, dialect=Dialect.MARLIN)
    assert len(program.moves) == 2
    with pytest.raises(GCodeError, match="G has no number"):
        parse_gcode("GX1\nM2\n")


def test_marlin_accepts_m17_as_it_does_m18_and_m84() -> None:
    program = parse_gcode("M17\nM17 X Y E\nG1 X1 F100\nM84\n", dialect=Dialect.MARLIN)
    assert [type(move) for move in program.moves] == [Linear]
    meanings = {word.word: word.meaning for word in program.ignored}
    assert meanings["M17"].startswith("enable the motors")
    assert meanings["X"].startswith("parameter of M17")
    with pytest.raises(UnsupportedGCodeError, match="not an M code LinuxCNC knows"):
        parse_gcode("M17\nM2\n")


def test_a_dollar_line_in_linuxcnc_names_the_grbl_dialect() -> None:
    with pytest.raises(GCodeError, match="only the grbl dialect reads"):
        parse_gcode("$H\nM2\n")
    with pytest.raises(GCodeError) as caught:
        parse_gcode("G0 X1 $\nM2\n")
    assert "grbl" not in caught.value.message


# --- usbmotion gcode moves --machine ---------------------------------------------------------


def _moves(*args: str) -> tuple[int, list[dict[str, object]], str]:
    result = CliRunner().invoke(app, ["gcode", "moves", *args])
    records = [json.loads(line) for line in result.stdout.splitlines()]
    return result.exit_code, records, result.stderr


def _machine(tmp_path: Path, *, top: str = "") -> Path:
    """The default machine (Z homing up to machine Z0) in ``tmp_path``, with top-level keys
    added."""
    text = DEFAULT.read_text()
    head, sep, rest = text.partition("\n[axes.X]")
    path = tmp_path / "mill.toml"
    path.write_text(head + "\n" + top + sep + rest)
    return path


def test_gcode_moves_reads_a_program_as_the_machine_runs_it(tmp_path: Path) -> None:
    (tmp_path / "tools.tbl").write_text("T1 P1 Z10.0 D6.0 ;end mill\n")
    (tmp_path / "mill.var").write_text("5221 100\n5222 50\n5210 1\n5211 7\n")
    machine = _machine(tmp_path, top='tool_table = "tools.tbl"\ndialect = "grbl"\n')
    program = tmp_path / "job.nc"
    program.write_text("G0 X1 Y2\nT1 M6\nG43.1 Z10\nG0 Z-50\n")
    code, records, err = _moves(str(program), "-m", str(machine))
    assert code == 0, err
    first, down = records
    # Starts where homing leaves the machine (Z up at machine Z0), in G54 (100, 50),
    # without the parameter file's G92 (grbl keeps none); G43.1 in grbl.
    assert first["start"] == [0.0, 0.0, 0.0] and first["end"] == [101.0, 52.0, 0.0]
    assert down["end"] == [101.0, 52.0, -40.0]
    # The same program read as LinuxCNC reads it: the G92 applies, and no end is refused.
    code, records, err = _moves(str(program), "-m", str(machine), "--dialect", "linuxcnc")
    assert code == 1 and records[0]["end"] == [108.0, 52.0, 0.0]
    assert "--dialect grbl" in err


def test_gcode_moves_on_a_plotter_gives_two_coordinates(tmp_path: Path) -> None:
    program = tmp_path / "circle.ngc"
    program.write_text("G0 X10 Y10\nG2 X10 Y10 I5 F600\nG4 P1\nM2\n")
    code, records, err = _moves(str(program), "--machine", str(PLOTTER))
    assert code == 0, err
    rapid, arc, dwell = records
    assert rapid["end"] == [10.0, 10.0] and arc["centre"] == [15.0, 10.0]
    assert dwell == {"line": 3, "type": "dwell", "seconds": 1.0, "position": [10.0, 10.0]}
    code, _, err = _moves(str(program))
    assert code == 0, err


@pytest.mark.parametrize(("top", "what"), [
    ("oops = 1\n", "oops"),
    ('tool_table = "broken.tbl"\n', "broken.tbl"),
])
def test_gcode_moves_answers_a_bad_machine_in_one_line(tmp_path: Path, top: str,
                                                       what: str) -> None:
    (tmp_path / "broken.tbl").write_text("T1 P1 Zx\n")
    program = tmp_path / "p.ngc"
    program.write_text("G0 X1\nM2\n")
    code, records, err = _moves(str(program), "-m", str(_machine(tmp_path, top=top)))
    assert code == 2 and records == []
    assert err.count("\n") == 1 and err.startswith("usbmotion gcode moves: ") and what in err
    code, _, err = _moves(str(program), "-m", str(tmp_path / "none.toml"))
    assert code == 2 and err.count("\n") == 1 and "none.toml" in err
    code, _, err = _moves(str(program), "--dialect", "klipper")
    assert code == 2 and "--dialect" in err and "linuxcnc, grbl, marlin" in err


def test_gcode_moves_help_says_what_it_prints() -> None:
    result = CliRunner().invoke(app, ["gcode", "moves", "--help"])
    text = " ".join(result.stdout.replace("│", " ").split())
    for phrase in ("position and seconds", "start and end", "Without --machine: axes X Y Z",
                   "--dialect", "starting where homing leaves it"):
        assert phrase in text, phrase
