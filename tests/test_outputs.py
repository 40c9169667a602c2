"""Coolant and laser outputs (``[outputs]``: an axis device's outputs, PROTOCOL.md call 42):
each change queued on the device tick its move starts on, so it happens on exactly the
tick the move's first setpoint is taken; a laser off on rapids, its power following the
speed the axes are told with M4, off at once on a hold, a stop and the program's end."""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path

import numpy as np
import pytest
from tests.executed import near_the_switches_text

from usbmotion.console import Console
from usbmotion.errors import ConfigError, GCodeError
from usbmotion.grbl.session_machine import SessionMachine
from usbmotion.host.config import load_config
from usbmotion.motion.gcode import MachineAxes, OutputChange, parse_gcode
from usbmotion.session import MachineSession
from usbmotion.session.live import LiveSnapshot
from usbmotion.session.operator import Operator
from usbmotion.session.outputs import RunOutputs, segment_values
from usbmotion.session.run import Run
from usbmotion.session.state import MachineState
from usbmotion.sim.machine import connect_session

LASER = Path(__file__).resolve().parents[1] / "examples" / "laser.toml"


def _laser(folder: Path, text: str | None = None) -> Path:
    """examples/laser.toml (or ``text``), its carriages powering up near their switches
    (these tests home only to begin)."""
    path = folder / "laser.toml"
    path.write_text(near_the_switches_text(text if text is not None else LASER.read_text()))
    return path


def test_an_outputs_table_is_read_and_checked(tmp_path: Path) -> None:
    config = load_config(_laser(tmp_path))
    assert config.outputs is not None
    pins = {name: (pin.axis, pin.output) for name, pin in config.outputs.pins.items()}
    assert pins == {"laser": ("X", 2), "flood": ("X", 0), "mist": ("X", 1)}
    text = LASER.read_text()
    for old, new, says in (
        ('laser = { axis = "X", output = 2 }', 'laser = { axis = "X", output = 1 }',
         "outputs.laser.output: 1 cannot carry laser; allowed: 2 or 3"),
        ('mist = { axis = "X", output = 1 }', 'mist = { axis = "X", output = 0 }',
         "axis X's output 0 already carries flood"),
        ('flood = { axis = "X", output = 0 }', 'flood = { axis = "Q", output = 0 }',
         "'Q' is not an axis of the machine"),
        ("laser_max_s = 1000.0", "laser_maxs = 1000.0", "did you mean 'laser_max_s'"),
    ):
        assert old in text
        bad = _laser(tmp_path, text.replace(old, new, 1))
        with pytest.raises(ConfigError) as caught:
            load_config(bad)
        assert says in str(caught.value), str(caught.value)
    both = text.replace("[outputs]", '[spindle]\nurl = "sim://S"\nmax_rpm = 6000\n\n[outputs]')
    with pytest.raises(ConfigError, match="the spindle of \\[spindle\\] or the laser"):
        load_config(_laser(tmp_path, both))


def test_the_words_become_output_changes_only_for_the_outputs_there_are() -> None:
    text = "G21 G90\nM8\nG1 X10 F600\nM7\nM9 M3 S500\nG1 X20\nM4 S1000\nG1 X5\nM5\nM2\n"
    every = parse_gcode(text, machine=MachineAxes(outputs=("flood", "mist", "laser")))
    assert every.outputs == (
        OutputChange(2, "flood", 1000), OutputChange(4, "mist", 1000),
        OutputChange(5, "mist", 0), OutputChange(5, "flood", 0),
        OutputChange(5, "laser", 500), OutputChange(7, "laser", 1000, dynamic=True),
        OutputChange(9, "laser", 0))
    assert every.ignored == ()
    flood = parse_gcode(text, machine=MachineAxes(outputs=("flood",)))
    assert [c.output for c in flood.outputs] == ["flood", "flood"]
    assert {w.word for w in flood.ignored} >= {"M7", "M3", "S500"}
    with pytest.raises(GCodeError, match="S1200 is beyond the laser's laser_max_s 1000"):
        parse_gcode("M3 S1200\nM2\n", machine=MachineAxes(outputs=("laser",)))
    ended = parse_gcode("M8\nG1 X1 F60\nM2\n", machine=MachineAxes(outputs=("flood",)))
    assert ended.outputs[-1] == OutputChange(3, "flood", 0), "M2 switches coolant off"


def _run(config_path: Path, program: str) -> tuple[MachineSession, Run]:
    session = connect_session(load_config(config_path))
    session.home()
    session.run(session.prepare("outputs.ngc", text=program))
    assert session.last_run is not None
    return session, session.last_run


def _first_row(run: Run, line: int) -> int:
    """The first row of the rows since the start taken by a move of ``line`` or later,
    computed from the plan's times (not from the rows' segments the outputs use)."""
    plan = run.legs.plan
    segment = int(np.searchsorted(plan.line, line, side="left"))
    return math.ceil(float(plan.start_time_s[segment]) / run.legs.period_s - 1e-9)


