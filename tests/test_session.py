"""The machine session in virtual time: state, taking over, homing, soft limits, programs
that start where the machine stands, and stops along the deceleration."""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from tests.executed import near_the_switches

from usbmotion.automation import device_io
from usbmotion.cli.run import default_machine
from usbmotion.device import Device
from usbmotion.errors import (
    MachineStateError,
    SequenceFaultError,
    SoftLimitError,
    StopRequestedError,
)
from usbmotion.host.config import MachineConfig, load_config, parse_config
from usbmotion.host.device import DeviceClient, Stopped
from usbmotion.motion.limits import SETTLED_BAND_COUNTS
from usbmotion.protocol import FaultCode
from usbmotion.session import (
    TRANSITIONS,
    MachineSession,
    MachineState,
    StopReason,
    check_transition,
    describe,
    home_position_mm,
)
from usbmotion.session.live import LiveSnapshot as Progress
from usbmotion.session.rest import STOP_LEAD_S
from usbmotion.session.state import UNITS, Event, StateMachine
from usbmotion.session.streaming import RunStreams
from usbmotion.sim.machine import connect_session
from usbmotion.sim.world import SimWorld

LINE = "G21 G90\nG1 X150 F1200\nM2\n"
"""A straight line at 20 mm/s, X's fastest on the default machine."""


@pytest.fixture(scope="module")
def config() -> MachineConfig:
    return load_config(default_machine())


@pytest.fixture(scope="module")
def near(config: MachineConfig) -> MachineConfig:
    """The machine, its carriages powering up near their switches: for the tests that home
    only to begin (a third of the homing's time); those about homing take ``config``."""
    return near_the_switches(config)


def _devices(session: MachineSession) -> dict[str, Device]:
    world = session.machine.world
    assert world is not None
    devices = {}
    for name in session.machine.axes:
        device = world.device(name)
        assert isinstance(device, Device)
        devices[name] = device
    return devices


def test_every_state_change_is_one_of_the_documented_transitions() -> None:
    for state in MachineState:
        for wanted in MachineState:
            if wanted in TRANSITIONS[state]:
                check_transition(state, wanted)
            else:
                with pytest.raises(MachineStateError, match=f"in {state.value}: it cannot go"):
                    check_transition(state, wanted)
    assert TRANSITIONS[MachineState.ALARM] == {MachineState.IDLE, MachineState.HOMING}, (
        "only a reset, or a homing (grbl's $H), leaves Alarm")


def test_each_state_decides_its_next_state_within_its_transitions() -> None:
    """Every state's unit answers every event with a state its transitions allow (or none),
    and the one door refuses the rest naming the state and the event."""
    for state, unit in UNITS.items():
        for event in Event:
            for at_rest in (False, True):
                wanted = unit.next_state(event, at_rest=at_rest)
                assert wanted is None or wanted in TRANSITIONS[state], (state, event, wanted)
    machine = StateMachine()
    seen: list[tuple[MachineState, MachineState]] = []
    machine.on_change = lambda old, new: seen.append((old, new))
    with pytest.raises(MachineStateError, match="in Idle: resume does not apply"):
        machine.fire(Event.RESUME)
    for event, at_rest, state in [
            (Event.START, True, MachineState.RUN), (Event.HOLD, False, MachineState.HOLD),
            (Event.RESUME, False, None), (Event.RESUME, True, MachineState.RUN),
            (Event.PAUSE, True, MachineState.PAUSED), (Event.RESUME, True, MachineState.RUN),
            (Event.STOP, False, MachineState.STOPPING), (Event.AT_REST, True, MachineState.IDLE),
            (Event.JOG, True, MachineState.JOG), (Event.HOLD, False, MachineState.STOPPING),
            (Event.DONE, True, MachineState.IDLE), (Event.START, True, MachineState.RUN),
            (Event.FAULT, False, MachineState.ALARM), (Event.HOME, True, MachineState.HOMING),
            (Event.FAULT, False, MachineState.ALARM), (Event.RESET, True, MachineState.IDLE)]:
        if state is None:
            with pytest.raises(MachineStateError):
                machine.fire(event, at_rest=at_rest)
        else:
            assert machine.fire(event, at_rest=at_rest) is state
    assert seen[0] == (MachineState.IDLE, MachineState.RUN) and len(seen) == 15
    assert machine.state is MachineState.IDLE


