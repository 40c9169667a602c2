"""Work offsets, tool tables and their files, end to end: the parameter file (LinuxCNC's
``.var`` numbers), the tool table (``tool.tbl``), ``usbmotion run --origin``, ``usbmotion
zero``, the console's ``$z`` and G10 lines, and CAM-style programs on the simulated machine."""

from __future__ import annotations

import json
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Protocol

import pytest
from tests.executed import near_the_switches_text
from typer.testing import CliRunner

from usbmotion.cli.main import app
from usbmotion.cli.run import NO_ORIGIN_HINT, default_machine, parse_origin
from usbmotion.console import Console
from usbmotion.errors import ConfigError, GCodeError
from usbmotion.host.config import load_config
from usbmotion.motion.dialects import Dialect
from usbmotion.motion.gcode import interpret_setting, parse_gcode
from usbmotion.motion.moves import Linear, Rapid
from usbmotion.motion.offsets import (
    NO_OFFSETS,
    format_parameter_file,
    parse_parameter_file,
    read_parameter_file,
    write_parameter_file,
)
from usbmotion.motion.tools import load_tool_table, parse_tool_table
from usbmotion.session import MachineSession
from usbmotion.sim.machine import connect_session

PROGRAMS = Path(__file__).parent / "programs"


def _machine_file(tmp_path: Path, extra: str = "") -> Path:
    """The default machine, with its parameter file (and ``extra`` top-level keys) in tmp,
    its carriages powering up near their switches (these tests home only to begin)."""
    text = near_the_switches_text(default_machine().read_text())
    head, sep, rest = text.partition("\n[axes.X]")
    path = tmp_path / "mill.toml"
    path.write_text(head + "\n" + extra + sep + rest)
    return path


class Doing(Protocol):
    """A line handed to the console (waiting for what it started, unless ``wait=False``)."""

    def __call__(self, line: str, *, wait: bool = True) -> None: ...


@contextmanager
def _console(tmp_path: Path) -> Iterator[tuple[MachineSession, Doing, list[str]]]:
    """A console on the machine of :func:`_machine_file`: its session, a function that hands
    it a line and (unless ``wait=False``) waits for what the line started, and the lines it
    wrote."""
    lines: list[str] = []
    with connect_session(load_config(_machine_file(tmp_path))) as session:
        console = Console(session, lines.append)

        def do(line: str, *, wait: bool = True) -> None:
            console.handle(line)
            assert not wait or console.wait_idle(60)

        try:
            yield session, do, lines
        finally:
            console.close()


def _xyz(x: float, y: float, z: float) -> tuple[float, ...]:
    """A point of the parameter file or the tool table (X Y Z U V W) with U V W at 0."""
    return (x, y, z, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)


# --- the parameter file ----------------------------------------------------------------------


def test_parameter_file_uses_linuxcnc_numbers_and_round_trips(tmp_path: Path) -> None:
    offsets = NO_OFFSETS.with_g5x(1, _xyz(100.0, 100.0, 60.0)).with_g5x(9, _xyz(1.0, 2.0, 3.0))
    path = tmp_path / "m.var"
    write_parameter_file(path, offsets)
    values = dict(line.split("\t") for line in path.read_text().splitlines())
    assert values["5221"] == "100.000000" and values["5223"] == "60.000000"
    assert values["5381"] == "1.000000" and values["5383"] == "3.000000"
    assert values["5220"] == "1.000000" and values["5210"] == "0.000000"
    assert read_parameter_file(path) == offsets
    assert read_parameter_file(tmp_path / "absent.var") == NO_OFFSETS


