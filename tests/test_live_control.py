"""Feed hold, resume, stop and overrides in virtual time, checked on what the devices
executed (their desired position at every servo tick, :mod:`usbmotion.sim.recording`).

Tolerances, from integer setpoints: velocity is measured over 10 ticks (a count of
rounding at each end: 1 count / 10 ms, 0.42 mm/s at 240 counts/mm) and acceleration as
the second difference over 20-tick windows (2 counts / (20 ms)^2, 20.8 mm/s^2). The
planner's corners (junction deviation) change an axis's velocity within a tick, which the
windowed acceleration sees; a hold, a resume or an override may add nothing beyond the
uninterrupted program's own peak (or the axis's limit, when higher). A path is the same
when every executed point of one run is within 1.5 counts (rounding of both, on three
axes) of the polyline the other executed, both ways round.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from tests.executed import (
    AXES,
    PATH_TOLERANCE_COUNTS,
    Positions,
    at_rest_spans,
    check_limits,
    check_same_path,
    distance_to_path,
    near_the_switches,
    record,
)

import usbmotion
from usbmotion.cli.run import default_machine
from usbmotion.errors import ArgumentError
from usbmotion.host.config import MachineConfig, load_config
from usbmotion.protocol import FaultCode
from usbmotion.session import MachineSession, MachineState, StopReason
from usbmotion.session.streaming import RunStreams
from usbmotion.sim.machine import connect_session

DEMO = Path(usbmotion.__file__).parent / "data" / "demos" / "1-rounded-square.ngc"


@pytest.fixture(scope="module")
def config() -> MachineConfig:
    return near_the_switches(load_config(default_machine()))


def _run(config: MachineConfig,
         act: Callable[[MachineSession, int], None] | None = None, *,
         live: bool = True) -> tuple[MachineSession, Positions, object]:
    """Home, run the demo with ``act(session, tick)`` called on every servo tick, and
    return the session (closed), what the devices executed during the run, and the report.
    ``live``: the session's live control (requests looked at every 10 ms, else 50 ms)."""
    session, positions, report = record(
        config, lambda s: s.run(s.prepare(DEMO))[0], act, live=live)
    session.report = report  # type: ignore[attr-defined]
    return session, positions, report


@pytest.fixture(scope="module")
def reference(config: MachineConfig) -> Positions:
    _, positions, report = _run(config)
    assert report.completed  # type: ignore[attr-defined]
    return positions


@pytest.mark.parametrize("live", [True, False], ids=["live", "batch"])
def test_hold_then_resume_keeps_the_path_within_the_limits(
        config: MachineConfig, reference: Positions, live: bool) -> None:
    states: list[MachineState] = []

    def act(session: MachineSession, tick: int) -> None:
        if tick == 4000:
            session.request_hold()
        if tick == 4600:
            states.append(session.state)
            session.request_resume()

    session, positions, report = _run(config, act, live=live)
    assert states == [MachineState.HOLD]
    assert report.completed and session.final_state is MachineState.IDLE  # type: ignore[attr-defined]
    assert at_rest_spans(positions, 300), "it came to rest and stayed there"
    check_limits(config, positions, reference)
    check_same_path(positions, reference)
    assert session.last_run is not None
    ((_, _, planned_mm, distance_mm),) = session.last_run.holds
    assert distance_mm <= planned_mm + 0.05 and distance_mm > 0.5 * planned_mm