def test_a_program_starts_where_the_machine_stands_and_can_run_twice(
        near: MachineConfig) -> None:
    with connect_session(near) as session:
        assert session.state is MachineState.IDLE and not session.is_homed
        session.home()
        assert session.is_homed
        step = "G21 G91\nG1 X10 Y5 F600\nM2\n"
        first = session.prepare("step.ngc", text=step)
        assert first.start_mm == tuple(home_position_mm(near.axis(n)) for n in "XYZ")
        report, _ = session.run(first)
        assert report.completed and report.stop_reason == "completed"
        second = session.prepare("step.ngc", text=step)
        assert second.start_mm == pytest.approx((10.0, 5.0, 0.0), abs=1 / 240)
        report, _ = session.run(second)
        assert report.completed
        assert session.positions_mm()["X"] == pytest.approx(20.0, abs=1 / 240)
        with pytest.raises(MachineStateError, match="prepare it again"):
            session.run(first)


def test_moves_to_zero_after_homing_touch_no_switch(near: MachineConfig) -> None:
    """The switch is outside the travel: G0 X0 and the CAM retracts to the top of Z
    (G28 G91 Z0, G53 G0 Z0) are moves, not faults."""
    program = ("G21 G90\nG0 X50 Y40 Z-20\nG0 X0 Y0\nG28 G91 Z0\nG90 G0 Z-30\n"
               "G53 G0 Z0\nG90 G0 X0 Y0 Z0\nM2\n")
    with connect_session(near) as session:
        session.home()
        report, _ = session.run(session.prepare("zero.ngc", text=program))
        assert report.completed and report.faults == ()
        for name, status in session.machine.status().items():
            assert status.desired_counts == 0, name
            assert not (status.lower_limit or status.upper_limit) and status.fault == 0


@pytest.mark.parametrize(("program", "line", "axis", "coordinate", "limit"), [
    ("G21 G90\nG0 X20\nG0 X300\nM2\n", 3, "X", 300.0, 200.0),
    ("G21 G90\nG0 X60 Y5\nG3 X100 Y5 I20 J0 F600\nM2\n", 3, "Y", None, 0.0),
    ("G21 G91\nG1 Z0.5 F100\nM2\n", 2, "Z", 0.5, 0.0),  # above the top of Z
    ("G21 G90\nG0 Z-50\nG1 Z-100.5 F100\nM2\n", 3, "Z", -100.5, -100.0),
])
def test_a_program_that_leaves_the_travel_is_refused_before_anything_moves(
        near: MachineConfig, program: str, line: int, axis: str, coordinate: float | None,
        limit: float) -> None:
    with connect_session(near) as session:
        session.home()
        devices = _devices(session)
        before = {name: (d.state.desired, d.state.queued, d.settings) for name, d in
                  devices.items()}
        with pytest.raises(SoftLimitError) as caught:
            session.prepare("far.ngc", text=program)
        error = caught.value
        assert (error.line, error.axis, error.limit_mm) == (line, axis, limit)
        if coordinate is not None:
            assert error.coordinate_mm == pytest.approx(coordinate)
        assert f"line {line}: {axis} would reach" in str(error)
        assert "nothing was moved" in str(error)
        after = {name: (d.state.desired, d.state.queued, d.settings) for name, d in
                 devices.items()}
        assert after == before, "no setpoint was sent"


