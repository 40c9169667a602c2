"""G-code as other controllers write it, on machines of any set of linear axes: LinuxCNC's
line length (grbl's and Marlin's: ``tests/test_gcode_rules.py``), the grbl and Marlin
dialects, plotters (X and Y only) and six-axis machines, and the programs of
tests/programs run to their end on simulated machines."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from usbmotion.cli.main import app
from usbmotion.errors import ConfigError, GCodeError, UnsupportedGCodeError
from usbmotion.host.config import DIALECTS, load_config, parse_config
from usbmotion.motion.dialects import Declared, Dialect, declared_dialect, dialect_named
from usbmotion.motion.gcode import (
    MachineAxes,
    distinct_ignored,
    interpret_until_error,
    move_record,
    parse_gcode,
)
from usbmotion.motion.limits import AxisLimits, PlannerConfig
from usbmotion.motion.moves import Arc, Dwell, Linear, Plane, Rapid
from usbmotion.motion.planner import plan_moves
from usbmotion.motion.sampler import sample_plan
from usbmotion.session.planning import machine_axes, plan_gcode, program_axes

ROOT = Path(__file__).resolve().parent.parent
PROGRAMS = ROOT / "tests" / "programs"
PLOTTER = ROOT / "examples" / "plotter.toml"
DEFAULT = ROOT / "src" / "usbmotion" / "data" / "machine.toml"
XY = MachineAxes(axes="XY")
HOMED_XYZ = MachineAxes(axes="XYZ", home_mm=(1.0, 2.0, 90.0), homing_order=("Z", "XY"))


# --- LinuxCNC's line length ---------------------------------------------------------------


def _line(length: int) -> str:
    """A valid G-code line of exactly ``length`` characters (a move and a comment)."""
    head = "G0 X1 ("
    return head + "c" * (length - len(head) - 1) + ")"


@pytest.mark.parametrize(("length", "ending", "last", "accepted"), [
    (252, "\n", False, True),
    (253, "\n", False, False),
    (251, "\r\n", False, True),
    (252, "\r\n", False, False),
    (253, "", True, True),
    (254, "", True, False),
])
def test_lines_as_long_as_linuxcnc_reads_them(length: int, ending: str, last: bool,
                                              accepted: bool) -> None:
    line = _line(length)
    assert len(line) == length
    text = f"G21{ending or chr(10)}{line}{ending}" + ("" if last else f"M2{ending}")
    if last:
        end = "M2   " + line[len("G0 X1"):]  # the last line ends the program, with no break
        assert len(end) == length
        program, error = interpret_until_error(f"G21\n{end}")
        if accepted:
            assert error is None and program.ended_by == "M2" and program.end_line == 2
        else:
            assert isinstance(error, GCodeError) and error.line == 2
            assert f"{length} bytes" in error.message and "at most 253" in error.message
        return
    if accepted:
        assert len(parse_gcode(text).moves) == 1
    else:
        with pytest.raises(GCodeError) as caught:
            parse_gcode(text)
        assert caught.value.line == 2
        longest = 252 if ending == "\n" else 251
        assert f"line too long: {length} bytes" in caught.value.message
        assert f"at most {longest} bytes" in caught.value.message
        assert "LINELEN" in caught.value.message


def test_a_long_line_counts_its_bytes_not_its_characters() -> None:
    line = "G0 X1 (" + "\u00e9" * 126 + ")"  # 134 characters, 260 bytes in UTF-8
    with pytest.raises(GCodeError, match="line too long: 260 bytes"):
        parse_gcode(f"{line}\nM2\n")


# --- any set of linear axes ---------------------------------------------------------------


def test_a_plotter_program_moves_x_and_y_only() -> None:
    program = parse_gcode((PROGRAMS / "plotter.ngc").read_text(), machine=XY)
    assert program.axes == "XY" and program.ended_by == "M2"
    assert all(len(move.end) == 2 for move in program.moves if not isinstance(move, Dwell))
    arcs = [move for move in program.moves if isinstance(move, Arc)]
    assert len(arcs) == 5 and all(arc.plane is Plane.XY for arc in arcs)
    full = arcs[-1]
    assert full.start == full.end == (20.0, 12.0) and full.centre == (20.0, 20.0)
    record = move_record(full, axes="XY")
    assert record["centre"] == [20.0, 20.0] and record["plane"] == "XY"


@pytest.mark.parametrize(("text", "word", "axis"), [
    ("G0 X1 Z5\nM2\n", "Z5", "Z"),
    ("G1 U2 F100\nM2\n", "U2", "U"),
    ("G92 W0\nM2\n", "W0", "W"),
])
def test_a_word_for_an_axis_the_machine_lacks_is_refused_naming_it(text: str, word: str,
                                                                   axis: str) -> None:
    with pytest.raises(UnsupportedGCodeError) as caught:
        parse_gcode(text, machine=XY)
    assert caught.value.word == word and caught.value.line == 1
    assert f"the machine has no axis {axis} (its axes are X, Y)" in caught.value.message


@pytest.mark.parametrize(("plane", "missing"), [("G18", "Z"), ("G19", "Z")])
def test_an_arc_needs_both_axes_of_its_plane(plane: str, missing: str) -> None:
    with pytest.raises(UnsupportedGCodeError) as caught:
        parse_gcode(f"{plane}\nG2 X10 I5 F100\nM2\n", machine=XY)
    assert caught.value.line == 2 and caught.value.word == "G2"
    assert f"the machine has no axis {missing}" in caught.value.message
    assert f"plane (G{plane[1:]})" in caught.value.message
    # The same arc in G17 runs: X and Y are the plane.
    parse_gcode("G17\nG2 X10 I5 F100\nM2\n", machine=XY)


def test_an_xz_machine_takes_g18_arcs_with_no_helix() -> None:
    program = parse_gcode("G18 G1 X5 Z0 F100\nG3 X15 Z0 I5 K0\nM2\n",
                          machine=MachineAxes(axes="XZ"))
    arc = program.moves[-1]
    assert isinstance(arc, Arc) and arc.centre == (10.0, 0.0) and arc.end == (15.0, 0.0)
    plan = plan_moves(program.moves, [AxisLimits(20, 500)] * 2, PlannerConfig(), axes="XZ")
    # A half circle of radius 5 about X 10: its chords reach 5 mm from Z 0.
    assert abs(plan.vertices_mm[:, 1]).max() == pytest.approx(5.0, abs=1e-3)
    assert plan.vertices_mm.shape[1] == 2


def test_six_axes_interpret_plan_and_sample() -> None:
    axes = MachineAxes(axes="XYZUVW")
    program = parse_gcode("G1 X1 Y2 Z3 U4 V5 W6 F600\nG91 G0 U-4 W1\n"
                          "G90 G17 G2 X3 Y2 I1 V7\nM2\n", machine=axes)
    assert program.moves[0].end == (1.0, 2.0, 3.0, 4.0, 5.0, 6.0)
    assert program.moves[1].end == (1.0, 2.0, 3.0, 0.0, 5.0, 7.0)
    plan = plan_moves(program.moves, [AxisLimits(20, 500)] * 6, PlannerConfig(),
                      axes="XYZUVW")
    setpoints = sample_plan(plan, period_s=0.001, counts_per_mm=[100.0] * 6)
    assert setpoints.shape[1] == 6
    assert setpoints[-1].tolist() == [300, 200, 300, 0, 700, 700]
    # V moves linearly along the arc: in proportion to the angle swept from X1 Y2.
    ends = plan.vertices_mm[1:][plan.line == 3]
    swept = (math.pi - np.arctan2(ends[:, 1] - 2.0, ends[:, 0] - 2.0)) / math.pi
    assert len(ends) > 10
    assert ends[:, 4] == pytest.approx(5.0 + 2.0 * swept, abs=1e-9)
    # Every axis within its own limits: the fastest single-axis speed is 20 mm/s.
    steps = abs(setpoints[1:].astype(float) - setpoints[:-1]) / 100.0 / 0.001
    assert steps.max() <= 20.0 + 1.0


def test_the_default_axes_are_unchanged() -> None:
    moves = parse_gcode("G1 X1 Y2 Z3 F100\nM2\n").moves
    assert moves == (Linear(1, (0.0, 0.0, 0.0), (1.0, 2.0, 3.0), 100.0),)


def test_machine_axes_refuse_what_is_not_an_axis_set() -> None:
    for bad in ("", "YX", "XXY", "XQ", "AX"):
        with pytest.raises(ValueError, match="one to nine of 'XYZABCUVW'"):
            MachineAxes(axes=bad)


# --- grbl ---------------------------------------------------------------------------------


def test_grbl_starts_in_g0_needs_no_end_and_homes_with_dollar_h() -> None:
    program = parse_gcode("G1 X5 Y5 F100\n$H\nX3 Y4\n", machine=HOMED_XYZ,
                          dialect=Dialect.GRBL)
    line, z_first, xy = program.moves[0:3]
    # $H: Z to its home first, then X and Y together, as the machine's homing order.
    assert isinstance(z_first, Rapid) and z_first.end == (5.0, 5.0, 90.0)
    assert isinstance(xy, Rapid) and xy.end == (1.0, 2.0, 90.0)
    assert line.line == 1 and z_first.line == xy.line == 2
    assert program.ended_by == "end of text" and program.end_line == 3
    # Before any G1 a bare axis line is a rapid (grbl's power-on G0).
    first = parse_gcode("X3 Y4\n", dialect=Dialect.GRBL).moves[0]
    assert isinstance(first, Rapid)


def test_grbl_homes_one_axis_and_refuses_others_by_name() -> None:
    moves = parse_gcode("G0 X5 Y5 Z5\n$HX\n", machine=HOMED_XYZ, dialect=Dialect.GRBL).moves
    assert moves[-1].end == (1.0, 5.0, 5.0)
    for command, name in (("$X", "alarm unlock ($X)"), ("$$", "settings listing ($$)"),
                          ("$J=G91 X1 F100", "a jog ($J=)"), ("$110=500", "a grbl setting"),
                          ("$SLP", "sleep mode ($SLP)")):
        with pytest.raises(UnsupportedGCodeError) as caught:
            parse_gcode(f"G21\n{command}\n", dialect=Dialect.GRBL)
        assert name in caught.value.message and caught.value.line == 2
    with pytest.raises(UnsupportedGCodeError, match="has no axis Z"):
        parse_gcode("$HZ\n", machine=XY, dialect=Dialect.GRBL)


def test_dollar_lines_and_a_missing_end_stay_errors_in_linuxcnc() -> None:
    with pytest.raises(GCodeError, match="unexpected character '\\$'"):
        parse_gcode("$H\nM2\n")
    with pytest.raises(GCodeError, match="ends without M2"):
        parse_gcode("G0 X1\n")


def test_grbl_dwell_is_seconds_and_laser_words_are_ignored_with_their_meaning() -> None:
    program = parse_gcode("G4 P0.5\nM4 S300\nG1 X1 F100 S800\nM5\n", dialect=Dialect.GRBL)
    assert program.moves[0] == Dwell(1, (0.0, 0.0, 0.0), 0.5)
    meanings = {word.word: word.meaning for word in program.ignored}
    assert "laser on with power scaled" in meanings["M4"]
    assert meanings["S800"] == "spindle speed or laser power"


# --- Marlin -------------------------------------------------------------------------------


def test_marlin_dwells_in_milliseconds_or_seconds() -> None:
    moves = parse_gcode("G4 P250\nG4 S2\n", dialect=Dialect.MARLIN).moves
    assert [move.seconds for move in moves if isinstance(move, Dwell)] == [0.25, 2.0]
    with pytest.raises(GCodeError, match="G4 needs P, the dwell time in milliseconds, or S"):
        parse_gcode("G4\n", dialect=Dialect.MARLIN)
    with pytest.raises(GCodeError, match="both P and S"):
        parse_gcode("G4 P1 S1\n", dialect=Dialect.MARLIN)


def test_marlin_g28_homes_the_named_axes_or_all() -> None:
    moves = parse_gcode("G0 X5 Y6 Z7\nG28 X Y\nG28\n", machine=HOMED_XYZ,
                        dialect=Dialect.MARLIN).moves
    assert moves[1].end == (1.0, 2.0, 7.0)  # X and Y only
    assert moves[2].end == (1.0, 2.0, 90.0)  # then Z: every axis
    # In LinuxCNC G28 goes to the stored position (0 here), through the point named.
    linuxcnc = parse_gcode("G0 X5 Y6 Z7\nG28 X3\nM2\n").moves
    assert [move.end for move in linuxcnc[1:]] == [(3.0, 6.0, 7.0), (0.0, 6.0, 7.0)]


def test_marlin_parameters_are_not_moves_and_extruder_words_are_ignored() -> None:
    program = parse_gcode("M201 X500 Y500 Z100 E5000\nG92 E0\nG1 X10 E1.5 F600\nM84 X Y E\n",
                          dialect=Dialect.MARLIN)
    assert [type(move) for move in program.moves] == [Linear]
    kinds = {word.kind: count for word, count in distinct_ignored(program.ignored)}
    extruder = ("E", "extruder position (no extruder)")
    assert kinds[extruder] == 2  # G92 E0 and E1.5
    assert kinds[("M201", "maximum accelerations (the machine file sets them)")] == 1
    assert sorted(letter for letter, meaning in kinds if "of M201" in meaning) == list("EXYZ")
    assert sorted(letter for letter, meaning in kinds if "of M84" in meaning) == list("EXY")
    meanings = {word.word: word.meaning for word in program.ignored}
    assert meanings["X500"].startswith("parameter of M201: maximum accelerations")
    assert meanings["E1.5"] == "extruder position (no extruder)"


def test_marlin_messages_hold_any_text() -> None:
    program = parse_gcode("M117 G28 X1 now (hot)\nG0 X2\n", dialect=Dialect.MARLIN)
    assert [move.end for move in program.moves] == [(2.0, 0.0, 0.0)]


@pytest.mark.parametrize(("text", "reason"), [
    ("G29\n", "bed levelling (G29) changes the geometry"),
    ("G10\n", "firmware retraction (G10)"),
    ("M48\n", "not an M code of the marlin dialect"),
    ("M999\n", "not an M code of the marlin dialect"),
])
def test_marlin_refuses_what_would_change_the_geometry(text: str, reason: str) -> None:
    with pytest.raises(UnsupportedGCodeError, match=reason.replace("(", "\\(").replace(
            ")", "\\)")):
        parse_gcode(text, dialect=Dialect.MARLIN)


def test_e_words_are_refused_in_linuxcnc() -> None:
    with pytest.raises(UnsupportedGCodeError, match="E words"):
        parse_gcode("G1 X1 E2 F100\nM2\n")


# --- machine files ------------------------------------------------------------------------


def test_the_dialect_names_agree() -> None:
    assert tuple(dialect.value for dialect in Dialect) == DIALECTS
    with pytest.raises(ValueError, match="'klipper' is not one of linuxcnc, grbl, marlin"):
        dialect_named("klipper")


@pytest.mark.parametrize(("text", "declared"), [
    (";FLAVOR:Marlin\nG1 X1\n", Declared(Dialect.MARLIN, 1, ";FLAVOR:Marlin")),
    ("G1 X1\n; gcode_flavor = marlin2\n",
     Declared(Dialect.MARLIN, 2, "; gcode_flavor = marlin2")),
    ("; LightBurn 1.4.03\n; GRBL device profile, absolute coords\nG0 X1\n",
     Declared(Dialect.GRBL, 2, "; GRBL device profile, absolute coords")),
    (";FLAVOR:RepRap\nG1 X1\n", None),  # RepRapFirmware's reading is none of ours
    ("G1 X1 (FLAVOR:Marlin)\n; say FLAVOR:Marlin\n", None),  # not the writer's header
])
def test_a_program_says_which_dialect_it_was_written_for(text: str,
                                                         declared: Declared | None) -> None:
    assert declared_dialect(text) == declared


def test_a_program_that_does_not_read_is_told_the_dialect_it_names(tmp_path: Path) -> None:
    """A slicer's file read as LinuxCNC reads G-code fails at its first Marlin code: the
    error names the dialect its header names, and how to read it so."""
    runner = CliRunner()
    slicer = PROGRAMS / "slicer.gcode"
    done = runner.invoke(app, ["run", str(slicer), "--no-plot", "-q"])
    assert done.exit_code == 2, done.output
    assert f"{slicer}:6: M73" in done.output, done.output
    hint = ("hint: the program says it was written for marlin (';FLAVOR:Marlin', line 2), and"
            " was read as linuxcnc reads G-code: read it with --dialect marlin")
    assert hint in done.output, done.output
    moves = runner.invoke(app, ["gcode", "moves", str(slicer)])
    assert moves.exit_code == 1 and hint in moves.output, moves.output
    laser = tmp_path / "lightburn.nc"
    laser.write_text("; LightBurn 1.4.03\n; GRBL device profile, absolute coords\n"
                     + (PROGRAMS / "laser.nc").read_text())
    refused = runner.invoke(app, ["run", str(laser), "--no-plot", "-q", "--dialect", "marlin"])
    assert refused.exit_code == 2, refused.output
    assert ("written for grbl ('; GRBL device profile, absolute coords', line 2), and was read"
            " as marlin reads G-code: read it with --dialect grbl") in refused.output, (
        refused.output)
    unhinted = runner.invoke(app, ["gcode", "moves", str(PROGRAMS / "laser.nc")])
    assert unhinted.exit_code == 1 and "hint" not in unhinted.output, "it names no dialect"


def test_a_machine_file_names_its_dialect(tmp_path: Path) -> None:
    text = PLOTTER.read_text().replace('name = "simulated XY plotter"',
                                       'name = "plotter"\ndialect = "grbl"')
    assert parse_config(text).dialect == "grbl"
    assert load_config(DEFAULT).dialect == "linuxcnc"
    bad = text.replace('dialect = "grbl"', 'dialect = "Grbl"')
    with pytest.raises(ConfigError) as caught:
        parse_config(bad, path=tmp_path / "m.toml")
    message = str(caught.value)
    assert "dialect" in message and "'Grbl' is not a G-code dialect" in message
    assert "allowed: 'linuxcnc', 'grbl', 'marlin'" in message and ":12" in message


def test_a_machine_of_u_v_w_axes_plans_them(tmp_path: Path) -> None:
    text = DEFAULT.read_text()
    for old, new in (("X", "U"), ("Y", "V"), ("Z", "W")):
        text = text.replace(f"[axes.{old}]", f"[axes.{new}]").replace(
            f'"sim://{old}"', f'"sim://{new}"').replace(f'"{old} AXIS"', f'"{new} AXIS"')
    text = text.replace('homing_order = ["Z", ["X", "Y"]]', 'homing_order = ["W", ["U", "V"]]')
    config = parse_config(text)
    assert program_axes(config) == "UVW"
    assert machine_axes(config).homing_order == ("W", "UV")
    _, plan = plan_gcode(config, "G1 U10 V5 W2 F600\nM2\n")
    assert plan.axes == "UVW" and plan.end == (10.0, 5.0, 2.0)
    with pytest.raises(UnsupportedGCodeError, match="no axis X"):
        plan_gcode(config, "G1 X1 F600\nM2\n")


# --- whole programs on simulated machines -------------------------------------------------


def _run(tmp_path: Path, program: Path, *options: str) -> tuple[dict[str, object], str]:
    """``usbmotion run PROGRAM`` with a report and a plot, in this process (the command as
    a process of its own: test_job's test_usbmotion_run_a_demo_as_a_user_does)."""
    report = tmp_path / "report.json"
    done = CliRunner().invoke(app, [
        "run", str(program), "--report", str(report), "-q", "--plot",
        str(tmp_path / "plot.png"), *options])
    assert done.exit_code == 0 and done.exception is None, (
        done.stdout + done.stderr + repr(done.exception))
    assert (tmp_path / "plot.png").stat().st_size > 0
    return json.loads(report.read_text()), done.stdout


def test_a_plotter_runs_a_plotter_program(tmp_path: Path) -> None:
    report, out = _run(tmp_path, PROGRAMS / "plotter.ngc", "--machine", str(PLOTTER))
    assert report["completed"] is True
    assert [axis["name"] for axis in report["axes"]] == ["X", "Y"]  # type: ignore[index]
    assert report["end_position_mm"] == pytest.approx({"X": 0.0, "Y": 0.0}, abs=0.02)
    assert report["max_endpoint_miss_mm"] < 0.05  # type: ignore[operator]
    assert "Z" not in out.split("following error")[1].split("end position")[0]


def _printer(tmp_path: Path) -> Path:
    """The default machine as a printer: Z homes down onto its bed (Marlin's way) and runs
    0..100 mm up from it, where the CNC convention has it home up."""
    text = DEFAULT.read_text().replace('name = "simulated XYZ"', 'name = "printer"')
    for cnc, printer in (("travel_mm = [-100.0, 0.0]", "travel_mm = [0.0, 100.0]"),
                         ("homing = { direction = 1,", "homing = { direction = -1,"),
                         ("sim = { start_mm = -50.0,", "sim = { start_mm = 50.0,")):
        assert text.count(cnc) == 1, cnc
        text = text.replace(cnc, printer)
    path = tmp_path / "printer.toml"
    path.write_text(text)
    return path


def test_a_slicer_program_runs_in_the_marlin_dialect(tmp_path: Path) -> None:
    report, out = _run(tmp_path, PROGRAMS / "slicer.gcode", "--dialect", "marlin",
                       "--machine", str(_printer(tmp_path)))
    assert report["completed"] is True
    # It ends homed in X and Y (G28 X Y), the nozzle lifted to Z 10.
    assert report["end_position_mm"] == pytest.approx({"X": 0.0, "Y": 0.0, "Z": 10.0},
                                                      abs=0.02)
    extruder = [record for record in report["ignored_words"]  # type: ignore[union-attr]
                if record["meaning"] == "extruder position (no extruder)"]
    assert len(extruder) == 1 and extruder[0]["word"] == "E0" and extruder[0]["count"] > 10
    assert "M104 (line 14: set the hotend temperature (no hotend); 2 times)" in out


def test_a_grbl_laser_program_runs_in_the_grbl_dialect(tmp_path: Path) -> None:
    machine = tmp_path / "laser.toml"
    machine.write_text(DEFAULT.read_text().replace('name = "simulated XYZ"',
                                                   'name = "laser"\ndialect = "grbl"'))
    report, out = _run(tmp_path, PROGRAMS / "laser.nc", "--machine", str(machine))
    assert report["completed"] is True
    assert "S words (line 5: spindle speed or laser power; 5 times)" in out, (
        "words of one letter and several values are named by the letter")
    assert report["end_position_mm"] == pytest.approx({"X": 0.0, "Y": 0.0, "Z": 0.0},
                                                      abs=0.02)
    assert report["planned_time_s"] > 10  # type: ignore[operator]