@pytest.mark.parametrize("hold_at", [4000, 9000], ids=["line", "arc"])
def test_a_hold_that_reaches_the_devices_late_resumes_on_the_path(
        config: MachineConfig, reference: Positions, hold_at: int,
        monkeypatch: pytest.MonkeyPatch) -> None:
    """The host held up 100 ms between planning the hold's stop and sending it (longer than
    the stop lasts): the axes run on along the path, decelerate in full from there, and the
    resume takes the program up where they came to rest, on the same path within the
    limits (no jump back to where the stop was planned to end)."""
    stop = RunStreams.stop

    def held_up(streams: RunStreams, tick: int, index: int, rows: np.ndarray) -> int:
        streams.machine.clock.sleep(0.1)
        return stop(streams, tick, index, rows)

    monkeypatch.setattr(RunStreams, "stop", held_up)

    def act(session: MachineSession, tick: int) -> None:
        if tick == hold_at:
            session.request_hold()
        if tick == hold_at + 700:
            session.request_resume()

    session, positions, report = _run(config, act)
    assert report.completed  # type: ignore[attr-defined]
    check_limits(config, positions, reference)
    # On the line the stop stays on the path. On the arc the stop is the planned one moved to
    # where the axes had got to, so it ends inside the curve by its length (0.39 mm) times the
    # angle the path turned meanwhile, and the resume's straight move back to the path and
    # the path differ by as much: 10 counts (0.04 mm) here.
    tolerance = PATH_TOLERANCE_COUNTS if hold_at == 4000 else 12.0
    off = distance_to_path(positions, reference)
    print(f"late hold on the {hold_at} tick: {off:.1f} counts off the path at most")
    assert off <= tolerance, "left the path"
    assert distance_to_path(reference, positions) <= tolerance, "skipped a part"
    assert np.array_equal(positions[-1], reference[-1]), "the same end position"
    travelled, planned = (float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum())
                          for p in (positions, reference))
    print(f"  travelled {travelled:.0f} counts against {planned:.0f} uninterrupted")
    assert travelled <= planned + 2 * tolerance, "nothing of the path gone over twice"
    assert session.last_run is not None
    ((_, _, planned_mm, distance_mm),) = session.last_run.holds
    assert distance_mm > planned_mm + 0.05, "the run-on, then the whole deceleration"


@pytest.mark.parametrize("resume", [False, True], ids=["start", "resume"])
def test_a_host_held_up_as_it_starts_the_axes_still_starts_them_together(
        config: MachineConfig, reference: Positions, resume: bool,
        monkeypatch: pytest.MonkeyPatch) -> None:
    """The host held up 0.4 s, twice the start's margin, between measuring the devices'
    clocks and sending the first setpoints (as it opens the streams: at the run's start, or
    at a resume after a hold): every device is held while its queue takes its first values,
    and all are armed after that, so every axis starts on the one tick. A device armed
    first started late on its own, when its values came: out of step with the others, the
    run's account of where it is wrong, and a stop planned from that account a jump (a
    following-error fault)."""
    opened = RunStreams.open

    def held_up(streams: RunStreams, rows: np.ndarray, released: int) -> None:
        opened(streams, rows, released)
        streams.machine.clock.sleep(0.4)

    monkeypatch.setattr(RunStreams, "open", held_up)

    def act(session: MachineSession, tick: int) -> None:
        if resume and tick == 4000:
            session.request_hold()
        if resume and tick == 4700:
            session.request_resume()

    _, positions, report = _run(config, act)
    assert report.completed, report  # type: ignore[attr-defined]
    check_limits(config, positions, reference)
    check_same_path(positions, reference)
    if not resume:  # every axis took its last value when the plan says (its last period)
        assert report.executed_time_s == pytest.approx(  # type: ignore[attr-defined]
            report.planned_time_s, abs=config.motion_period_s)  # type: ignore[attr-defined]


def test_a_start_armed_too_late_ends_the_run_with_every_axis_stopped(
        config: MachineConfig, monkeypatch: pytest.MonkeyPatch) -> None:
    """The host held up 0.5 s right after arming the first axis's real start, past its
    tick: that axis started alone, the others only when their arming came. The run says so
    and ends there: every queue is emptied at once (a device that had started stops taking
    values where it is, its servo holding it: no coasting), every axis at rest."""
    from usbmotion.device import Device, core1  # noqa: PLC0415
    from usbmotion.host.device import DeviceClient  # noqa: PLC0415

    armed = DeviceClient.start_at
    arms: list[int] = []

    def late(client: DeviceClient, tick: int) -> None:
        armed(client, tick)
        arms.append(tick)
        if len(arms) == len(AXES) + 1:  # the real start's first arming (the held ones first)
            client.link_clock.sleep(0.5)

    monkeypatch.setattr(DeviceClient, "start_at", late)
    with connect_session(config) as session:
        session.home()
        report, _ = session.run(session.prepare(DEMO))
        assert not report.completed
        assert "the host was held up while it armed the axes' common start" in (
            report.stop_reason), report.stop_reason
        assert "run it again" in report.stop_reason, report.stop_reason
        assert session.state is MachineState.ALARM
        world = session.machine.world
        assert world is not None
        devices = [world.device(name) for name in AXES]
        assert all(isinstance(d, Device) for d in devices)
        before = [int(d._state[core1.S_DESIRED]) for d in devices]  # type: ignore[union-attr]
        world.advance(500_000)
        states = [d._state for d in devices]  # type: ignore[union-attr]
        assert [int(s[core1.S_DESIRED]) for s in states] == before, "held where it stood"
        assert [int(s[core1.S_ENABLE]) for s in states] == [1, 1, 1], "servos on: no coasting"
        assert all(abs(int(s[core1.S_ACTUAL]) - int(s[core1.S_DESIRED])) <= 2 for s in states)
        assert [int(s[core1.S_QUEUE_COUNT]) for s in states] == [0, 0, 0], (
            "nothing left to run when the held start's tick comes")
        assert before[0] != 0, "X had started alone (the case this test is about)"