def test_two_runs_in_a_row_ending_at_the_top_of_z_both_complete(near: MachineConfig) -> None:
    """``usbmotion run`` twice on the same devices, each a take-over, a program ending with
    the CAM retract G53 G0 Z0 and the servos disabled at its end. The run ends with Z on its
    last setpoint, the top of its travel; a servo that holds a count past it (friction) is
    what a travel one count shorter shows: the next run, a jog back inside and MDI start
    from there; a move farther out is still refused."""
    program = "G21 G90\nG0 X10 Y10 Z-20\nG53 G0 Z0\nM2\n"
    world = SimWorld()
    with connect_session(near, world=world) as first:
        first.home()
        report, _ = first.run(first.prepare("retract.ngc", text=program))
        assert report.completed, report.stop_reason
        assert report.end_position_mm["Z"] == 0.0, "the run ends on its last setpoint"
        first.shutdown()
    top = -1 / 240  # one count below where Z stands
    shorter = replace(near, axes=tuple(
        replace(axis, travel_mm=(axis.travel_mm[0], top)) if axis.name == "Z" else axis
        for axis in near.axes))
    with connect_session(shorter, world=world) as second:
        assert second.is_homed
        start_z = second.positions_mm()["Z"]
        assert 0.0 < start_z - top <= SETTLED_BAND_COUNTS / 240, (
            "outside the travel's top, within the settled band: what refused every program")
        report, _ = second.run(second.prepare("retract.ngc", text=program.replace(
            "G53 G0 Z0", f"G53 G0 Z{top!r}")))
        assert report.completed, report.stop_reason
        second.shutdown()
    top = -2 / 240  # a count shorter again: Z stands a count outside
    shorter = replace(shorter, axes=tuple(
        replace(axis, travel_mm=(axis.travel_mm[0], top)) if axis.name == "Z" else axis
        for axis in shorter.axes))
    with connect_session(shorter, world=world) as third:
        start_z = third.positions_mm()["Z"]
        assert start_z > top
        with pytest.raises(SoftLimitError) as caught:
            third.jog({"Z": 1.0}, feed_mm_min=600)
        assert caught.value.axis == "Z" and caught.value.limit_mm == pytest.approx(top)
        assert "farther out than" in str(caught.value)
        report = third.jog({"Z": -5.0}, feed_mm_min=600)
        assert report.completed
        assert third.positions_mm()["Z"] == pytest.approx(start_z - 5.0, abs=1 / 240)
        third.shutdown()
    with connect_session(shorter, world=world) as mdi:
        feed = mdi.open_feed(file="<console>")
        feed.add("G91 G0 X1")
        feed.close()
        report, _ = mdi.run_feed(feed)
        assert report.completed


def test_a_run_from_beyond_the_band_must_come_back_first(near: MachineConfig) -> None:
    """After a travel made shorter (as after a limit fault or a push by hand) the machine
    stands well outside: a program that moves X first is refused naming Z and its limit,
    a jog of Z back inside is taken."""
    with connect_session(near) as session:
        session.home()
        shorter = replace(near, axes=tuple(
            replace(axis, travel_mm=(-100.0, -0.5),
                    homing=replace(axis.homing, pull_off_mm=1.5)) if axis.name == "Z"
            else axis for axis in near.axes))
        session.reconfigure(shorter)
        assert session.is_homed and session.positions_mm()["Z"] == 0.0
        with pytest.raises(SoftLimitError, match="must bring an axis that stands outside back"
                           ) as caught:
            session.prepare("x.ngc", text="G21 G90\nG0 X10\nG0 Z-5\nM2\n")
        assert (caught.value.line, caught.value.axis, caught.value.limit_mm) == (2, "Z", -0.5)
        report = session.jog({"Z": -2.0}, feed_mm_min=600)
        assert report.completed and session.positions_mm()["Z"] == pytest.approx(-2.0)