def test_parameter_file_keeps_numbers_it_does_not_use() -> None:
    offsets = parse_parameter_file("5235 7.5\n5161 1\n31 2.5\n")
    assert offsets.g28 == _xyz(1.0, 0.0, 0.0)
    assert dict(offsets.other) == {31: 2.5, 5235: 7.5}
    assert "31\t2.500000\n" in format_parameter_file(offsets)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("5221\n", "not a parameter line"),
        ("abc 1\n", "'abc' is not a whole number"),
        ("9999 1\n", "out of range; allowed: 1..5602"),
        ("5221 x\n", "value 'x' is not a number"),
        ("5221 1\n5221 2\n", "given twice (also line 1)"),
        ("5220 10\n", "allowed: 1 (G54) to 9 (G59.3)"),
        ("5210 0.5\n", "allowed: 0 or 1"),
    ],
)
def test_a_malformed_parameter_file_is_refused_naming_the_line(text: str, message: str) -> None:
    with pytest.raises(ConfigError) as info:
        parse_parameter_file(text, path="m.var")
    assert message in str(info.value) and str(info.value).startswith("m.var:")


def test_offsets_from_a_parameter_file_apply_and_a_program_leaves_its_own() -> None:
    start = parse_parameter_file("5220 2\n5241 10\n5242 20\n5210 1\n5211 1\n5163 7\n")
    program = parse_gcode("G0 X0 Y0\nG28.1\nG10 L2 P1 Z-5\nM2\n", offsets=start)
    assert program.moves[0].end == (11.0, 20.0, 0.0)  # G55 + G92
    assert program.offsets.g28 == _xyz(11.0, 20.0, 0.0)
    assert program.offsets.g5x[0] == _xyz(0.0, 0.0, -5.0)
    assert program.offsets.coordinate_system == 1  # M2 goes back to G54, as LinuxCNC


# --- the tool table --------------------------------------------------------------------------


def test_tool_table_reads_linuxcnc_lines() -> None:
    table = parse_tool_table("T1 P1 Z12.5 D6 ;end mill\nt2 p3 x1 z-2.5 d3 a0\n\n;only a note\n")
    assert table.tools[1].offset_mm == _xyz(0.0, 0.0, 12.5) and table.tools[1].comment == "end mill"
    assert table.tools[2].pocket == 3 and table.tools[2].offset_mm == _xyz(1.0, 0.0, -2.5)
    inch = parse_tool_table("T1 P1 Z0.5\n", mm_per_unit=25.4)
    assert inch.tools[1].offset_mm == _xyz(0.0, 0.0, 12.7)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("P1 Z1\n", "needs T"),
        ("T1 P1 K1\n", "unknown word K1"),
        ("T1 Z1 Z2\n", "Z appears twice"),
        ("T1.5 Z1\n", "T1.5: a tool number is a whole number >= 1"),
        ("T1 Z1\nT1 Z2\n", "T1 is listed twice (also line 1)"),
        ("T1 A5\n", "offsets the rotary axis A"),
        ("T1 Z1 #\n", "unexpected '#'"),
    ],
)
def test_a_malformed_tool_table_is_refused_naming_the_line(text: str, message: str) -> None:
    with pytest.raises(ConfigError) as info:
        parse_tool_table(text, path="t.tbl")
    assert message in str(info.value) and str(info.value).startswith("t.tbl:")


def test_a_missing_table_gives_every_tool_zero_length(tmp_path: Path) -> None:
    program = parse_gcode("T7 M6 G43\nG0 Z1\nG43 H3\nG0 Z2\nM2\n",
                          tools=load_tool_table(tmp_path / "none.tbl"))
    assert [m.end[2] for m in program.moves] == [1.0, 2.0]


def test_a_tool_not_in_the_table_is_refused_naming_the_table() -> None:
    table = parse_tool_table("T1 P1 Z10\n", path="t.tbl")
    with pytest.raises(GCodeError) as info:
        parse_gcode("G0 Z0\nG43 H2\nM2\n", tools=table)
    assert info.value.line == 2 and "tool 2 is not in the tool table t.tbl (T1)" in str(info.value)
    with pytest.raises(GCodeError) as info:
        parse_gcode("T3 M6\nM2\n", tools=table)
    assert info.value.word == "T3"