def test_a_host_held_up_longer_than_a_queue_lasts_ends_the_run_with_every_axis_held(
        config: MachineConfig, monkeypatch: pytest.MonkeyPatch) -> None:
    """The host held up 1.5 s mid-program, longer than a queue's setpoints last (at most
    1,000 of 1 ms): the queues run dry and the axes stand still. At its next refill the host
    finds a queue empty with setpoints still to send: it ends the run there, every queue
    emptied and every servo holding its axis, rather than send what follows to run late,
    each axis out of step with the others and with the run's account of it (where a stop
    planned from that account is a jump: a following-error fault)."""
    from usbmotion.device import Device, core1  # noqa: PLC0415
    from usbmotion.session.run import Run  # noqa: PLC0415

    looked = Run._look
    held = [False]

    def held_up(run: Run, *, at_once: bool = False) -> bool:
        if not held[0] and run.streams.sent > 3000:
            held[0] = True
            run.clock.sleep(1.5)
        return looked(run, at_once=at_once)

    monkeypatch.setattr(Run, "_look", held_up)
    with connect_session(config) as session:
        session.home()
        report, _ = session.run(session.prepare(DEMO))
        assert held[0] and not report.completed
        assert "motion queue ran dry" in report.stop_reason, report.stop_reason
        assert "the host fell behind it" in report.stop_reason, report.stop_reason
        assert not report.faults, "no device faulted: no jump, no following error"
        assert session.state is MachineState.ALARM
        world = session.machine.world
        assert world is not None
        devices = [world.device(name) for name in AXES]
        assert all(isinstance(d, Device) for d in devices)
        states = [d._state for d in devices]  # type: ignore[union-attr]
        before = [int(s[core1.S_DESIRED]) for s in states]
        world.advance(500_000)
        assert [int(s[core1.S_DESIRED]) for s in states] == before, "held where they stood"
        assert [int(s[core1.S_ENABLE]) for s in states] == [1, 1, 1], "servos on"
        assert [int(s[core1.S_QUEUE_COUNT]) for s in states] == [0, 0, 0]


def test_a_queue_that_ran_dry_where_its_axis_stands_still_is_taken_up_on_schedule(
        config: MachineConfig, reference: Positions, monkeypatch: pytest.MonkeyPatch) -> None:
    """Y's stream not served for 1.5 s while X cuts line 7 (X20 to X80 at Y10, 3 s): Y's
    queue runs dry where Y is to stand still anyway. The host takes it up again on schedule
    (call 38 from a row already due: the device skips what is past), so the program runs
    to its end on the same path, in its planned time, where a queue that ran dry mid-move
    ends the run (above)."""
    from usbmotion.host.stream import SetpointStream  # noqa: PLC0415

    serve = SetpointStream.service
    skipped: list[float] = []

    def late_for_y(stream: SetpointStream) -> None:
        clock = stream.client.link_clock
        if stream.client.name.startswith("Y") and stream.sent >= 2000:
            if not skipped:
                skipped.append(clock.now())
            if clock.now() < skipped[0] + 1.5:
                clock.sleep(0.01)  # held up elsewhere: time passes, Y's stream waits
                return
        serve(stream)

    monkeypatch.setattr(SetpointStream, "service", late_for_y)
    _, positions, report = _run(config)
    assert skipped, "Y's stream was held up"
    assert report.completed, report.stop_reason  # type: ignore[attr-defined]
    check_same_path(positions, reference)
    assert report.executed_time_s == pytest.approx(  # type: ignore[attr-defined]
        report.planned_time_s, abs=config.motion_period_s)  # type: ignore[attr-defined]