def test_a_rapid_into_the_stock_is_reported_before_and_after_the_run(
        near: MachineConfig) -> None:
    """A report, not a refusal: the warning is in the prepared program and heads the
    report's notes; the run goes."""
    program = "G21 G90\nG0 X2 Y2\nG1 Z-3 F300\nG1 X20 F900\nG1 Y20\nG0 X10 Y10\nG0 Z0\nM2\n"
    with connect_session(near) as session:
        session.home()
        prepared = session.prepare("plunge.ngc", text=program)
        assert len(prepared.warnings) == 1
        assert prepared.warnings[0].startswith("line 6: a rapid reaches work Z -3.000 mm")
        report, _ = session.run(prepared)
        assert report.completed
        assert report.notes[0] == prepared.warnings[0]
        assert f"note           {prepared.warnings[0]}" in describe(report)


def test_an_unhomed_machine_plans_where_homing_will_leave_it(config: MachineConfig) -> None:
    with connect_session(config) as session:
        prepared = session.prepare("p.ngc", text="G21 G90\nG0 X300\nM2\n", unhomed=True)
        assert not prepared.homed, "in the devices' own counts: no soft limits"
        with pytest.raises(SoftLimitError):
            session.prepare("p.ngc", text="G21 G90\nG0 X300\nM2\n")
        homed = session.prepare("p.ngc", text="G21 G90\nG0 X30\nM2\n")
        assert homed.homed and homed.start_mm == (0.0, 0.0, 0.0)
        with pytest.raises(MachineStateError, match="home it first"):
            session.run(homed)


def _stop_mid_run(session: MachineSession, at_s: float, *, twice: bool = False) -> None:
    """Ask the session to stop once the program reaches ``at_s`` (from its progress)."""
    asked = [False]

    def progress(update: Progress) -> None:
        if update.done_s >= at_s and not asked[0]:
            asked[0] = True
            session.request_stop()
            if twice:
                session.request_stop()

    report, trace = session.run(session.prepare("line.ngc", text=LINE), on_progress=progress)
    assert asked[0]
    session.last = (report, trace)  # type: ignore[attr-defined]


@pytest.mark.parametrize("stall_s", [0.02, 0.2])
def test_a_stop_that_reaches_the_devices_late_still_decelerates_in_full(
        near: MachineConfig, stall_s: float, monkeypatch: pytest.MonkeyPatch) -> None:
    """The host held up between planning the stop and sending it (20 ms: part of the 40 ms
    deceleration already past when it arrives; 200 ms: all of it): the axis runs on at speed
    until the stop arrives, then decelerates in full from there (call 50), where call 38
    would have cut the deceleration short, down to a dead stop from 20 mm/s."""
    stop = RunStreams.stop

    def held_up(streams: RunStreams, tick: int, index: int, rows: np.ndarray) -> int:
        streams.machine.clock.sleep(stall_s)
        return stop(streams, tick, index, rows)

    monkeypatch.setattr(RunStreams, "stop", held_up)
    with connect_session(near) as session:
        session.home()
        devices = _devices(session)
        _stop_mid_run(session, 3.0)
        report, _ = session.last  # type: ignore[attr-defined]
        planned = 20.0**2 / (2 * 500.0)
        run_on = 20.0 * (stall_s - STOP_LEAD_S)
        assert report.stop_planned_mm == pytest.approx(planned, rel=0.05)
        assert run_on + 0.8 * planned <= report.stop_distance_mm <= run_on + planned + 0.1, (
            "the run-on at speed, then the whole deceleration")
        x = next(axis for axis in report.axes if axis.name == "X")
        assert x.max_error_counts <= 30, "no dead stop from speed: the error stays small"
        assert any("decelerated in full" in note for note in report.notes), report.notes
        assert report.stop_late_s == pytest.approx(stall_s - STOP_LEAD_S, abs=0.002)
        print(f"stop {report.stop_late_s * 1000:.0f} ms late at 20 mm/s: {run_on:.3f} mm of"
              f" run-on, then stopped in {report.stop_distance_mm:.3f} mm in all (planned"
              f" {report.stop_planned_mm:.3f} mm), X's peak error {x.max_error_counts} counts")
        for name, device in devices.items():
            state = device.state
            assert state.enable == 1 and state.queued == 0 and state.velocity == 0, name


