"""Running a program from a line (``motion.resume``): from every 10th line of every
LinuxCNC conformance program and of the demos, the resumed program's planned path from that
line is the uninterrupted program's, to 1e-6 mm in machine coordinates; the re-entry never
rapids below the safe height (a property over random positions)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from tests.test_gcode_conformance import ACCEPTED, CONFORMANCE, _interpret

from usbmotion.demos import DEMOS, demo_path
from usbmotion.errors import ArgumentError
from usbmotion.motion.gcode import GCodeProgram, parse_gcode, read_gcode_text
from usbmotion.motion.moves import Linear, Rapid, start_of
from usbmotion.motion.planner import AxisLimits, Plan, PlannerConfig, plan_moves
from usbmotion.motion.resume import reentry_moves, resume_from_line

LIMITS = [AxisLimits(200.0, 2000.0), AxisLimits(200.0, 2000.0), AxisLimits(100.0, 1000.0)]
HERE = (-37.5, 81.25, -12.0)  # where a stopped run left the machine: anywhere
DESCENT_FEED = 300.0
EVERY = 10
TOLERANCE_MM = 1e-6


def _plan(program: GCodeProgram, start: tuple[float, ...]) -> Plan:
    return plan_moves(program.moves, LIMITS, PlannerConfig(), start=start)


def _programs() -> list[tuple[str, GCodeProgram]]:
    programs = []
    for case in ACCEPTED:
        program, _ = _interpret(case)  # a few end in an error LinuxCNC reports too
        if program.moves:
            programs.append((f"{case.parent.name}/{case.name}", program))
    for number in DEMOS:
        path = demo_path(number)
        programs.append((path.name, parse_gcode(read_gcode_text(path), file=path.name)))
    return programs


def _resumed_tail_matches(program: GCodeProgram, line: int, safe_z: float) -> None:
    whole = _plan(program, (0.0, 0.0, 0.0))
    resumed = resume_from_line(program, line, here=HERE, safe_z_mm=safe_z,
                               descent_feed_mm_min=DESCENT_FEED)
    assert [m for m in resumed.moves if m.line >= line][-1] == program.moves[-1]
    again = _plan(resumed, HERE)
    first = int(np.flatnonzero(whole.line >= line)[0])
    tail = whole.vertices_mm[first:]
    # the resumed plan's last len(tail) vertices: from the point line N starts at, on
    got = again.vertices_mm[-len(tail):]
    assert got.shape == tail.shape
    worst = float(np.max(np.abs(got - tail))) if tail.size else 0.0
    assert worst <= TOLERANCE_MM, (program.file, line, worst)
    assert np.array_equal(again.line[-len(tail) + 1:], whole.line[first:])


@pytest.mark.skipif(not CONFORMANCE.is_dir(), reason="the conformance cases are absent")
def test_the_resumed_path_is_the_uninterrupted_one_from_every_tenth_line() -> None:
    checked = 0
    for _, program in _programs():
        top = max(*(start_of(m)[2] for m in program.moves), 0.0) + 5.0
        last = max(move.line for move in program.moves)
        for line in range(1, last + 1, EVERY):
            if not any(move.line >= line for move in program.moves):
                continue
            _resumed_tail_matches(program, line, top)
            checked += 1
    assert checked >= 70, checked


def test_a_line_out_of_the_program_or_with_nothing_after_it_is_refused() -> None:
    program = parse_gcode("G21 G90\nG0 X1\nG1 X2 F100\nM2\n", file="p.ngc")
    for line, words in ((0, "allowed 1..4"), (5, "allowed 1..4"), (4, "no move")):
        with pytest.raises(ArgumentError, match=words):
            resume_from_line(program, line, here=HERE, safe_z_mm=0.0,
                             descent_feed_mm_min=DESCENT_FEED)


def test_pauses_tool_changes_and_frames_follow_the_resumed_moves(tmp_path: Path) -> None:
    from usbmotion.motion.gcode import Pauses  # noqa: PLC0415

    text = ("G21 G90\nG0 X1 Y1\nM0\nG10 L2 P1 X5\nG0 X2\nT1 M6\nG1 X3 F200\nM0\nG1 Y3\nM2\n")
    program = parse_gcode(text, file="p.ngc", pauses=Pauses.PROGRAM)
    resumed = resume_from_line(program, 7, here=(0.0, 0.0, -10.0), safe_z_mm=0.0,
                               descent_feed_mm_min=DESCENT_FEED)
    assert [p.line for p in resumed.pauses] == [8]
    pause = resumed.pauses[0]
    assert resumed.moves[pause.move].line == 8
    assert [c.line for c in resumed.tool_changes] == []
    assert resumed.frames[0][0] == 0
    assert resumed.frames[0][1] == dict(program.frames)[max(
        index for index, _ in program.frames if index <= next(
            i for i, m in enumerate(program.moves) if m.line >= 7))]


@settings(max_examples=300, deadline=None)
@given(here=st.tuples(*(st.floats(-300, 300) for _ in range(3))),
       target=st.tuples(*(st.floats(-300, 300) for _ in range(3))),
       safe_z=st.floats(-300, 300))
def test_no_reentry_rapid_goes_below_the_safe_height(
        here: tuple[float, float, float], target: tuple[float, float, float],
        safe_z: float) -> None:
    moves = reentry_moves(here, target, line=9, axes="XYZ", safe_z_mm=safe_z,
                          feed_mm_min=DESCENT_FEED)
    position = here
    for move in moves:
        assert isinstance(move, Rapid | Linear) and move.start == position
        if isinstance(move, Rapid):
            below = min(move.start[2], move.end[2]) < safe_z
            # the retract, straight up from where the machine stands, is the one rapid below
            assert not below or (move.start == here and move.end[:2] == here[:2]
                                 and move.end[2] >= safe_z), (move, safe_z)
        position = move.end
    assert position == target or (not moves and here == target)


def test_a_run_from_a_line_on_the_simulated_machine_ends_as_the_whole_program() -> None:
    """Homed, the machine elsewhere (as a stop leaves it): demo 2 from line 9 re-enters from
    above and runs the rest of the star exactly as the whole program plans it."""
    from usbmotion.cli.machines import default_machine  # noqa: PLC0415
    from usbmotion.host.config import load_config  # noqa: PLC0415
    from usbmotion.sim.machine import connect_session  # noqa: PLC0415

    text = demo_path(2).read_text()
    with connect_session(load_config(default_machine())) as session:
        session.home()
        whole = session.prepare("2-star.ngc", text=text)
        session.jog({"X": 30.0, "Y": 40.0, "Z": -3.0}, feed_mm_min=3000, absolute=True)
        resumed = session.prepare("2-star.ngc", text=text, from_line=9)
        first = int(np.flatnonzero(whole.plan.line >= 9)[0])
        tail = whole.plan.vertices_mm[first:]
        assert np.max(np.abs(resumed.plan.vertices_mm[-len(tail):] - tail)) <= TOLERANCE_MM
        assert resumed.warnings[0].startswith("run from line 9")
        report, _ = session.run(resumed)
        assert report.completed, report.stop_reason
        end = tail[-1]
        for index, axis in enumerate("XYZ"):
            assert report.end_position_mm[axis] == pytest.approx(end[index], abs=2 / 240)


def test_usbmotion_run_from_line(tmp_path: Path) -> None:
    from typer.testing import CliRunner  # noqa: PLC0415

    from usbmotion.cli.machines import default_machine  # noqa: PLC0415
    from usbmotion.cli.main import app  # noqa: PLC0415

    program = tmp_path / "2-star.ngc"
    program.write_text(demo_path(2).read_text())
    machine = tmp_path / "machine.toml"  # its parameter file beside it, in tmp_path
    machine.write_text(default_machine().read_text())
    base = ["run", str(program), "-q", "--no-plot", "--machine", str(machine)]
    done = CliRunner().invoke(app, [*base, "--from-line", "12"])
    assert done.exit_code == 0, done.output
    assert "run from line 12" in done.output and "completed" in done.output
    for line, words in (("99", "allowed 1..16"), ("16", "makes no move"),
                        ("0", "--from-line 0 is out of range; allowed: 1 or more")):
        done = CliRunner().invoke(app, [*base, "--from-line", line])
        assert done.exit_code == 2, done.output
        assert words in done.output, done.output


def test_the_console_runs_a_program_from_a_line() -> None:
    import subprocess  # noqa: PLC0415
    import sys  # noqa: PLC0415

    done = subprocess.run([sys.executable, "-m", "usbmotion", "console"],
                          input="$d 2\n$c x\n$c 99\n$c 12\n", capture_output=True, text=True,
                          timeout=240, check=False)
    assert done.returncode == 0, done.stderr
    out = done.stdout
    assert "error: $c x: a line number, 1 or more" in out
    assert "error: from line 99: allowed 1..16" in out
    assert "joining it at line 12" in out
    assert "run from line 12" in out and "result         completed" in out