def test_coolant_changes_on_the_first_tick_of_the_move_that_asks_for_it(
        tmp_path: Path) -> None:
    program = "G21 G90\nG0 X10\nM8\nG1 X20 F600\nM9\nG0 X30\n"
    session, run = _run(_laser(tmp_path), program + "G1 X31\n")
    try:
        outputs = run.outputs
        assert isinstance(outputs, RunOutputs)
        flood = [c for c in outputs.applied if c.name == "flood"]
        on_tick = run.streams.tick_of(_first_row(run, 4))
        off_tick = run.streams.tick_of(_first_row(run, 6))
        assert [(c.value, c.tick) for c in flood] == [(1000, on_tick), (0, off_tick)]
        state = session.machine.axis("X").client.outputs()
        assert state.values[0] == 0 and state.last_change_tick == off_tick, (
            "the device applied the last change on exactly the tick it was given")
    finally:
        session.shutdown()
        session.close()


def test_the_device_turns_the_flood_on_on_the_moves_first_tick(tmp_path: Path) -> None:
    """The program ends with the flood on (no M9, no M2 in grbl): the device's last
    change is the M8's, on the tick the G1's first setpoint is taken."""
    session, run = _run(_laser(tmp_path), "G21 G90\nG0 X10\nM8\nG1 X20 F600\n")
    try:
        state = session.machine.axis("X").client.outputs()
        tick = run.streams.tick_of(_first_row(run, 4))
        assert state.values[0] == 1000 and state.last_change_tick == tick
        # The setpoint of that tick is the move's first (at or past X 10 mm, where the
        # G1 starts), the one before it the rapid's.
        rows = run.legs.rows[:, 0]
        row = _first_row(run, 4)
        assert rows[row - 1] < 10 * 240 <= rows[row], rows[row - 2: row + 2]
    finally:
        session.shutdown()
        session.close()


def test_a_laser_is_on_while_it_cuts_and_off_on_rapids(tmp_path: Path) -> None:
    program = ("G21 G90\nG0 X10 Y10\nM3 S600\nG1 X20 F1200\nG0 X30\nG1 X40\nG0 Y20\n"
               "G1 X30\nM5\nG0 X5\n")
    session, run = _run(_laser(tmp_path), program)
    try:
        outputs = run.outputs
        assert outputs is not None
        laser = [(c.value, c.tick) for c in outputs.applied if c.name == "laser"]
        expected = [(600, 4), (0, 5), (600, 6), (0, 7), (600, 8), (0, 10)]
        assert laser == [(value, run.streams.tick_of(_first_row(run, line)))
                         for value, line in expected]
        assert session.machine.axis("X").client.outputs().values[2] == 0
    finally:
        session.shutdown()
        session.close()


def test_m4_power_follows_the_speed_through_a_corner(tmp_path: Path) -> None:
    """Into a right-angle corner the axes slow down and the dynamic laser's power with
    them: at every change the power is the speed the rows tell the axes over the feed,
    within a step and the counts' quantisation."""
    program = "G21 G90\nG0 X10 Y10\nM4 S1000\nG1 X40 F1500\nG1 Y40\nM5\n"
    session, run = _run(_laser(tmp_path), program)
    try:
        outputs = run.outputs
        assert outputs is not None
        laser = [c for c in outputs.applied if c.name == "laser"]
        assert len(laser) > 20, "many steps through the accelerations"
        # The speed the axes are told around each change, over 10 ms; F1500 is 25 mm/s,
        # beyond X's and Y's 20 mm/s: full power at 20 mm/s (grbl's programmed rate).
        rows = run.legs.rows[:, :2].astype(np.float64) / 240
        for change in laser[:-1]:
            ahead, behind = min(change.row + 5, len(rows) - 1), change.row - 5
            speed = np.linalg.norm(rows[ahead] - rows[behind]) / ((ahead - behind) * 0.001)
            told = min(1.0, speed / 20.0) * 1000
            # Within a step (10) below, and the counts' quantisation over 10 ms either way
            # (a count in 10 ms is 0.42 mm/s, 21 per mille of 20 mm/s).
            assert told - 10 - 25 <= change.value <= told + 25, (change, told)
        powers = [c.value for c in laser]
        corner = powers.index(min(powers[2:-2]))
        assert 0 < powers[corner] < 500 < max(powers), "the power dips through the corner"
        assert laser[-1].value == 0
    finally:
        session.shutdown()
        session.close()