def test_a_stop_reaches_every_device_together_over_slow_links(near: MachineConfig) -> None:
    """Links with 2 ms each way: the stop's line goes to every device before any answer is
    read, so all three take it on one device tick (one after another, each waiting for
    its answer, they took it 4 ms apart: the last one late)."""
    slow = replace(near, axes=tuple(replace(axis, url=f"{axis.url}?latency_us=2000")
                                    for axis in near.axes))
    with connect_session(slow) as session:
        session.home()
        taken: dict[str, list[int]] = {}
        for name, device in _devices(session).items():
            feed, ticks = device.feed, taken.setdefault(name, [])

            def watched(data: bytes, feed: Any = feed, ticks: list[int] = ticks,
                        device: Device = device) -> None:
                if any(line.startswith(b"50 ") for line in bytes(data).split(b"\n")):
                    ticks.append(device.clock)
                feed(data)

            device.__dict__["feed"] = watched
        _stop_mid_run(session, 3.0)
        report, _ = session.last  # type: ignore[attr-defined]
    assert report.stop_reason == StopReason.USER.value and report.stop_late_s == 0.0
    assert all(len(ticks) == 1 for ticks in taken.values()), taken
    firsts = [ticks[0] for ticks in taken.values()]
    assert max(firsts) - min(firsts) <= 1, taken


def test_a_stop_mid_run_decelerates_along_the_path_within_v2_over_2a(
        near: MachineConfig) -> None:
    with connect_session(near) as session:
        session.home()
        devices = _devices(session)
        _stop_mid_run(session, 3.0)
        report, trace = session.last  # type: ignore[attr-defined]
        assert report.stop_reason == StopReason.USER.value and not report.completed
        assert session.state is MachineState.IDLE, "at rest: Hold ended"
        planned = 20.0**2 / (2 * 500.0)
        assert report.stop_planned_mm == pytest.approx(planned, rel=0.05)
        assert report.stop_distance_mm <= report.stop_planned_mm + 0.05, (
            "within the planned deceleration (plus the following error)")
        assert report.stop_distance_mm > 0.5 * planned, "a deceleration, not a dead stop"
        for name, device in devices.items():
            state = device.state
            assert state.enable == 1, f"{name}: still servoing at rest (no coasting)"
            assert state.queued == 0 and state.velocity == 0
            assert abs(state.desired - state.actual) <= 2
        times, desired, _ = trace.arrays("X")
        steps = np.abs(np.diff(desired)) / np.diff(times)
        assert steps.max() <= 20.0 * 240 * 1.02, "no jump in the commanded path at the stop"
        assert 3.0 <= report.stopped_at_s <= 3.5, "where it was when asked (progress is sparse)"
        session.shutdown()
        assert all(d.state.enable == 0 and d.state.fault == FaultCode.NONE
                   for d in devices.values()), "servos off, no fault latched"


def test_a_second_stop_request_stops_at_once(near: MachineConfig) -> None:
    with connect_session(near) as session:
        session.home()
        _stop_mid_run(session, 2.0, twice=True)
        report, _ = session.last  # type: ignore[attr-defined]
        assert not report.completed
        assert any("stopped every axis at once" in note for note in report.notes), report.notes
        assert all(not s.enabled for s in session.machine.status().values())


def _stop_homing_at_poll(session: MachineSession, monkeypatch: pytest.MonkeyPatch,
                         poll: int, before: Callable[[], None] = lambda: None) -> None:
    """Ask the session to stop once homing has polled ``poll`` times (``before`` first)."""
    original = device_io.DeviceHomingIO.after_poll
    polls = [0]

    def after_poll(self: device_io.DeviceHomingIO) -> None:
        original(self)
        polls[0] += 1
        if polls[0] == poll:
            before()
            session.request_stop()

    monkeypatch.setattr(device_io.DeviceHomingIO, "after_poll", after_poll)


