"""Rotary axes A B C in the interpreter, against LinuxCNC's own: the cases of
``tests/conformance/rotary`` (``make_references.py`` made their references with
``rs274``), each read for its machine's axes (``axes``; ``test.ini`` names a wrapped axis)
and compared move by move: kind, end point and arc centre within 1e-6 (mm or degrees), arc
direction and turns."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from usbmotion.errors import ConfigError, GCodeError, SoftLimitError
from usbmotion.host.config import load_config, parse_config
from usbmotion.motion.gcode import GCodeProgram, MachineAxes, move_record, parse_gcode
from usbmotion.session import describe
from usbmotion.session.planning import machine_axes, program_axes
from usbmotion.sim.machine import connect_session

CASES = Path(__file__).resolve().parent / "conformance" / "rotary"
FOLDERS = sorted(path for path in CASES.iterdir() if (path / "test.ngc").is_file())
TOLERANCE = 1e-6


def _machine(case: Path) -> MachineAxes:
    ini = case / "test.ini"
    wrapped = "".join(re.findall(r"\[AXIS_([ABC])\]\s*WRAPPED_ROTARY\s*=\s*1",
                                 ini.read_text())) if ini.is_file() else ""
    return MachineAxes(axes=(case / "axes").read_text().strip(), wrapped=wrapped)


def _interpret(case: Path) -> GCodeProgram:
    return parse_gcode((case / "test.ngc").read_text(), file=str(case / "test.ngc"),
                       machine=_machine(case))


def _differences(case: Path, program: GCodeProgram) -> list[str]:
    axes = program.axes
    reference = [json.loads(line) for line in (case / "motion.jsonl").read_text().splitlines()]
    ours = [move_record(move, axes=axes) for move in program.moves]
    problems = []
    if len(ours) != len(reference):
        problems.append(f"{len(ours)} moves, LinuxCNC {len(reference)}")
    for index, (mine, theirs) in enumerate(zip(ours, reference, strict=False)):
        if mine["type"] != theirs["type"]:
            problems.append(f"move {index + 1}: {mine['type']}, LinuxCNC {theirs['type']}")
            continue
        for key in ("start", "end", "centre"):
            if key not in theirs:
                continue
            for letter, a, b in zip(axes, mine[key], theirs[key], strict=True):  # type: ignore[call-overload]
                if (a is None) != (b is None) or (a is not None and abs(a - b) > TOLERANCE):
                    problems.append(f"move {index + 1} {key} {letter}: {a}, LinuxCNC {b}")
        if theirs["type"] == "arc" and mine["rotation"] != theirs["rotation"]:
            problems.append(f"move {index + 1}: rotation {mine['rotation']}, LinuxCNC"
                            f" {theirs['rotation']}")
    return problems


def test_the_cases_are_there() -> None:
    assert {case.name for case in FOLDERS} >= {"feed-mixed", "offsets", "wrapped", "five-axis"}


@pytest.mark.parametrize("case", FOLDERS, ids=lambda case: case.name)
def test_rotary_moves_agree_with_linuxcnc(case: Path) -> None:
    problems = _differences(case, _interpret(case))
    assert not problems, "\n".join(problems)


def _primary_and_total(record: dict[str, object], axes: str) -> tuple[float, float]:
    start, end = record["start"], record["end"]
    linear = sum((b - a) ** 2 for letter, a, b in zip(axes, start, end, strict=True)  # type: ignore[call-overload]
                 if letter in "XYZ") ** 0.5
    rotary = sum((b - a) ** 2 for letter, a, b in zip(axes, start, end, strict=True)  # type: ignore[call-overload]
                 if letter in "ABC") ** 0.5
    return (linear if linear > 0 else rotary), (linear * linear + rotary * rotary) ** 0.5


@pytest.mark.parametrize("case", FOLDERS, ids=lambda case: case.name)
def test_every_straight_feed_move_takes_linuxcncs_time(case: Path) -> None:
    """LinuxCNC's feed (its trace's) is along the X Y Z length (A B C alone: degrees per
    minute, G93 converted); ours is along the path every axis makes: each move's time,
    length over feed, is the same."""
    program = _interpret(case)
    reference = [json.loads(line) for line in (case / "motion.jsonl").read_text().splitlines()]
    checked = 0
    for move, theirs in zip(program.moves, reference, strict=True):
        if theirs["type"] != "linear":
            continue
        primary, total = _primary_and_total(theirs, program.axes)
        if primary == 0.0:
            continue
        their_minutes = primary / float(theirs["feed"])
        our_minutes = total / move.feed_mm_min  # type: ignore[union-attr]
        assert our_minutes == pytest.approx(their_minutes, rel=1e-4), (theirs, move)
        # and the feed it is shown with (usbmotion gcode moves) is LinuxCNC's own
        ours = move_record(move, axes=program.axes)["feed"]
        assert ours == pytest.approx(float(theirs["feed"]), rel=1e-4), (theirs, ours)
        checked += 1
    assert checked >= 1


# --- the interpreter's rules ------------------------------------------------------------------

XYZA = MachineAxes(axes="XYZA")


@pytest.mark.parametrize(("text", "words"), [
    ("G21 G93\nG1 X10 A90\nM2\n", "every feed move needs its own F word"),
    ("G21 G93\nG81 X1 Y1 Z-1 R1 F10\nM2\n", "canned cycles need G94"),
    ("G21 G94 F100\nG93\nG94\nG1 X1\nM2\n", "feed rate 0"),
])
def test_inverse_time_feed_is_refused_where_linuxcnc_refuses_it(text: str, words: str) -> None:
    with pytest.raises(GCodeError, match=words):
        parse_gcode(text, machine=XYZA)


def test_a_wrapped_axis_refuses_a_whole_turn_and_rotary_words_ignore_inches() -> None:
    with pytest.raises(GCodeError, match=r"A360: A is a wrapped rotary axis"):
        parse_gcode("G90 G0 A360\nM2\n", machine=MachineAxes(axes="XYZA", wrapped="A"))
    moves = parse_gcode("G91 G0 A720\nM2\n", machine=MachineAxes(axes="XYZA", wrapped="A")).moves
    assert moves[-1].end[3] == 720.0  # incremental: as far as it says
    inch = parse_gcode("G20 G90 G0 X1 A1\nM2\n", machine=XYZA).moves[-1]
    assert inch.end == (25.4, 0.0, 0.0, 1.0)
    with pytest.raises(GCodeError, match="the machine has no axis B"):
        parse_gcode("G0 B1\nM2\n", machine=XYZA)
    with pytest.raises(ValueError, match="wrapped 'X'"):
        MachineAxes(axes="XYZA", wrapped="X")


# --- a 4-axis machine ----------------------------------------------------------------------------

FOUR_AXIS = Path(__file__).resolve().parents[1] / "examples" / "machine-4axis.toml"
FOUR_AXIS_PROGRAM = FOUR_AXIS.parent / "4-axis-wrap.ngc"


def test_a_rotary_axis_is_in_degrees_in_its_machine_file(tmp_path: Path) -> None:
    config = load_config(FOUR_AXIS)
    table = config.axis("A")
    assert table.rotary and table.wrapped and table.homing.declare
    assert table.counts_per_mm == pytest.approx(53.3333333333)
    assert machine_axes(config).wrapped == "A" and program_axes(config) == "XYZA"
    text = FOUR_AXIS.read_text()
    for old, new, words in (
            ("counts_per_degree = 53.3333333333", "counts_per_mm = 53.3",
             "unknown key 'counts_per_mm'; did you mean 'counts_per_degree'?"),
            ("\nwrapped = true\n", "\nwrapped = true\ntravel_deg = [0, 90]\n",
             "it has no travel"),
            ("homing = { declare = true, position_deg = 0.0 }", "homing = { declare = false }",
             "a wrapped axis has no end switches"),
            ("max_velocity_deg_s = 90.0", "max_velocity_deg_s = -1",
             "axes.A.max_velocity_deg_s: -1 is out of range; allowed: a number > 0"),
            ("\nwrapped = true\n", "\nwrapped = 1\n",
             "axes.A.wrapped: 1 (int) is not true or false")):
        assert old in text, old
        with pytest.raises(ConfigError, match=re.escape(words)):
            parse_config(text.replace(old, new), path=FOUR_AXIS)
    with pytest.raises(ConfigError, match="unknown key 'wrapped'"):
        parse_config(text.replace('[axes.X]\nurl = "sim://X"',
                                  '[axes.X]\nwrapped = true\nurl = "sim://X"'), path=FOUR_AXIS)


def test_a_four_axis_program_runs_on_the_simulated_machine() -> None:
    """The rotary table is homed by declaring its angle; the program's X and A move
    together at LinuxCNC's feed (F along X), A alone in degrees per minute, a G93 move in
    1/F minutes; the wrapped A turns on to 360 for ``G0 A0``; every end point is passed
    within a few counts."""
    config = load_config(FOUR_AXIS)
    text = FOUR_AXIS_PROGRAM.read_text()
    with connect_session(config) as session:
        session.home()
        assert session.positions_mm()["A"] == 0.0
        prepared = session.prepare(FOUR_AXIS_PROGRAM.name, text=text)
        plan = prepared.plan
        times = {}
        for line in set(plan.line.tolist()):
            rows = plan.line == line
            times[line] = float((plan.t_accel_s[rows] + plan.t_cruise_s[rows]
                                 + plan.t_decel_s[rows]).sum())
        # 20 mm of X at 600 mm/min; 90 degrees at 1800 degrees/min; 1/6 minute in G93
        for line, nominal in ((6, 2.0), (7, 3.0), (9, 10.0)):
            assert nominal <= times[line] <= nominal + 0.3, (line, times[line])
        report, _ = session.run(prepared)
    assert report.completed, report.stop_reason
    assert report.end_position_mm["A"] == pytest.approx(360.0, abs=2 / 53.33)
    assert report.max_endpoint_miss_mm < 0.05
    text_report = describe(report)
    assert "A 360.000 deg" in text_report and " deg (" in text_report


def test_the_grbl_front_reports_the_rotary_axis_in_degrees() -> None:
    """grblHAL's way: ``MPos:x,y,z,a``; with $13=1 (inches) A stays in degrees."""
    from usbmotion.grbl.protocol import GrblProtocol  # noqa: PLC0415
    from usbmotion.grbl.session_machine import SessionMachine  # noqa: PLC0415
    from usbmotion.session.operator import Operator  # noqa: PLC0415

    with connect_session(load_config(FOUR_AXIS)) as session, Operator(session) as operator:
        session.home()
        operator.wait_idle(60)
        session.jog({"X": 25.4, "A": 90.0}, feed_mm_min=3000)
        out: list[bytes] = []
        front = GrblProtocol(SessionMachine(operator), out.append)
        front.connect()
        front.receive(b"$X\n")
        front.poll()
        front.receive(b"?")
        assert _mpos(out) == pytest.approx((25.4, 0.0, 0.0, 90.0), abs=2 / 53.3)
        out.clear()
        front.receive(b"$13=1\n")
        front.poll()
        out.clear()
        front.receive(b"?")
        inches = _mpos(out)
        assert inches == pytest.approx((1.0, 0.0, 0.0, 90.0), abs=2 / 53.3)
        assert re.search(r"MPos:[-\d.]+,[-\d.]+,[-\d.]+,\d+\.\d{3}\|", b"".join(out).decode())
        out.clear()
        front.receive(b"$$\n")
        front.poll()
        settings = b"".join(out).decode()
        assert "$133=0.000" in settings, "a wrapped axis has no travel"
        assert "$130=200.000" in settings, "settings in mm whatever $13 says (grbl)"
        out.clear()
        front.receive(b"$133=0\n")  # a sender restoring its backup changes nothing
        front.poll()
        assert b"".join(out).strip().endswith(b"ok"), out