def test_m6_selects_the_tool_and_g43_applies_it() -> None:
    table = parse_tool_table("T1 P4 Z10\nT2 P5 Z20\n")
    program = parse_gcode("T2\nG0 X0 Y0 Z0\nM6\nG43\nG0 Z0\nM2\n", tools=table)
    assert program.tool_changes[0].tool == 2 and program.tool_changes[0].pocket == 5
    assert program.moves[-1].end == (0.0, 0.0, 20.0)


# --- G-code errors for the new words -----------------------------------------------------------


@pytest.mark.parametrize(
    ("text", "word", "message"),
    [
        ("G10 P1 X1\n", "G10", "G10 needs L"),
        ("G10 L2 X1\n", "G10", "needs P, the coordinate system"),
        ("G10 L2 P10 X1\n", "P10", "P10: the coordinate system is 0"),
        ("G10 L20 P1 X1 R5\n", "R5", "G10 L20 takes no R"),
        ("G53 G2 X1 I1 F1\n", "G53", "G0 or G1 only"),
        ("G91 G53 G0 X1\n", "G53", "cannot be used with incremental"),
        ("G0 Z5\nG81 X1 Y1 R1 F10\n", "G81", "G81 needs Z, the bottom of the hole"),
        ("G0 Z5\nG83 X1 Y1 Z-1 R1 F10\n", "G83", "G83 needs Q, the peck depth"),
        ("G0 Z5\nG83 X1 Z-1 R1 Q0 F10\n", "Q0", "the peck depth is greater than 0"),
        ("G0 Z5\nG81 X1 Z-1 R1 L0 F10\n", "L0", "L, the number of holes, is a whole number"),
        ("G0 Z5\nG81 X1 Z-1 R1\n", "G81", "feed rate 0"),
        ("G0 X1 L2\n", "L2", "L word with no G10 or canned cycle"),
        ("G0 Z5\nG83 X1 Z-1000 R1 Q0.001 F10\n", "G83", "at most 100,000 pecks"),
        ("G0 Z5\nG81 X1 Z-1 R1 L1000000 F10\n", "G81", "would make 1000000 hole(s)"),
        ("G43 H1.5\n", "H1.5", "H is a tool number"),
    ],
)
def test_bad_offset_tool_and_cycle_words_are_refused(text: str, word: str,
                                                      message: str) -> None:
    with pytest.raises(GCodeError) as info:
        parse_gcode(text + "M2\n")
    assert info.value.word == word and message in info.value.message, info.value


def test_interpret_setting_sets_offsets_and_refuses_moves() -> None:
    offsets = interpret_setting("G10 L20 P1 X0 Y0", start=(30.0, 40.0, 10.0))
    assert offsets.g5x[0] == _xyz(30.0, 40.0, 0.0)
    with pytest.raises(GCodeError) as info:
        interpret_setting("X1", start=(0.0, 0.0, 0.0))
    assert "axis word with no motion mode" in info.value.message
    with pytest.raises(GCodeError) as info:
        interpret_setting("G1 X1 F100", start=(0.0, 0.0, 0.0))
    assert "would move the machine" in info.value.message


# --- the command line and the console --------------------------------------------------------


def test_an_origin_is_set_by_any_offset_that_moves_a_program() -> None:
    from dataclasses import replace  # noqa: PLC0415

    assert not NO_OFFSETS.origin_set
    assert NO_OFFSETS.with_g5x(3, _xyz(0.0, 0.0, -40.0)).origin_set, "G56's Z"
    rotated = list(NO_OFFSETS.rotation_deg)
    rotated[0] = 15.0
    assert replace(NO_OFFSETS, rotation_deg=tuple(rotated)).origin_set
    shifted = replace(NO_OFFSETS, g92=_xyz(1.0, 0.0, 0.0))
    assert not shifted.origin_set, "a G92 offset not in force"
    assert replace(shifted, g92_enabled=True).origin_set
    assert not replace(NO_OFFSETS, g28=_xyz(5.0, 5.0, 5.0)).origin_set, "G28's position"


def test_parse_origin_reads_axis_words() -> None:
    assert parse_origin(["X100 Y100", "Z60"]) == {"X": 100.0, "Y": 100.0, "Z": 60.0}
    assert parse_origin(["x-1.5y2"]) == {"X": -1.5, "Y": 2.0}


