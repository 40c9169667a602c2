"""Rapids into the stock (``motion.plunges``): a rapid below work Z0 inside the XY extent of
the program's cuts at or below work Z0 is reported with its line and the Z it reaches; a
retract, a rapid outside the stock, a peck drill's return into its hole are not. Work Z is
the tool tip in the offsets each move was made in (G5x, G92, tool length)."""

from __future__ import annotations

from pathlib import Path

import pytest

from usbmotion.errors import GCodeError
from usbmotion.motion.dialects import Dialect
from usbmotion.motion.gcode import DEFAULT_MACHINE, GCodeStream, MachineAxes, parse_gcode
from usbmotion.motion.limits import AxisLimits, PlannerConfig
from usbmotion.motion.offsets import NO_OFFSETS, WorkOffsets
from usbmotion.motion.planner import plan_moves
from usbmotion.motion.plunges import RapidPlunge, rapid_plunges
from usbmotion.motion.tools import NO_TOOLS, ToolTable, parse_tool_table

PROGRAMS = Path(__file__).resolve().parent / "programs"
STOCK = NO_OFFSETS.with_g5x(1, (100.0, 100.0, -60.0) + (0.0,) * 6)
"""G54 on the stock's top front-left corner at machine X100 Y100 Z-60."""
LIMITS = [AxisLimits(20.0, 500.0)] * 3


def plunges(text: str, *, offsets: WorkOffsets = STOCK, tools: ToolTable = NO_TOOLS,
            machine: MachineAxes = DEFAULT_MACHINE, dialect: Dialect = Dialect.LINUXCNC,
            ) -> tuple[RapidPlunge, ...]:
    start = (0.0,) * len(machine.axes)
    program = parse_gcode(text, start=start, offsets=offsets, tools=tools, machine=machine,
                          dialect=dialect)
    plan = plan_moves(program.moves, LIMITS[:len(machine.axes)], PlannerConfig(),
                      start=start, axes=machine.axes)
    return rapid_plunges(program, plan)


POCKET = """G21 G90 G54
G0 Z5
G0 X2 Y2
G1 Z-3 F200
G1 X20 F600
G1 Y20
G1 X2
G1 Y2
G0 Z5
{extra}
M2
"""


def test_a_rapid_below_work_z0_over_the_cut_is_reported_with_its_line_and_z() -> None:
    found = plunges(POCKET.format(extra="G0 X10 Y10\nG0 Z-1\nG1 Z-3\nG0 Z5"))
    assert len(found) == 1
    plunge = found[0]
    assert (plunge.line, plunge.z_mm, plunge.x_mm, plunge.y_mm) == (
        11, pytest.approx(-1.0), pytest.approx(110.0), pytest.approx(110.0))
    assert plunge.extent_mm == ((102.0, 120.0), (102.0, 120.0)), "machine XY of the cuts"
    assert plunge.message == (
        "line 11: a rapid reaches work Z -1.000 mm, below work Z0, at machine X 110.000"
        " Y 110.000 mm, inside the stock's XY extent X 102.000..120.000 Y 102.000..120.000 mm"
        " (where the program cuts at or below work Z0): it would plunge into the stock at"
        " rapid speed")


def test_a_rapid_across_the_stock_below_z0_is_reported_where_it_is_lowest() -> None:
    found = plunges(POCKET.format(extra="G0 X-10 Y10 Z-2\nG0 X30 Y10 Z-1"))
    assert [(p.line, p.z_mm) for p in found] == [(11, pytest.approx(-1.7))]
    assert found[0].x_mm == pytest.approx(102.0), "where it enters the extent, lowest there"


@pytest.mark.parametrize("extra", [
    "",  # the pocket alone: every rapid above Z0, the retract straight up
    "G0 X40 Y40\nG0 Z-2",  # below Z0 but off the stock
    "G0 X10 Y10\nG0 Z0",  # down to Z0 exactly, not below
    "G0 X20 Y20\nG0 Z-2\nG0 Z5",  # back down into the corner it cut at Z-3
    "G0 X2 Y2\nG0 Z-3.5",  # ... but deeper than it cut there: see below
])
def test_rapids_that_do_not_plunge_into_the_stock_are_not_reported(extra: str) -> None:
    found = plunges(POCKET.format(extra=extra))
    if "Z-3.5" in extra:
        assert [(p.line, p.z_mm) for p in found] == [(11, pytest.approx(-3.5))]
    else:
        assert found == ()


def test_a_cam_post_job_with_its_retracts_reports_nothing() -> None:
    text = (PROGRAMS / "cam_corner.ngc").read_text()
    assert plunges(text, dialect=Dialect.GRBL) == ()
    rapid_back = text.replace("X2\nY2\n", "G0 X2\nG1 Y2\n")
    assert [p.line for p in plunges(rapid_back, dialect=Dialect.GRBL)] == [13], (
        "back along the pocket's edge at Z-3")