def _mpos(out: list[bytes]) -> tuple[float, ...]:
    found = re.search(r"MPos:([^|>]*)", b"".join(out).decode())
    assert found is not None, out
    return tuple(float(value) for value in found.group(1).split(","))


def test_a_refused_line_leaves_the_feed_mode_and_units_as_they_were() -> None:
    from usbmotion.motion.gcode import GCodeStream  # noqa: PLC0415

    stream = GCodeStream(machine=XYZA)
    stream.feed("G21 G94 F100")
    with pytest.raises(GCodeError, match="its own F word"):
        stream.feed("G93 G20 G1 X1 A5")
    assert not stream.modes().inverse_time and not stream.modes().inches
    stream.feed("G1 X1 A5")
    assert stream.moves[-1].end == (1.0, 0.0, 0.0, 5.0)
    stream.feed("G93 G1 X2 A10 F60")
    assert stream.modes().inverse_time


def test_a_limited_rotary_axis_homes_on_its_switch_and_keeps_its_travel() -> None:
    """A tilting B of -90..90 degrees homing down onto its switch, as a linear axis does;
    a move beyond its travel is refused in degrees before anything moves."""
    text = FOUR_AXIS.read_text()
    limited = text[:text.index("[axes.A]")] + (
        '[axes.B]\nurl = "sim://B"\ndevice = "B AXIS"\ncounts_per_degree = 53.3333333333\n'
        "max_velocity_deg_s = 90.0\nmax_accel_deg_s2 = 900.0\ntravel_deg = [-90.0, 90.0]\n"
        "gains = { kp = 0.5, ki = 5.0, kd = 0.002 }\n"
        "velocity_gains = { kp = 0.001, ki = 0.5, kd = 0.0 }\n"
        "homing = { direction = -1, speed_deg_s = 30.0, slow_speed_deg_s = 5.0,"
        " backoff_deg = 2.0 }\nsim = { start_deg = -60.0 }\n")
    limited = limited.replace('homing_order = ["Z", ["X", "Y"], "A"]',
                              'homing_order = ["Z", ["X", "Y"], "B"]')
    config = parse_config(limited, path=FOUR_AXIS)
    with connect_session(config) as session:
        session.home()
        assert session.positions_mm()["B"] == pytest.approx(-90.0, abs=2 / 53.3)
        assert session.zeroes["B"].edge_counts != 0  # the latched switch edge
        with pytest.raises(SoftLimitError, match=r"B would reach 120\.000 deg, beyond the"
                           r" upper end 90 deg of axis B's travel_deg"):
            session.prepare("tilt.ngc", text="G21 G90\nG0 B120\nM2\n")
        report, _ = session.run(session.prepare("tilt.ngc", text="G21 G90\nG1 B45 F1800\nM2\n"))
    assert report.completed and report.end_position_mm["B"] == pytest.approx(45.0, abs=0.05)