@pytest.mark.parametrize("value", ["X100 Q1", "100", "X1 X2", ""])
def test_parse_origin_refuses_what_is_not_an_origin(value: str) -> None:
    import typer  # noqa: PLC0415

    with pytest.raises(typer.BadParameter):
        parse_origin([value])


def test_a_cam_program_runs_after_origin_and_is_refused_without(tmp_path: Path) -> None:
    """A grbl job with its origin at the stock's top corner (Z +5 to -3 mm, no M2): with
    G54 at machine zero its clearance (Z5) is above the top of Z's travel."""
    machine = _machine_file(tmp_path)
    program = PROGRAMS / "cam_corner.ngc"
    text = program.read_text()
    assert "M2" not in text and "M30" not in text and "%" not in text
    runner = CliRunner()
    base = ["run", str(program), "--machine", str(machine), "--no-plot", "--quiet"]
    unended = runner.invoke(app, base)  # read as LinuxCNC reads it, it lacks its end
    assert unended.exit_code == 2 and "ends without M2, M30" in unended.output, unended.output
    refused = runner.invoke(app, [*base, "--dialect", "grbl"])
    assert refused.exit_code == 2, refused.output
    assert f"{program}:8: Z would reach 5.000 mm, beyond the upper end 0 mm of axis Z's" in (
        refused.output), refused.output  # the clearance, G0 Z5, above the top of Z
    assert "nothing was moved" in refused.output, refused.output
    assert NO_ORIGIN_HINT in refused.output, "no origin set: how to set one"
    assert not (tmp_path / "mill.var").exists()
    report = tmp_path / "cam.json"
    done = runner.invoke(app, [*base, "--dialect", "grbl", "--origin", "X100 Y100 Z-40",
                               "--report", str(report)])
    assert done.exit_code == 0, done.output
    assert read_parameter_file(tmp_path / "mill.var").g5x[0] == _xyz(100.0, 100.0, -40.0)
    figures = json.loads(report.read_text())
    assert figures["completed"] is True, figures
    assert figures["end_position_mm"]["Z"] == pytest.approx(-35.0, abs=0.02), "G0 Z5 at the end"
    assert figures["notes"] == [], "no rapid into the stock"
    far = tmp_path / "far.ngc"
    far.write_text("G21 G90\nG0 X500\nM2\n")
    beyond = runner.invoke(app, ["run", str(far), "--machine", str(machine), "--no-plot",
                                 "--quiet"])
    assert beyond.exit_code == 2 and f"{far}:2: X would reach 600.000 mm" in beyond.output, (
        beyond.output)
    assert "hint" not in beyond.output, "an origin is set: no hint to set one"


def test_a_rapid_into_the_stock_is_reported_and_the_program_still_runs(tmp_path: Path) -> None:
    """cam_corner.ngc with its plunge as a G0: a report, not a refusal."""
    machine = _machine_file(tmp_path)
    report = tmp_path / "plunge.json"
    done = CliRunner().invoke(app, [
        "run", str(PROGRAMS / "cam_rapid_plunge.ngc"), "--machine", str(machine), "--no-plot",
        "--quiet", "--dialect", "grbl", "--origin", "X100 Y100 Z-40", "--report", str(report)])
    assert done.exit_code == 0, done.output
    figures = json.loads(report.read_text())
    assert figures["completed"] is True
    warning = ("line 10: a rapid reaches work Z -3.000 mm, below work Z0, at machine X 102.000"
               " Y 102.000 mm, inside the stock's XY extent X 102.000..120.000 Y 102.000..120.000"
               " mm (where the program cuts at or below work Z0): it would plunge into the stock"
               " at rapid speed")
    assert figures["notes"] == [warning]
    assert f"note           {warning}" in done.output