def test_a_stop_during_homing_brings_every_axis_to_rest_unhomed(
        config: MachineConfig, monkeypatch: pytest.MonkeyPatch) -> None:
    with connect_session(config) as session:
        _stop_homing_at_poll(session, monkeypatch, 40)
        with pytest.raises(StopRequestedError, match="interrupted by the user"):
            session.home()
        assert session.state is MachineState.IDLE and not session.is_homed
        assert session.stop_latency_s < 0.1, "every axis at rest within 100 ms"
        for name, device in _devices(session).items():
            assert device.state.velocity == 0 and device.state.queued == 0, name
            assert device.state.fault == FaultCode.NONE


def test_a_stop_during_homing_sent_late_still_ramps_down(
        config: MachineConfig, monkeypatch: pytest.MonkeyPatch) -> None:
    """The host held up 40 ms before each axis's ramp to rest (longer than the ramp, shorter
    than the velocity the device holds between polls): the ramp still plays whole, late
    (call 50), where call 38 would have left the queue empty and the velocity loop braking
    from the seek speed at once."""
    stop_from = DeviceClient.stop_from

    def held_up(client: DeviceClient, tick: int, values: Sequence[int]) -> Stopped:
        client.link_clock.sleep(0.04)
        stopped = stop_from(client, tick, values)
        late.append(stopped.late)
        return stopped

    late: list[int] = []
    with connect_session(config) as session:
        _stop_homing_at_poll(session, monkeypatch, 40, before=lambda: monkeypatch.setattr(
            DeviceClient, "stop_from", held_up))
        velocities: dict[str, list[int]] = {}
        for name, device in _devices(session).items():
            run, seen = type(device).run, velocities.setdefault(name, [])

            def tick_by_tick(ticks: int, device: Device = device, run: Any = run,
                             seen: list[int] = seen) -> None:
                for _ in range(ticks):
                    run(device, 1)
                    seen.append(device.state.desired_velocity)

            device.__dict__["run"] = tick_by_tick
        world = session.machine.world
        assert world is not None
        world.run_ahead = False  # every tick seen once, at the world's time
        with pytest.raises(StopRequestedError, match="interrupted by the user"):
            session.home()
        assert late and min(late) > 0, "every stop came late"
        moving = 0
        for name in ("X", "Y", "Z"):  # Z homes first: the stop finds it seeking
            axis = config.axis(name)
            step = axis.counts_per_mm * axis.max_accel_mm_s2 * config.motion_period_s
            seen = np.array(velocities[name])
            moving += int(np.abs(seen).max() >= axis.homing.speed_mm_s * axis.counts_per_mm - 1)
            assert np.abs(np.diff(seen)).max() <= step + 1, f"{name}: a dead stop"
        assert moving, "an axis was seeking at speed when the stop came"
        for name, device in _devices(session).items():
            assert device.state.velocity == 0 and device.state.fault == FaultCode.NONE, name


def test_no_switch_within_the_search_distance_fails_naming_the_axis() -> None:
    text = default_machine().read_text().replace(
        "homing = { direction = -1, speed_mm_s = 10.0, slow_speed_mm_s = 1.0, backoff_mm = 1.0 }",
        "homing = { direction = -1, speed_mm_s = 10.0, slow_speed_mm_s = 1.0, backoff_mm = 1.0,"
        " search_mm = 20.0 }", 1)
    config = parse_config(text, path="short-search.toml")
    assert config.axis("X").homing.search_mm == 20.0
    with connect_session(config) as session:
        with pytest.raises(SequenceFaultError) as caught:
            session.home()
        assert caught.value.axis == "X"
        assert "no switch within 20 mm of the seek" in str(caught.value)
        assert session.state is MachineState.ALARM
        for name, device in _devices(session).items():
            assert device.state.velocity == 0, f"{name} brought to rest"
        session.reset()
        assert session.state is MachineState.IDLE


