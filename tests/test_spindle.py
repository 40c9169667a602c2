"""The spindle: a USB Motion Device in velocity mode (``[spindle]`` in the machine file).

``M3``/``M4`` with ``S`` spin it, ``M5`` and the program's end stop it along its ramp; the
feed moves after each wait until its encoder says it is at speed (LinuxCNC's
spindle-at-speed); once at speed, a stall is an alarm that stops every axis along its path
and the spindle too. The live model, the grbl front's ``FS`` and ``$G``, the console's ``?``
and the dashboard's state show the speed the encoder measures. Without a ``[spindle]`` the
words stay listed as ignored."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pytest

from usbmotion.console import Console
from usbmotion.device import Device
from usbmotion.errors import ConfigError, GCodeError
from usbmotion.grbl.session_machine import SessionMachine
from usbmotion.host.config import load_config
from usbmotion.host.device import DeviceClient, Stopped
from usbmotion.host.spindle import SpindleNow
from usbmotion.motion.gcode import MachineAxes, parse_gcode
from usbmotion.motion.moves import Dwell
from usbmotion.session.live import LiveSnapshot
from usbmotion.session.operator import Operator
from usbmotion.session.planning import prepare_program
from usbmotion.session.report import RunReport, Trace
from usbmotion.sim.machine import SimulatedMachine, connect_session, load_machine_file
from usbmotion.sim.predict import predict
from usbmotion.web.dashboard import Dashboard

ROUTER = Path(__file__).resolve().parents[1] / "examples" / "router.toml"
RAMP_S = 1.2
"""examples/router.toml: 0 to 12,000 rpm at 10,000 rpm/s."""


def _router(folder: Path, extra: str = "") -> Path:
    path = folder / "router.toml"
    path.write_text(ROUTER.read_text() + extra)
    return path


def test_a_spindle_table_is_read_and_checked(tmp_path: Path) -> None:
    config = load_config(_router(tmp_path))
    spindle = config.spindle
    assert spindle is not None and spindle.is_simulated
    assert (spindle.max_rpm, spindle.accel_rpm_s, spindle.counts_per_revolution) == (
        12000.0, 10000.0, 400)
    assert spindle.counts_per_s(12000) == 80_000 and spindle.rpm(80_000) == 12000
    text = ROUTER.read_text()
    for old, new, says in (
        ("max_rpm = 12000.0", "max_rpm = 20000.0", "more than the simulated motor reaches"),
        ("max_rpm = 12000.0", "max_rpm = -1", "max_rpm: -1 is out of range"),
        ("accel_rpm_s = 10000.0", "accel_rmp_s = 10000.0", "did you mean 'accel_rpm_s'"),
        ("stall_tolerance = 0.15", "stall_tolerance = 0.005", "stall_tolerance"),
        ('url = "sim://S"\ndevice = "SPINDLE"', "", "missing required key 'device' or 'url'"),
    ):
        assert old in text
        bad = tmp_path / "bad.toml"
        bad.write_text(text.replace(old, new, 1))
        with pytest.raises(ConfigError) as caught:
            load_config(bad)
        assert says in str(caught.value), str(caught.value)
        assert "spindle" in str(caught.value)


def test_spindle_words_pause_for_the_spindle_only_on_a_machine_with_one() -> None:
    text = "G21 G90\nM3 S12000\nG1 X10 F600\nS12000\nS6000\nG1 X20\nM4\nM5 S100\nM2\n"
    program = parse_gcode(text, machine=MachineAxes(spindle_max_rpm=12000))
    assert [(p.line, p.code, p.spindle_rpm) for p in program.pauses] == [
        (2, "M3", 12000.0), (5, "S", 6000.0), (7, "M4", -6000.0), (8, "M5", 0.0),
        (9, "M2", 0.0)], "an unchanged S (line 4) is no pause; M2 stops the spindle"
    assert program.ignored == ()
    plain = parse_gcode(text)
    assert plain.pauses == ()
    assert {w.word for w in plain.ignored} >= {"M3", "S12000", "M4", "M5"}
    with pytest.raises(GCodeError, match=r"S12001 is beyond the spindle's max_rpm 12000"):
        parse_gcode("M3 S12001\nM2\n", machine=MachineAxes(spindle_max_rpm=12000))


def _run(path: Path, program: str) -> tuple[RunReport, Trace, SpindleNow]:
    with connect_session(load_config(path)) as session:
        session.home()
        report, trace = session.run(session.prepare("spindle.ngc", text=program))
        spindle = session.machine.spindle
        assert spindle is not None
        after = spindle.read()
        session.shutdown()
        return report, trace, after


def test_the_feed_waits_for_the_spindle_at_speed_and_m5_stops_it(tmp_path: Path) -> None:
    program = "G21 G90\nM3 S12000\nG1 X10 F600\nS6000\nG1 X20\nM5\nM2\n"
    report, trace, after = _run(_router(tmp_path), program)
    assert report.completed, report.stop_reason
    up, down, stop = report.spindle
    assert (up.line, up.rpm, down.line, down.rpm, stop.line, stop.rpm) == (
        2, 12000.0, 4, 6000.0, 6, 0.0)
    assert RAMP_S <= up.waited_s <= RAMP_S + 0.05, up
    assert up.measured_rpm == pytest.approx(12000, rel=0.01)
    assert down.measured_rpm == pytest.approx(6000, rel=0.01)
    assert 0.6 <= down.waited_s <= 0.65 and 0.6 <= stop.waited_s <= 0.65
    assert after.measured_rpm == 0 and after.commanded_rpm == 0
    # The first feed move starts only once the spindle is at speed: X's commanded
    # position leaves 0 no earlier than the ramp's end.
    clocks = trace.column(trace.clock, "X")
    desired = trace.column(trace.desired, "X")
    moving = clocks[np.flatnonzero(desired != desired[0])[0]]
    assert (moving - trace.start_tick) * trace.tick_s >= up.waited_s - 0.011
    assert report.executed_time_s >= report.planned_time_s + up.waited_s + down.waited_s


def test_a_new_speed_sent_late_ramps_whole(tmp_path: Path,
                                           monkeypatch: pytest.MonkeyPatch) -> None:
    """The host held up 0.2 s before sending the ramp from 12,000 to 6,000 rpm (a third of
    it): the ramp plays whole, late (call 50), where call 38 would have dropped its first
    third and stepped the commanded speed by 2,000 rpm at once."""
    stop_from = DeviceClient.stop_from
    late: list[int] = []
    held: list[DeviceClient | None] = [None]

    def held_up(client: DeviceClient, tick: int, values: Sequence[int]) -> Stopped:
        if client is held[0]:
            client.link_clock.sleep(0.2)
        stopped = stop_from(client, tick, values)
        late.append(stopped.late)
        return stopped

    config = load_config(_router(tmp_path))
    spindle = config.spindle
    assert spindle is not None
    with connect_session(config) as session:
        session.home()
        world = session.machine.world
        assert world is not None
        device = world.device("S")
        assert isinstance(device, Device)
        run, seen = type(device).run, []

        def tick_by_tick(ticks: int) -> None:
            for _ in range(ticks):
                run(device, 1)
                seen.append(device.state.desired_velocity)

        device.__dict__["run"] = tick_by_tick
        world.run_ahead = False
        machine_spindle = session.machine.spindle
        assert machine_spindle is not None
        held[0] = machine_spindle.client
        period_s = machine_spindle.period_s  # a value every 10 ms
        monkeypatch.setattr(DeviceClient, "stop_from", held_up)
        report, _ = session.run(session.prepare(
            "spindle.ngc", text="G21 G90\nM3 S12000\nG1 X10 F600\nS6000\nG1 X20\nM5\nM2\n"))
        session.shutdown()
    assert report.completed, report.stop_reason
    assert max(late) > 0, "the new speed came late"
    step = spindle.accel_rpm_s * spindle.counts_per_revolution / 60.0 * period_s
    speeds = np.array(seen)
    assert np.abs(speeds).max() >= spindle.counts_per_s(12000) - 1
    assert np.abs(np.diff(speeds)).max() <= step + 1, "the ramp cut short: a jump in speed"


def test_a_stall_is_an_alarm_that_stops_every_axis_along_its_path(tmp_path: Path) -> None:
    """A load beyond the motor's torque at 12,000 rpm (1 Nm; about 0.6 Nm is left above
    the back-EMF) put on the simulated spindle mid-cut."""
    program = "G21 G90\nM3 S12000\nG1 X60 F600\nM5\nM2\n"
    loaded: list[bool] = []
    machine: list[SimulatedMachine] = []

    def load_at_2_s(snapshot: LiveSnapshot) -> None:
        if snapshot.done_s > 2.0 and not loaded and machine:
            machine[0].world.device("S").feed(b"33 1 3\n")  # 1e3 mNm
            loaded.append(True)

    config = load_config(_router(tmp_path))
    with connect_session(config) as session:
        assert isinstance(session.machine, SimulatedMachine)
        machine.append(session.machine)
        session.home()
        prepared = session.prepare("stall.ngc", text=program)
        report, _ = session.run(prepared, on_progress=load_at_2_s)
        assert loaded
        assert not report.completed and report.stop_reason.startswith("fault"), report
        fault, = report.faults
        assert fault.axis == "spindle" and "spindle stalled" in fault.fault
        assert fault.line == 3
        assert report.stop_planned_mm > 0 and report.stop_distance_mm == pytest.approx(
            report.stop_planned_mm, abs=0.05), "X decelerated along its path, not coasting"
        spindle = session.machine.spindle
        assert spindle is not None and spindle.commanded_rpm == 0, "the spindle told to stop"


def test_grbl_shows_the_measured_speed_and_its_override_turns_the_spindle(
        tmp_path: Path) -> None:
    config = load_config(_router(tmp_path))
    with connect_session(config) as session:
        session.home()  # before the front: one thread talks to the devices at a time
        operator = Operator(session, file="<grbl>")
        front = SessionMachine(operator)
        try:
            assert front.submit("M3S12000", None).name == "ACCEPTED"
            assert front.submit("G1X10F600", None).name == "ACCEPTED"
            assert operator.wait_idle(60)
            status = front.status()
            assert status.spindle_rpm == pytest.approx(12000, rel=0.01)
            modal = front.modal_state()
            assert (modal.spindle, modal.spindle_speed) == ("M3", 12000.0)
            shown = Dashboard(operator).state(session.live.reader())["spindle"]
            assert shown["commanded_rpm"] == 12000 and shown["at_speed"]
            assert shown["measured_rpm"] == pytest.approx(12000, rel=0.01)
            front.set_spindle_override(50)
            clock = session.machine.clock
            for _ in range(300):  # idle: the operator's keep-alive services the spindle
                operator.keep_alive()
                clock.sleep(0.01)
            assert front.status().spindle_rpm == pytest.approx(6000, rel=0.01)
            assert front.submit("M5", None).name == "ACCEPTED"
            assert operator.wait_idle(60)
            assert front.status().spindle_rpm == 0
        finally:
            front.close()
            operator.close()
            session.shutdown()


def test_prepare_refuses_a_speed_beyond_the_spindle(tmp_path: Path) -> None:
    config = load_config(_router(tmp_path))
    with pytest.raises(GCodeError, match="max_rpm 12000"):
        prepare_program(config, "M3 S15000\nM2\n", file="fast.ngc", start_mm=(0.0,) * 3,
                        homed=True)


def test_a_prediction_spins_a_simulated_spindle_for_a_real_one(tmp_path: Path) -> None:
    """A spindle on a port has no simulated motor: the prediction winds the default one
    to reach its max_rpm, so the program's spindle pauses take the ramp's time."""
    text = ROUTER.read_text()
    for old, new in (('url = "sim://S"', 'url = "/dev/ttyACM9"'),
                     ("max_rpm = 12000.0", "max_rpm = 24000.0"),
                     ("accel_rpm_s = 10000.0", "accel_rpm_s = 20000.0"),
                     ("sim = { load_torque_mnm = 5.0 }", "")):
        assert old in text
        text = text.replace(old, new, 1)
    machine = tmp_path / "real-router.toml"
    machine.write_text(text)
    config = load_machine_file(machine)
    assert config.spindle is not None and config.spindle.sim is None
    program = tmp_path / "fast.ngc"
    program.write_text("G21 G90\nM3 S24000\nG1 X10 F600\nM2\n")
    report = predict(config, program, program.read_text()).report
    assert report.completed, report.stop_reason
    up, stop = report.spindle
    assert up.rpm == 24000 and up.measured_rpm == pytest.approx(24000, rel=0.01)
    assert 1.2 <= up.waited_s <= 1.25 and stop.rpm == 0


def test_the_console_shows_the_spindle_it_spins(tmp_path: Path) -> None:
    config = load_config(_router(tmp_path))
    said: list[str] = []
    with connect_session(config) as session:
        console = Console(session, said.append)
        try:
            for line in ("$r", "M3 S9000", "?"):
                console.handle(line)
                assert console.operator.wait_idle(60)
            assert "spindle: 9000 rpm measured, 9000 rpm commanded" in said, said[-5:]
            console.handle("M5")
            assert console.operator.wait_idle(60)
            console.handle("?")
            assert console.operator.wait_idle(60)
            assert "spindle: 0 rpm measured, 0 rpm commanded" in said, said[-5:]
        finally:
            console.close()
            session.shutdown()


def test_a_run_from_a_line_starts_the_spindle_the_lines_before_left_turning(
        tmp_path: Path) -> None:
    """LinuxCNC's run from a line restores the spindle: examples/router.ngc from line 9
    (after ``M3 S12000`` at line 6) spins up to 12,000 rpm before the re-entry goes over and
    down, from line 14 (after ``S9000``) to 9,000 rpm; from line 19 (after ``M5``) it stays
    still. Standing low, the retract straight up comes first."""
    text = (ROUTER.parent / "router.ngc").read_text()
    config = load_config(_router(tmp_path))
    with connect_session(config) as session:
        session.home()
        session.jog({"X": 50.0, "Y": 40.0, "Z": -3.0}, feed_mm_min=3000.0, absolute=True)
        prepared = session.prepare("router.ngc", text=text, from_line=9)
        first = prepared.program.pauses[0]
        assert (first.line, first.code, first.spindle_rpm) == (9, "M3", 12000.0)
        retract = prepared.program.moves[0]
        assert not isinstance(retract, Dwell) and retract.end[2] == 0.0 and retract.end[:2] \
            == (50.0, 40.0), "the retract straight up before the spindle starts"
        assert isinstance(prepared.program.moves[first.move], Dwell)
        report, trace = session.run(prepared)
        assert report.completed, report.stop_reason
        up = report.spindle[0]
        assert (up.line, up.rpm) == (9, 12000.0)
        assert up.measured_rpm == pytest.approx(12000, rel=0.01)
        # Nothing moves over or down before the spindle is at speed.
        clocks = trace.column(trace.clock, "X")
        desired = trace.column(trace.desired, "X")
        moving = clocks[np.flatnonzero(desired != desired[0])[0]]
        assert (moving - trace.start_tick) * trace.tick_s >= up.waited_s - 0.011
        slower = session.prepare("router.ngc", text=text, from_line=14).program.pauses[0]
        assert (slower.line, slower.spindle_rpm) == (14, 9000.0)
        still = session.prepare("router.ngc", text=text, from_line=19).program.pauses
        assert [(pause.line, pause.spindle_rpm) for pause in still] == [(20, 0.0)], still
        session.shutdown()