def test_a_fusion_style_program_with_tools_offsets_and_cycles_runs_to_the_end(
    tmp_path: Path,
) -> None:
    (tmp_path / "mill.tbl").write_text((PROGRAMS / "fusion_mill.tbl").read_text())
    machine = _machine_file(tmp_path, 'tool_table = "mill.tbl"\n')
    offsets = NO_OFFSETS.with_g5x(1, _xyz(50.0, 50.0, -60.0)).with_g5x(
        2, _xyz(120.0, 50.0, -60.0))
    write_parameter_file(tmp_path / "mill.var", offsets)
    config = load_config(machine)
    assert config.tool_table == tmp_path / "mill.tbl"
    with connect_session(config) as session:
        session.home()
        prepared = session.prepare(PROGRAMS / "fusion_mill.ngc")
        moves = prepared.program.moves
        assert [c.tool for c in prepared.program.tool_changes] == [1, 2]
        # T1 in G54: the cut at Z-1 is -60 + 20 - 1 mm in machine Z; the drill in G55.
        assert any(isinstance(m, Linear) and m.end == (90.0, 60.0, -41.0) for m in moves)
        assert any(isinstance(m, Linear) and m.end == (125.0, 55.0, -34.0) for m in moves)
        assert any(isinstance(m, Linear) and m.end == (145.0, 55.0, -36.0) for m in moves)
        assert any(isinstance(m, Rapid) and m.end[2] == 0.0 for m in moves), "G53 G0 Z0"
        assert prepared.warnings == (), "its pecks go back into their holes: no plunge"
        report, _ = session.run(prepared)
    assert report.completed, report.stop_reason


def test_a_completed_program_keeps_its_offsets_for_the_next_run(tmp_path: Path) -> None:
    config = load_config(_machine_file(tmp_path))
    program = tmp_path / "set.ngc"
    program.write_text("G10 L2 P1 X5 Y6 Z-7\nG0 X0 Y0 Z0\nM2\n")
    with connect_session(config) as session:
        session.home()
        report, _ = session.run(session.prepare(program))
        assert report.completed
        assert read_parameter_file(config.parameter_path).g5x[0] == _xyz(5.0, 6.0, -7.0)
        again = tmp_path / "again.ngc"
        again.write_text("G0 X1 Y1 Z1\nM2\n")
        assert session.prepare(again).program.moves[0].end == (6.0, 7.0, -6.0)


def test_a_jobs_g92_does_not_shift_the_next_job(tmp_path: Path) -> None:
    """A completed run leaves its G92 suspended in the parameter file (LinuxCNC's numbers:
    5210 0, the values kept for a G92.3), so the next job runs where it is written; a grbl
    job's G92 never reaches the file."""
    config = load_config(_machine_file(tmp_path))
    shifted = tmp_path / "shift.ngc"
    shifted.write_text("G0 X3 Y3\nG92 X0 Y0\nG0 X1 Y1\nM2\n")
    plain = tmp_path / "plain.ngc"
    plain.write_text("G0 X1 Y1\nM2\n")
    with connect_session(config) as session:
        session.home()
        report, _ = session.run(session.prepare(shifted))
        assert report.completed and session.positions_mm()["X"] == pytest.approx(4.0, abs=0.01)
        stored = read_parameter_file(config.parameter_path)
        assert stored.g92 == _xyz(3.0, 3.0, 0.0) and stored.g92_enabled is False
        assert "5210\t0.000000" in config.parameter_path.read_text()
        assert session.prepare(plain).program.moves[0].end == (1.0, 1.0, 0.0)
        grbl = tmp_path / "grbl.nc"
        grbl.write_text("G92 X0\nG0 X2\n")
        prepared = session.prepare(grbl, dialect=Dialect.GRBL)
        assert prepared.program.moves[0].end == (6.0, 4.0, 0.0)  # from X4: G92 X-4
        report, _ = session.run(prepared)
        assert report.completed
        assert read_parameter_file(config.parameter_path) == stored