def test_peck_drilling_returns_into_its_hole_unreported_a_low_r_plane_is() -> None:
    pecks = "G21 G90\nG0 Z10\nG99 G83 X5 Y5 Z-6 R3 Q2 F150\nX15\nG80\nG0 Z10\nM2\n"
    program = parse_gcode(pecks, start=(0.0, 0.0, 0.0), offsets=STOCK)
    assert sum(1 for m in program.moves if m.end[2] < m.start[2]
               and m.end[2] - STOCK.g5x[0][2] < 0 and type(m).__name__ == "Rapid") >= 4, (
        "the cycle does rapid back down into each hole, below work Z0")
    assert plunges(pecks) == ()
    low_r = "G21 G90\nG0 Z10\nG98 G81 X5 Y5 Z-6 R-1 F150\nX15\nG80\nM2\n"
    found = plunges(low_r)
    assert [(p.line, p.z_mm) for p in found] == [(3, -1.0), (4, -1.0)], (
        "each hole's rapid to R below the stock's top, before anything cut there")


def test_work_z_is_the_tool_tip_in_the_offsets_each_move_was_made_in() -> None:
    tools = parse_tool_table("T1 P1 Z20.0\n")
    two_stocks = STOCK.with_g5x(2, (150.0, 100.0, -80.0) + (0.0,) * 6)
    text = ("G21 G90 G54\nT1 M6\nG43 H1\nG0 Z5\nG0 X2 Y2\nG1 Z-1 F200\nG1 X10 F600\n"
            "G53 G0 Z0\nG55\nG0 X2 Y2\nG0 Z5\nG1 Z-1\nG1 X10\nG53 G0 Z0\n"
            "G54\nG0 X5 Y2\nG0 Z{z}\nM2\n")
    program = parse_gcode(text.format(z=1), start=(0.0, 0.0, 0.0), offsets=two_stocks,
                          tools=tools)
    assert [(index, offset[2]) for index, offset in program.frames] == [
        (0, -60.0), (0, -60.0), (0, -40.0), (5, -60.0), (10, -40.0), (12, -40.0)], (
        "at the start, then G54, G43 H1 (20 mm), G55, G54 and M2")
    assert plunges(text.format(z=1), offsets=two_stocks, tools=tools) == ()
    found = plunges(text.format(z=-0.5), offsets=two_stocks, tools=tools)
    assert [(p.line, p.z_mm) for p in found] == [(17, -0.5)], (
        "machine Z -40.5: below Z0 only with G54's Z and the tool's length")
    assert found[0].extent_mm == ((102.0, 160.0), (102.0, 102.0)), "both stocks' cuts"


def test_an_arc_s_bulge_is_part_of_the_stock() -> None:
    arc = "G21 G90\nG0 Z5\nG0 X0 Y0\nG1 Z-1 F200\nG2 X20 Y0 I10 J0\nG0 Z5\n{extra}M2\n"
    assert plunges(arc.format(extra="G0 X10 Y11\nG0 Z-0.5\n")) == (), "off the bulge"
    found = plunges(arc.format(extra="G0 X10 Y5\nG0 Z-0.5\n"))
    assert [p.line for p in found] == [8], "inside it: the chord alone would miss it"
    assert found[0].extent_mm[1] == (100.0, pytest.approx(110.0, abs=0.01))


def test_only_the_part_of_a_ramp_at_or_below_z0_is_part_of_the_stock() -> None:
    ramp = "G21 G90\nG0 X0 Y0 Z5\nG1 X12 Z-1 F300\nG1 X20\nG0 Z5\nG0 X{x}\nG0 Z-0.5\nM2\n"
    assert plunges(ramp.format(x=5)) == (), "above the ramp's part in the air"
    found = plunges(ramp.format(x=15))
    assert [(p.line, p.z_mm) for p in found] == [(7, -0.5)]
    assert found[0].extent_mm == ((pytest.approx(110.0), 120.0), (100.0, 100.0)), (
        "from where the ramp goes below Z0 (X10 in work coordinates)")


def test_a_machine_without_z_or_a_program_that_never_cuts_below_z0_reports_nothing() -> None:
    plotter = MachineAxes(axes="XY")
    assert plunges("G21 G90\nG1 X10 Y10 F600\nG0 X5 Y5\nM2\n", machine=plotter) == ()
    assert plunges("G21 G90\nG1 Z1 F100\nG1 X10 F600\nG0 X5 Z-2\nM2\n") == ()


def test_a_stream_keeps_the_frames_of_its_lines_and_drops_a_failed_line_s() -> None:
    stream = GCodeStream(start=(0.0, 0.0, 0.0), offsets=STOCK)
    stream.feed("G0 X1")
    stream.feed("G10 L20 P1 Z0")
    with pytest.raises(GCodeError):
        stream.feed("G92 Z0 G0 Q1")
    stream.feed("G0 Z-1")
    frames = stream.result().frames
    assert frames == ((0, (100.0, 100.0, -60.0)), (1, (100.0, 100.0, 0.0)))
    stream.restart((1.0, 0.0, -1.0))
    assert stream.result().frames == ((0, (100.0, 100.0, 0.0)),)