def test_a_hold_turns_the_laser_off_at_once_and_the_resume_on_again(tmp_path: Path) -> None:
    """Held mid-cut: the laser goes off on a tick just ahead of the request, while the axes
    still decelerate (grbl's laser mode); the resume starts it again with the move."""
    program = "G21 G90\nG0 X10 Y10\nM3 S800\nG1 X60 F600\nM5\nG0 X5\n"
    session = connect_session(load_config(_laser(tmp_path)))
    try:
        session.home()
        asked: list[int] = []
        resumed: list[bool] = []

        shown: list[int] = []

        def hold_then_resume(snapshot: LiveSnapshot) -> None:
            if 15 < snapshot.axes["X"].measured_mm < 25 and not asked:
                shown.append(snapshot.outputs.get("laser", -1))
            if snapshot.done_s > 2.5 and not asked:
                asked.append(snapshot.axes["X"].tick)
                session.request_hold()
            elif asked and snapshot.state is MachineState.HOLD and snapshot.at_rest \
                    and not resumed:
                resumed.append(True)
                session.request_resume()

        report, _ = session.run(session.prepare("hold.ngc", text=program),
                                on_progress=hold_then_resume)
        assert report.completed and resumed, report.stop_reason
        assert shown and set(shown) == {800}, "the live model shows the laser cutting"
        run = session.last_run
        assert run is not None
        outputs = run.outputs
        assert outputs is not None
        laser = [(c.value, c.tick) for c in outputs.applied if c.name == "laser"]
        values = [value for value, _ in laser]
        assert values[:2] == [800, 0] and 800 in values[2:] and values[-1] == 0, laser
        off_tick = laser[1][1]
        hold = run.holds[0]
        assert off_tick <= hold[1], "off no later than the deceleration's first tick"
        assert off_tick - asked[0] < 0.1 / 0.001, "within 0.1 s of the request's tick"
    finally:
        session.shutdown()
        session.close()


def test_a_grbl_sender_switches_the_coolant_and_the_laser(tmp_path: Path) -> None:
    """Lines as a sender streams them (the grbl dialect of examples/laser.toml): an ``M8``
    alone turns the flood on while the machine stands; ``M3 S500`` then cuts."""
    session = connect_session(load_config(_laser(tmp_path)))
    session.home()  # before the front: one thread talks to the devices at a time
    operator = Operator(session, file="<grbl>")
    front = SessionMachine(operator)
    clock = session.machine.clock

    def outputs_now() -> Mapping[str, int]:
        """The outputs a tick after what was asked, as the idle read shows them."""
        assert operator.wait_idle(60)
        clock.sleep(0.002)
        operator.keep_alive()
        return session.live.read().outputs

    try:
        assert front.submit("M8", None).name == "ACCEPTED"
        assert outputs_now()["flood"] == 1000, "M8 alone: the flood on at once"
        assert front.status().accessories == "F", "grbl's A:F"
        assert front.settings().extra == {30: 1000.0, 32: 1.0}, "$30 full power, $32 laser"
        for line in ("M3S500", "G1X10F600", "G0X20", "M5", "M9"):
            assert front.submit(line, None).name == "ACCEPTED", line
        now = outputs_now()
        run = session.last_run
        assert run is not None and run.outputs is not None
        laser = [c.value for c in run.outputs.applied if c.name == "laser"]
        assert 500 in laser and laser[-1] == 0, laser
        assert now["flood"] == 0 and now["laser"] == 0, now
        assert front.status().accessories == ""
    finally:
        front.close()
        operator.close()
        session.shutdown()
        session.close()


def test_the_console_shows_the_outputs(tmp_path: Path) -> None:
    said: list[str] = []
    with connect_session(load_config(_laser(tmp_path))) as session:
        console = Console(session, said.append)
        try:
            for line in ("$r", "M8"):
                console.handle(line)
                assert console.operator.wait_idle(60)
            session.machine.clock.sleep(0.002)  # the change applies on the next servo tick
            console.handle("?")
            assert console.operator.wait_idle(60)
        finally:
            console.close()
            session.shutdown()
    assert "outputs: flood on, mist off, laser 0 %" in said, said[-4:]


def test_a_run_from_a_line_switches_on_the_coolant_the_lines_before_switched_on(
        tmp_path: Path) -> None:
    """``M8`` at line 3, the run from line 5: the flood goes on with the re-entry's first
    move (its first tick), as the uninterrupted program has it on there."""
    config = load_config(_laser(tmp_path))
    with connect_session(config) as session:
        session.home()
        text = "G21 G90\nG0 X10\nM8\nG1 X20 F600\nG1 X30\nG0 X40\nM9\nM2\n"
        prepared = session.prepare("p.ngc", text=text, from_line=5)
        values, _ = segment_values(prepared.plan, prepared.program.outputs, "flood")
        assert values[0] == 1000 and values[len(prepared.plan)] == 0, values
        assert set(prepared.plan.line[:2]) == {5}, "the re-entry's moves are line 5's"
        report, _ = session.run(prepared)
        assert report.completed
        outputs = session.last_run.outputs if session.last_run is not None else None
        assert isinstance(outputs, RunOutputs)
        flood = [(c.value, c.tick) for c in outputs.applied if c.name == "flood"]
        assert flood[0] == (1000, session.last_run.streams.tick_of(0)), flood
        assert flood[-1][0] == 0
        session.shutdown()