def test_zero_and_g10_from_the_console_set_g54_where_the_machine_stands(
    tmp_path: Path,
) -> None:
    with _console(tmp_path) as (session, do, lines):
        config = session.config
        do("$z")
        assert lines[-1].startswith("error: the machine is not homed")
        session.home()
        where = session.positions_mm()
        do("$z X Y")
        offsets = read_parameter_file(config.parameter_path)
        assert offsets.g5x[0][:2] == (where["X"], where["Y"]), lines
        do("G10 L20 P1 Z10")
        offsets = read_parameter_file(config.parameter_path)
        assert offsets.g5x[0][2] == pytest.approx(where["Z"] - 10.0), lines
        do("G0 X1 Y1 Z1")
        assert lines[-1] == "ok", "a line that moves is MDI"
        assert session.positions_mm() == pytest.approx(
            {"X": where["X"] + 1, "Y": where["Y"] + 1, "Z": where["Z"] - 9}), "in G54"
        do("$z Q")
        assert "takes axes X, Y, Z" in lines[-1]


def test_usbmotion_zero_sets_g54_at_the_homed_position(tmp_path: Path) -> None:
    machine = _machine_file(tmp_path)
    result = CliRunner().invoke(app, ["zero", "X", "Z", "--machine", str(machine)])
    assert result.exit_code == 0, result.output
    assert "saved in" in result.output
    offsets = read_parameter_file(tmp_path / "mill.var")
    assert offsets.g5x[0] == _xyz(0.0, 0.0, 0.0)  # homing leaves the default machine at 0
    bad = CliRunner().invoke(app, ["zero", "Q", "--machine", str(machine)])
    assert bad.exit_code == 2


def test_machine_file_keys_for_the_tool_table_and_parameter_file(tmp_path: Path) -> None:
    config = load_config(_machine_file(tmp_path, 'parameter_file = "state/m.var"\n'))
    assert config.parameter_path == tmp_path / "state" / "m.var"
    assert load_config(_machine_file(tmp_path)).parameter_path == tmp_path / "mill.var"
    with pytest.raises(ConfigError) as info:
        load_config(_machine_file(tmp_path, "tool_table = 5\n"))
    assert "tool_table" in str(info.value) and "not a file name" in str(info.value)
    assert info.value.line is not None


def test_the_console_holds_the_lines_typed_while_it_homes_and_runs_them_in_order(
    tmp_path: Path,
) -> None:
    """As grbl holds the lines after its ``$H``: lines handed in at once after ``$H`` (a
    script piped in) run once the homing has ended, in order (a jog between two lines runs
    between them); a stop drops those held."""
    with _console(tmp_path) as (session, do, lines):
        for line in ("$H", "G90 G0 X5", "$j X1 F600", "G91 G0 X1"):
            do(line, wait=False)
        do("G0 Y2")
        assert lines[0].startswith("homed in "), lines
        assert lines[1:] == ["ok", "jogged: X 6.000  Y 0.000  Z 0.000 mm", "ok", "ok"], lines
        where = session.positions_mm()
        assert (where["X"], where["Y"]) == pytest.approx((7.0, 2.0), abs=0.01), where
        lines.clear()
        do("$H", wait=False)
        do("G0 X9", wait=False)
        do("$x")
        assert "dropped 1 line held for the homing" in lines, lines
        assert "ok" not in lines
        assert session.positions_mm()["X"] != pytest.approx(15.0, abs=0.01)


def test_the_console_homes_with_dollar_h_and_says_how_when_a_line_needs_it(
    tmp_path: Path,
) -> None:
    """A line of G-code before homing is refused with the way to home (``$H``, as grbl
    spells it; ``$h`` stays the help); ``$H`` homes every axis, then the line runs."""
    with _console(tmp_path) as (session, do, lines):
        do("G0 X1")
        assert lines[-1] == "error: the machine is not homed: home it first; $H homes it"
        do("$z")
        assert lines[-1].endswith("$H homes it")
        do("$h")
        assert any(line.startswith("$H ") for line in lines[-1].splitlines())
        do("$H")
        assert lines[-1].startswith("homed in ") and session.is_homed, lines[-3:]
        where = session.positions_mm()
        do("G91 G0 X1")
        assert lines[-1] == "ok"
        assert session.positions_mm()["X"] == pytest.approx(where["X"] + 1)