def test_two_holds_and_resumes_one_on_an_arc(config: MachineConfig,
                                             reference: Positions) -> None:
    def act(session: MachineSession, tick: int) -> None:
        if tick in (2500, 9000):
            session.request_hold()
        if tick in (3200, 9700):
            session.request_resume()

    session, positions, report = _run(config, act)
    assert report.completed  # type: ignore[attr-defined]
    assert session.last_run is not None and len(session.last_run.holds) == 2
    check_limits(config, positions, reference)
    check_same_path(positions, reference)


def test_stop_while_held_leaves_the_machine_homed_and_idle(config: MachineConfig,
                                                         reference: Positions) -> None:
    def act(session: MachineSession, tick: int) -> None:
        if tick == 5000:
            session.request_hold()
        if tick == 5600:
            session.request_stop()

    session, positions, report = _run(config, act)
    assert not report.completed and report.stop_reason == StopReason.USER.value  # type: ignore[attr-defined]
    assert session.final_state is MachineState.IDLE and session.is_homed  # type: ignore[attr-defined]
    check_limits(config, positions, reference)
    assert distance_to_path(positions, reference) <= PATH_TOLERANCE_COUNTS


def test_stop_while_running_decelerates_along_the_path(config: MachineConfig,
                                                      reference: Positions) -> None:
    def act(session: MachineSession, tick: int) -> None:
        if tick == 6000:
            session.request_stop()

    session, positions, report = _run(config, act)
    assert not report.completed and session.final_state is MachineState.IDLE  # type: ignore[attr-defined]
    assert session.is_homed
    check_limits(config, positions, reference)
    assert distance_to_path(positions, reference) <= PATH_TOLERANCE_COUNTS
    with connect_session(config) as again:
        assert all(s.fault == FaultCode.NONE for s in again.machine.status().values())


@pytest.mark.parametrize(("feed", "rapid"), [(50, 100), (200, 100), (100, 25)])
def test_an_override_keeps_the_path_and_the_limits(config: MachineConfig, reference: Positions,
                                                  feed: int, rapid: int) -> None:
    def act(session: MachineSession, tick: int) -> None:
        if tick == 3000:
            session.set_feed_override(feed)
            session.set_rapid_override(rapid)
        if tick == 12000 and feed == 10:
            session.set_feed_override(150)

    session, positions, report = _run(config, act)
    assert report.completed  # type: ignore[attr-defined]
    assert session.last_run is not None and session.last_run.seams
    check_limits(config, positions, reference)
    check_same_path(positions, reference)
    longer = positions.shape[0] > reference.shape[0]
    assert longer == (feed < 100 or rapid < 100 or feed == 10)


def test_override_values_outside_their_range_are_refused(config: MachineConfig) -> None:
    with connect_session(config) as session:
        session.live_control = True
        for bad in (9, 201, 0, 50.5, True):
            with pytest.raises(ArgumentError, match=r"feed override .* 10 \.\. 200"):
                session.set_feed_override(bad)  # type: ignore[arg-type]
        for bad in (75, 0, 200):
            with pytest.raises(ArgumentError, match=r"rapid override 75|rapid override 0|"
                               r"rapid override 200"):
                session.set_rapid_override(bad)
        assert session.feed_override_percent == 100 and session.rapid_override_percent == 100


@pytest.mark.parametrize("realtime", [False, True], ids=["virtual", "realtime"])
def test_a_run_against_the_wall_clock_keeps_more_of_its_queue(config: MachineConfig,
                                                               realtime: bool) -> None:
    """Against the wall clock a run refills a queue once 0.6 s of setpoints are left (a host
    or a link held up that long still finds it running), in virtual time at 0.3 s (its
    devices wait for it: batches of 600, half the exchanges)."""
    from usbmotion.sim.world import SimWorld  # noqa: PLC0415

    with connect_session(config, world=SimWorld(realtime=realtime)) as session:
        streams = RunStreams(session.machine, ["X", "Y"], period_s=config.motion_period_s,
                             scalar=1)
        streams.open(np.zeros((10, 2), dtype=np.int32), 10)
        marks = {(s.low_water, s.high_water) for s in streams.streams.values()}
    assert marks == ({(600, 950)} if realtime else {(300, 900)})