def test_a_second_host_finds_the_machine_homed_where_the_first_left_it(
        config: MachineConfig) -> None:
    world = SimWorld()
    with connect_session(config, world=world) as first:
        first.home()
        report, _ = first.run(first.prepare("a.ngc", text="G21 G90\nG1 X40 Y30 Z-10 F900\nM2\n"))
        assert report.completed
        first.shutdown()
    with connect_session(config, world=world) as second:
        assert second.notices == [] and second.is_homed, "no fault: the position is known"
        where = second.positions_mm()
        assert where == pytest.approx({"X": 40.0, "Y": 30.0, "Z": -10.0}, abs=3 / 240), (
            "where the axes rest, to a few counts of where the first host left them")
        prepared = second.prepare("b.ngc", text="G21 G90\nG1 X0 Y0 Z0 F900\nM2\n")
        assert prepared.start_mm == (where["X"], where["Y"], where["Z"])
        report, _ = second.run(prepared)
        assert report.completed and report.homing_time_s == 0


def test_a_run_that_cannot_start_ends_in_alarm_never_left_running(
        near: MachineConfig) -> None:
    """A device refusing to enable (a fault latched since the last command: here its
    watchdog, run out while nobody fed it): the run ends at once in Alarm, the report
    says why; the next program is refused until the machine is reset, not taken as
    started."""
    world = SimWorld()
    with connect_session(near, world=world) as session:
        session.home()
        prepared = session.prepare("line.ngc", text=LINE)
        client = session.machine.axis("Y").client
        client.set_watchdog_ms(50)
        world.advance(200_000)
        report, _ = session.run(prepared)
        assert not report.completed and "watchdog" in report.stop_reason, report.stop_reason
        assert session.state is MachineState.ALARM
        with pytest.raises(MachineStateError, match="Alarm"):
            session.run(session.prepare("line.ngc", text=LINE))


def test_a_fault_an_earlier_host_left_is_reported_cleared_and_needs_homing(
        config: MachineConfig) -> None:
    world = SimWorld()
    with connect_session(config, world=world) as first:
        first.home()
        for axis in first.machine.axes.values():
            axis.client.set_watchdog_ms(50)
    world.advance(200_000)
    with connect_session(config, world=world) as second:
        assert sorted(second.faults_found) == ["X", "Y", "Z"]
        assert all(code == FaultCode.WATCHDOG for code, _ in second.faults_found.values())
        assert len(second.notices) == 3
        assert "fault 1 (watchdog)" in second.notices[0] and "homing is required" in (
            second.notices[0])
        assert not second.is_homed
        assert all(s.fault == FaultCode.NONE for s in second.machine.status().values())


def test_motion_an_earlier_host_left_running_is_stopped_along_its_deceleration(
        near: MachineConfig) -> None:
    world = SimWorld()
    with connect_session(near, world=world) as first:
        first.home()
        client = first.machine.axis("X").client
        ramp = [round(4.8 * k * k / 400) if k < 200 else round(4.8 * (k - 100))
                for k in range(1, 1001)]
        client.add_setpoints(ramp)
    world.advance(500_000)
    device = world.device("X")
    assert isinstance(device, Device)
    moving_at = device.state.actual
    assert device.state.queued > 0 and device.state.velocity > 3000, "still running"
    with connect_session(near, world=world) as second:
        assert any("still running what an earlier host queued" in n for n in second.notices)
        state = device.state
        assert state.queued == 0 and state.velocity == 0
        travelled_mm = (state.actual - moving_at) / 240
        speed_mm_s = 4800 / 240
        assert travelled_mm <= speed_mm_s**2 / (2 * 500) + speed_mm_s * 0.05, (
            "stopped within its deceleration (plus the 20 ms it was watched)")


