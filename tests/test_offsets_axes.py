"""Work offsets, tools and canned cycles on machines of any axis set, in each dialect."""

from __future__ import annotations

import pytest

from usbmotion.errors import GCodeError, UnsupportedGCodeError
from usbmotion.motion.dialects import Dialect
from usbmotion.motion.gcode import MachineAxes, interpret_setting, parse_gcode
from usbmotion.motion.moves import Linear, Rapid
from usbmotion.motion.offsets import (
    NO_OFFSETS,
    WorkOffsets,
    format_parameter_file,
    parse_parameter_file,
)
from usbmotion.motion.tools import parse_tool_table

XY = MachineAxes(axes="XY")
XZW = MachineAxes(axes="XZW")
SIX = MachineAxes(axes="XYZUVW")


def test_uvw_offsets_are_linuxcncs_parameters_and_apply_on_a_six_axis_machine() -> None:
    offsets = parse_parameter_file("5221 10\n5227 1\n5228 2\n5229 3\n5230 0\n")
    assert offsets.g5x[0] == (10.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 2.0, 3.0)
    program = parse_gcode("G0 X1 Y0 Z0 U0 V0 W0\nM2\n", machine=SIX, offsets=offsets)
    assert program.moves[-1].end == (11.0, 0.0, 0.0, 1.0, 2.0, 3.0)
    set_here = parse_gcode("G10 L20 P1 V5\nM2\n", machine=SIX, start=(0.0,) * 6)
    assert set_here.offsets.g5x[0][7] == -5.0
    assert "5228\t-5.000000" in format_parameter_file(set_here.offsets)


def test_a_machine_without_some_axes_keeps_their_offsets_as_read() -> None:
    offsets = NO_OFFSETS.with_g5x(1, (1.0, 2.0, 3.0, 0.0, 0.0, 0.0, 4.0, 5.0, 6.0))
    program = parse_gcode("G10 L2 P1 X7 W8\nG0 X0 Z0 W0\nM2\n", machine=XZW, offsets=offsets)
    assert program.moves[-1].end == (7.0, 3.0, 8.0)
    assert program.offsets.g5x[0] == (7.0, 2.0, 3.0, 0.0, 0.0, 0.0, 4.0, 5.0, 8.0)


def test_g92_g53_g28_on_a_plotter() -> None:
    text = "G0 X10 Y10\nG92 X0 Y0\nG0 X5\nG28.1\nG53 G0 X0 Y0\nG28\nM2\n"
    program = parse_gcode(text, machine=XY)
    ends = [move.end for move in program.moves if isinstance(move, Rapid)]
    assert ends[1] == (15.0, 10.0)  # G92 shifted X
    assert ends[2] == (0.0, 0.0)  # G53: machine coordinates
    assert ends[-1] == (15.0, 10.0)  # G28: the stored position
    assert program.offsets.g28 == (15.0, 10.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)


def test_g28_is_a_stored_position_in_linuxcnc_and_grbl_and_homing_in_marlin() -> None:
    homed = MachineAxes(axes="XYZ", home_mm=(1.0, 2.0, 90.0))
    offsets = WorkOffsets(g28=(5.0, 6.0, 7.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0))
    text = "G0 X20 Y20 Z20\nG28\nM2\n"
    for dialect in (Dialect.LINUXCNC, Dialect.GRBL):
        program = parse_gcode(text, machine=homed, offsets=offsets, dialect=dialect)
        assert program.moves[-1].end == (5.0, 6.0, 7.0), dialect
    marlin = parse_gcode(text, machine=homed, offsets=offsets, dialect=Dialect.MARLIN)
    assert marlin.moves[-1].end == (1.0, 2.0, 90.0)
    with pytest.raises(UnsupportedGCodeError, match="probes the bed"):
        parse_gcode("G30\n", machine=homed, dialect=Dialect.MARLIN)


def test_tool_lengths_on_the_machines_axes() -> None:
    table = parse_tool_table("T1 P1 Z10\nT2 P2 W4\n")
    program = parse_gcode("T2 M6\nG43\nG0 X0 W0\nM2\n", machine=XZW, tools=table)
    assert program.moves[-1].end == (0.0, 0.0, 4.0)
    with pytest.raises(UnsupportedGCodeError, match="machine has no axis Z"):
        parse_gcode("G43 H1\nM2\n", machine=XY, tools=table)
    g431 = parse_gcode("G43.1 W2\nG0 W1\nM2\n", machine=XZW)
    assert g431.moves[-1].end == (0.0, 0.0, 3.0)


def test_canned_cycles_need_the_three_axes_of_their_plane() -> None:
    with pytest.raises(UnsupportedGCodeError, match="machine has no axis Z") as info:
        parse_gcode("G0 X0 Y0\nG81 X1 Y1 R1 F100\nM2\n", machine=XY)
    assert info.value.line == 2
    drilled = parse_gcode("G0 X0 Y0 Z5 W3\nG81 X1 Y1 Z-1 R1 F100\nG80\nM2\n", machine=SIX)
    bottoms = [m.end for m in drilled.moves if isinstance(m, Linear)]
    assert bottoms == [(1.0, 1.0, -1.0, 0.0, 0.0, 3.0)]  # W stays where it stood


def test_grbl_refuses_what_grbl_lacks_and_marlin_g10_is_retraction() -> None:
    for text, reason in (("G81 X0 Y0 Z-1 R1 F100\n", "no canned cycles"),
                         ("G43 H1\n", "G43.1"), ("G59.1\n", "G54-G59")):
        with pytest.raises(UnsupportedGCodeError, match=reason):
            parse_gcode(text, dialect=Dialect.GRBL)
    assert parse_gcode("G10 L20 P1 X0\n", dialect=Dialect.GRBL, start=(4.0, 0.0, 0.0)
                       ).offsets.g5x[0][0] == 4.0
    with pytest.raises(UnsupportedGCodeError, match="firmware retraction"):
        parse_gcode("G10 L20 P1 X0\n", dialect=Dialect.MARLIN)


def test_a_rotation_needs_x_and_y() -> None:
    with pytest.raises(UnsupportedGCodeError, match="rotation turns X and Y"):
        parse_gcode("G10 L2 P1 R30\nM2\n", machine=XZW)


def test_console_settings_on_a_plotter() -> None:
    offsets = interpret_setting("G10 L20 P1 X0 Y0", start=(3.0, 4.0), machine=XY)
    assert offsets.g5x[0] == (3.0, 4.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    with pytest.raises(GCodeError):
        interpret_setting("G10 L20 P1 Z0", start=(3.0, 4.0), machine=XY)