def test_the_console_starts_a_cycle_twice_from_where_the_machine_stands() -> None:
    done = subprocess.run(
        [sys.executable, "-m", "usbmotion", "console"], input="$d 1\n$c\n$c\n?\n$q\n",
        capture_output=True, text=True, timeout=300, check=False)
    assert done.returncode == 0, done.stdout + done.stderr
    starts = [line for line in done.stdout.splitlines() if line.startswith("cycle start:")]
    assert len(starts) == 2
    assert "from X 0.000  Y 0.000  Z 0.000 mm" in starts[0]
    assert "from X 5.000  Y 5.000  Z -5.000 mm" in starts[1], (
        "the second from where the first ended")
    assert done.stdout.count("\ndone\n") == 2
    assert "faults         none" in done.stdout


def test_usbmotion_run_refuses_a_program_beyond_the_travel_with_exit_2(tmp_path: Path) -> None:
    program = tmp_path / "far.ngc"
    program.write_text("G21 G90\nG0 X20\nG0 X300\nM2\n")
    done = subprocess.run([sys.executable, "-m", "usbmotion", "run", str(program), "-q",
                           "--no-plot"], capture_output=True, text=True, timeout=120,
                          check=False)
    assert done.returncode == 2, done.stdout + done.stderr
    assert f"{program}:3: X would reach 300.000 mm, beyond the upper end 200 mm" in (
        done.stderr)
    assert "homing" not in done.stdout and "Traceback" not in done.stderr


def test_homing_feeds_every_watchdog_however_slowly_its_polls_come(
        config: MachineConfig) -> None:
    from dataclasses import replace  # noqa: PLC0415

    from usbmotion.session.homing import HomingCycle  # noqa: PLC0415

    watched = replace(config, watchdog_ms=1250)
    with connect_session(watched) as session:
        machine = session.machine
        cycle = HomingCycle(machine, keep_alive_period_s=session.keep_alive_period_s(),
                            stop_now=lambda: False)
        cycle.enter_velocity_mode()
        for _ in range(10):  # polls 0.6 s apart (a host far behind its 50 Hz): 6 s
            machine.clock.sleep(0.6)
            cycle.io.after_poll()
        devices = _devices(session)
        assert all(d.state.enable == 1 and d.state.fault == FaultCode.NONE
                   for d in devices.values()), "no watchdog fault on any axis"
        machine.stop()


def test_homing_leaves_alarm_as_grbl_s_dollar_h_does(config: MachineConfig,
                                                     tmp_path: Path) -> None:
    """A device fault puts the machine in Alarm; homing from there clears the faults first
    and leaves it Idle and homed (grbl's $H clears an alarm), the live model with it."""
    tight = default_machine().read_text().replace(
        "following_error_limit_mm = 1.0", "following_error_limit_mm = 0.04", 1)
    path = tmp_path / "tight.toml"
    path.write_text(tight)
    with connect_session(load_config(path)) as session:
        session.home()
        report, _ = session.run(session.prepare("m.ngc", text="G1 X50 F1200\nM2\n"))
        assert not report.completed and report.faults[0].axis == "X"
        assert session.state is MachineState.ALARM and not session.homed["X"]
        assert session.live.read().state is MachineState.ALARM
        assert "axis X: following error" in session.live.read().alarm
        session.home()
        assert session.state is MachineState.IDLE and session.is_homed
        assert session.live.read().state is MachineState.IDLE


def test_a_jog_runs_at_its_own_feed_whatever_the_feed_override(near: MachineConfig) -> None:
    """grbl 1.1: the feed override does not apply to jogs (the next program gets it)."""
    with connect_session(near) as session:
        session.home()
        plain = session.jog({"X": 30.0}, feed_mm_min=600.0)
        session.set_feed_override(50)
        overridden = session.jog({"X": -30.0}, feed_mm_min=600.0)
        assert plain.completed and overridden.completed
        assert overridden.executed_time_s == pytest.approx(plain.executed_time_s, abs=0.002)
        assert session.feed_override_percent == 50, "kept for the next program"
        slower = session.run(session.prepare("p.ngc", text="G91 G1 X30 F600\nM2\n"))[0]
        assert slower.executed_time_s > 1.8 * plain.executed_time_s
