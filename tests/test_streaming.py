"""A program streamed line by line (session.feed), and program pauses (M0, M1, M6), in
virtual time, checked on what the devices executed (tests.executed's invariants)."""

from __future__ import annotations

import queue
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest
from tests.executed import (
    AXES,
    Positions,
    TickAction,
    at_rest_spans,
    check_limits,
    check_same_path,
    distance_to_path,
    near_the_switches,
    record,
)
from tests.programs.engraving import engraving

import usbmotion
import usbmotion.session.feed as feed_module
from usbmotion.cli.run import default_machine
from usbmotion.errors import GCodeError, MachineStateError, SoftLimitError
from usbmotion.host.config import MachineConfig, load_config
from usbmotion.session import MachineSession, MachineState
from usbmotion.session.feed import ProgramFeed
from usbmotion.session.operator import IdleReader, Operator
from usbmotion.session.planning import plan_gcode
from usbmotion.session.report import RunReport
from usbmotion.sim.machine import connect_session
from usbmotion.sim.recording import ExecutedRecorder

DEMO = Path(usbmotion.__file__).parent / "data" / "demos" / "1-rounded-square.ngc"
SHORT = """G21 G90 G17
G0 X10 Y10 Z-5
G1 X60 Y10 F3000
G1 X60 Y50
G2 X40 Y70 I-20 J0
G1 X10 Y70
G0 Z0
"""


@pytest.fixture(scope="module")
def config() -> MachineConfig:
    return near_the_switches(load_config(default_machine()))


def _record(config: MachineConfig, go: Callable[[MachineSession], RunReport],
            act: TickAction | None = None) -> tuple[MachineSession, Positions, RunReport]:
    return record(config, go, act)


def _whole(path: Path | None = None, text: str | None = None, **kwargs: object,
           ) -> Callable[[MachineSession], RunReport]:
    def go(session: MachineSession) -> RunReport:
        source = path if path is not None else Path("<text>")
        return session.run(session.prepare(source, text=text, **kwargs))[0]  # type: ignore[arg-type]
    return go


def _fed(lines: Iterator[str], file: str = "<stream>") -> Callable[[MachineSession], RunReport]:
    def go(session: MachineSession) -> RunReport:
        return session.run_feed(session.open_feed(file=file, source=lines))[0]
    return go


@pytest.fixture(scope="module")
def short_reference(config: MachineConfig) -> Positions:
    """What the devices executed for SHORT, planned whole."""
    return _record(config, _whole(text=SHORT + "M2\n"))[1]


@pytest.fixture(scope="module")
def demo_reference(config: MachineConfig) -> tuple[Positions, RunReport]:
    _, positions, report = _record(config, _whole(DEMO))
    return positions, report


def test_a_file_read_line_by_line_runs_as_its_whole_plan(
        config: MachineConfig, demo_reference: tuple[Positions, RunReport],
        monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(feed_module, "PULL_MOVES", 3)
    reference, whole = demo_reference
    session, positions, report = _record(
        config, _fed(iter(DEMO.read_text().splitlines()), str(DEMO)))
    assert report.completed and session.final_state is MachineState.IDLE  # type: ignore[attr-defined]
    assert session.last_run is not None and len(session.last_run.legs.legs) > 3, "joined as it read"
    assert abs(report.executed_time_s - whole.executed_time_s) <= 0.005 * whole.executed_time_s
    check_limits(config, positions, reference)
    check_same_path(positions, reference)
    assert [a.max_error_counts for a in report.axes] == [a.max_error_counts
                                                         for a in whole.axes]


def test_a_checker_of_the_path_sees_a_line_left_out(
        config: MachineConfig, demo_reference: tuple[Positions, RunReport]) -> None:
    reference, _ = demo_reference
    lines = DEMO.read_text().splitlines()
    moving = [i for i, line in enumerate(lines) if line.startswith(("G1", "G2", "G3"))]
    del lines[moving[3]]
    _, positions, _ = _record(config, _fed(iter(lines)))
    assert distance_to_path(reference, positions) > 10, "the path without a line differs"


def test_lines_written_while_it_runs_late_ones_included(config: MachineConfig) -> None:
    """A front writes the lines as the machine moves: one comes while the machine already
    decelerates to the end of what it has (the queued future is replaced, call 38); once
    it has played out all it was given the run ends (Idle) and a later line needs a new
    feed."""
    lines = SHORT.splitlines()
    _, reference, _ = _record(config, _whole(text="\n".join(lines[:6]) + "\nM2\n"))
    written: list[bool] = []
    feeds: list[ProgramFeed] = []

    def go(session: MachineSession) -> RunReport:
        feed = session.open_feed(file="<front>")
        feeds.append(feed)
        for text in lines[:3]:
            assert feed.add(text)
        return session.run_feed(feed)[0]

    ticks_per_s = round(1 / config.servo_period_s)
    _, part = plan_gcode(config, "\n".join(lines[:5]) + "\nM2\n")
    late_s = part.duration_s - 0.06
    schedule = {round(at_s * ticks_per_s): text
                for at_s, text in ((0.04, lines[3]), (0.25, lines[4]), (late_s, lines[5]))}

    def act(session: MachineSession, tick: int) -> None:
        text = schedule.get(tick)
        if text is not None:
            written.append(feeds[0].add(text))

    session, positions, report = _record(config, go, act)
    assert written == [True, True, True] and report.completed
    assert session.last_run is not None and len(session.last_run.legs.legs) >= 3
    assert session.final_state is MachineState.IDLE  # type: ignore[attr-defined]
    check_limits(config, positions, reference)
    check_same_path(positions, reference)
    assert feeds[0].closed and not feeds[0].add("G0 X0"), "a played-out feed takes no line"


def test_a_bad_line_is_refused_and_nothing_else_changes(config: MachineConfig) -> None:
    with connect_session(config) as session:
        session.home()
        feed = session.open_feed(file="<front>")
        assert feed.add("G0 X10 Y10")
        with pytest.raises(GCodeError) as bad:
            feed.add("G1 X20 Y")
        assert bad.value.line == 2 and "Y" in str(bad.value)
        with pytest.raises(SoftLimitError) as beyond:
            feed.add("G0 X900")
        assert beyond.value.line == 3 and "X" in str(beyond.value)
        assert feed.add("G1 X20 F600")
        moves = feed.snapshot().moves
        assert [move.line for move in moves] == [1, 4]
        report, _ = session.run_feed(feed)
        assert report.completed
        assert session.positions_mm()["X"] == pytest.approx(20.0, abs=0.01)
        session.shutdown()


def test_a_full_window_says_so_and_takes_the_line_later(config: MachineConfig) -> None:
    with connect_session(config) as session:
        session.home()
        feed = session.open_feed(file="<front>", window=2)
        assert feed.add("G0 X10") and feed.add("G0 X20")
        assert feed.blocks_free == 0 and not feed.add("G0 X30")
        assert len(feed.snapshot().moves) == 2, "the refused line added nothing"
        feed.executed(1)
        assert feed.blocks_free == 1 and feed.add("G0 X30")
        session.shutdown()


def test_the_operator_is_busy_from_queueing_an_action_to_its_end(config: MachineConfig) -> None:
    """Between the worker taking an action and starting it, the operator is busy: a front
    that acknowledged a line never reports Idle before the line's motion starts."""
    taken = threading.Event()
    release = threading.Event()

    class SlowQueue(queue.Queue[object]):
        def get(self, block: bool = True, timeout: float | None = None) -> object:
            item = super().get(block, timeout)
            taken.set()
            release.wait(5)  # the worker preempted right after taking the action
            return item

    with connect_session(config) as session:
        operator = Operator(session)
        try:
            waiting = operator._actions
            operator._actions = SlowQueue()  # type: ignore[assignment]
            operator._pending += 1
            waiting.put((lambda: None, None))  # wakes the worker: it waits on the slow queue next
            release.set()
            assert operator.wait_idle(5)
            taken.clear()
            release.clear()
            operator.do(lambda: None)
            assert taken.wait(5)
            assert operator.busy, "idle between taking the action and running it"
            release.set()
            assert operator.wait_idle(5) and not operator.busy
        finally:
            release.set()
            operator.close()


def test_a_front_thread_never_talks_to_a_device(config: MachineConfig) -> None:
    """Only the worker and the idle keep-alive exchange lines with the devices: a front that
    submits lines (opening a feed, restarting a closed one) while an idle reader reads the
    devices on a thread of its own never shares a link with it (two threads on one link
    take each other's answers)."""
    with connect_session(config) as session:
        session.home()
        with Operator(session) as operator:
            callers: set[str] = set()
            for axis in session.machine.axes.values():
                query = axis.client.query

                def recorded(*args: object, _query: Callable[..., object] = query) -> object:
                    callers.add(threading.current_thread().name)
                    return _query(*args)

                axis.client.query = recorded  # type: ignore[method-assign]
            reader = IdleReader(operator, on_error=lambda error: None, name="reader",
                                period_s=0.002)
            reader.start()
            try:
                for line in ("G21 G90", "G0 X2", "G0 X3"):
                    while not operator.submit(line):
                        time.sleep(0.001)
                    assert operator.wait_idle(60)
                    time.sleep(0.02)
                operator.feed = None  # a new feed, from where the machine stands
                assert operator.submit("G0 X4") and operator.wait_idle(60)
            finally:
                reader.close()
            assert operator.status().machine_mm()["X"] == pytest.approx(4.0, abs=0.01)
        assert callers == {"usbmotion-operator", "reader"}, \
            f"the devices were read on {sorted(callers)}"
        session.shutdown()


def test_a_source_line_that_fails_ends_the_run_there(config: MachineConfig) -> None:
    text = "G0 X10 Y10\nG1 X30 F1200\nG1 Y\nG1 X40\n"
    _, positions, report = _record(config, _fed(iter(text.splitlines()), "bad.ngc"))
    assert not report.completed and report.stop_reason.startswith("error: bad.ngc:3")
    counts = config.axis("X").counts_per_mm
    assert positions[-1][0] == round(30 * counts), "ran up to the line before"


def test_a_feed_needs_a_homed_machine(config: MachineConfig) -> None:
    with connect_session(config) as session, pytest.raises(MachineStateError, match="home"):
        session.open_feed()


def test_m0_pauses_until_cycle_start_on_the_same_path(config: MachineConfig,
                                                     short_reference: Positions) -> None:
    """In a fed program; a file's pauses are the same pauses (the M1 and M6 test reads
    one)."""
    paused_text = SHORT.replace("G1 X60 Y50\n", "G1 X60 Y50\nM0\n") + "M2\n"
    reference = short_reference
    seen: list[tuple[MachineState, str]] = []

    def act(session: MachineSession, tick: int) -> None:
        if session.paused is not None and not seen:
            seen.append((session.state, session.paused.code))
            at[0] = tick
        if at[0] and tick == at[0] + 400:
            now = session.live.read()
            shown.append((now.line, now.lines_done))
        if at[0] and tick == at[0] + 800:
            session.request_resume()

    at = [0]
    shown: list[tuple[int, int]] = []
    go = _fed(iter(paused_text.splitlines()))
    session, positions, report = _record(config, go, act)
    assert seen == [(MachineState.PAUSED, "M0")]
    assert shown == [(5, 4)], "the live model's line at the pause is the M0's"
    assert report.completed and session.paused is None
    assert session.last_run is not None and [p.line for p in session.last_run.paused] == [5]
    spans = at_rest_spans(positions, 700)
    assert spans, "it waited at rest"
    counts = config.axis("X").counts_per_mm
    start, _ = spans[0]
    assert tuple(positions[start][:2]) == (round(60 * counts), round(50 * counts))
    check_limits(config, positions, reference)
    check_same_path(positions, reference)


def test_m1_pauses_only_with_optional_stop_and_m6_names_the_tool(config: MachineConfig) -> None:
    text = "G0 X10 Y10\nM1\nG0 X20\nT4 M6\nG0 X30\nM2\n"
    messages: list[str] = []

    def act(session: MachineSession, tick: int) -> None:
        pause = session.paused
        if pause is not None and (not messages or messages[-1] != pause.message):
            messages.append(pause.message)
            session.request_resume()

    def run(optional: bool) -> RunReport:
        def go(session: MachineSession) -> RunReport:
            session.optional_stop = optional
            return session.run(session.prepare("p.ngc", text=text,
                                               pauses=session.pause_rule()))[0]
        return _record(config, go, act)[2]

    assert run(False).completed
    assert len(messages) == 1 and "tool 4" in messages[0]
    messages.clear()
    assert run(True).completed
    assert [m.split(" ")[0] for m in messages] == ["optional", "tool"]


def test_a_hold_and_resume_in_a_fed_program_keeps_the_path(
        config: MachineConfig, demo_reference: tuple[Positions, RunReport],
        monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(feed_module, "PULL_MOVES", 3)
    reference, _ = demo_reference

    def act(session: MachineSession, tick: int) -> None:
        if tick == 6000:
            session.request_hold()
        if tick == 6700:
            session.request_resume()
        if tick == 9000:
            session.set_feed_override(150)

    session, positions, report = _record(
        config, _fed(iter(DEMO.read_text().splitlines())), act)
    assert report.completed and session.last_run is not None
    assert len(session.last_run.holds) == 1 and len(session.last_run.seams) == 1
    check_limits(config, positions, reference)
    check_same_path(positions, reference)


def test_jogs_incremental_and_continuous_and_cancelled(config: MachineConfig) -> None:
    counts = config.axis("X").counts_per_mm
    ticks_per_s = round(1 / config.servo_period_s)

    def go(session: MachineSession) -> RunReport:
        first = session.jog({"X": 10.0, "Y": 5.0}, feed_mm_min=600)
        assert first.completed and session.positions_mm()["X"] == pytest.approx(10.0)
        with pytest.raises(SoftLimitError):
            session.jog({"X": -50.0}, feed_mm_min=600)
        return session.jog({"X": 1.0}, feed_mm_min=1200, continuous=True)

    cancel_tick = [0]

    def act(session: MachineSession, tick: int) -> None:
        run = session.last_run
        continuous = run is not None and run.prepared.plan.end[0] > 100
        if session.jogging and continuous and tick > 3 * ticks_per_s and not cancel_tick[0]:
            cancel_tick[0] = tick
            session.request_jog_cancel()

    session, positions, report = _record(config, go, act)
    assert cancel_tick[0] and report.stop_reason == "jog cancelled" and not report.completed
    assert session.final_state is MachineState.IDLE and session.is_homed  # type: ignore[attr-defined]
    assert not session.stop_requested, "a cancelled jog leaves no stop request behind"
    assert 10 * counts < positions[-1][0] < 200 * counts, "it stopped short of the limit"
    check_limits(config, positions, positions)
    assert report.stop_distance_mm <= report.stop_planned_mm + 0.05


def test_a_continuous_jog_stops_at_the_soft_limit(config: MachineConfig) -> None:
    def go(session: MachineSession) -> RunReport:
        return session.jog({"Z": -1.0}, feed_mm_min=1200, continuous=True)

    _, positions, report = _record(config, go)
    lower, _ = config.axis("Z").travel_mm  # down from the top, where homing leaves Z
    assert report.completed
    assert positions[-1][2] == round(lower * config.axis("Z").counts_per_mm)


def test_the_operator_runs_mdi_lines_with_their_modal_state(config: MachineConfig) -> None:
    with connect_session(config) as session:
        session.home()
        messages: list[str] = []
        world = session.machine.world
        assert world is not None
        with Operator(session, on_message=messages.append) as operator, \
                ExecutedRecorder(world, AXES) as recorder:
            for line in ("G21 G90", "G0 X10 Y10", "G91", "G1 X5 F600", "G0 Z-2"):
                assert operator.submit(line)
            assert operator.wait_idle(60)
            positions = recorder.positions()
            check_limits(config, positions, positions)
            counts = config.axis("X").counts_per_mm
            assert positions[-1].tolist() == [round(15 * counts), round(10 * counts),
                                              round(-2 * counts)]
            with pytest.raises(GCodeError):
                operator.submit("G1 X")
            deadline = 0
            while not operator.submit("G0 X-5"):
                deadline += 1
                assert deadline < 1000
            assert operator.wait_idle(60)
            where = operator.status().machine_mm()
        assert where["X"] == pytest.approx(10.0, abs=0.01), "the encoder, within 2 counts"
        assert (where["Y"], where["Z"]) == (pytest.approx(10.0, abs=0.01),
                                            pytest.approx(-2.0, abs=0.01))
        assert not [m for m in messages if m.startswith("error")]
        session.shutdown()


@contextmanager
def _operated(config: MachineConfig) -> Iterator[tuple[MachineSession, Operator,
                                                       ExecutedRecorder, list[int]]]:
    """A homed machine, its operator and a recorder of what the devices execute; the list
    counts the runs the operator starts."""
    with connect_session(config) as session:
        session.home()
        world = session.machine.world
        assert world is not None
        runs: list[int] = []
        run_feed = session.run_feed

        def counted(*args: object, **kwargs: object) -> object:
            runs.append(1)
            return run_feed(*args, **kwargs)  # type: ignore[arg-type]

        session.run_feed = counted  # type: ignore[method-assign]
        with Operator(session) as operator, ExecutedRecorder(world, AXES) as recorder:
            yield session, operator, recorder, runs
        session.shutdown()


def _counts(config: MachineConfig, *mm: float) -> list[int]:
    return [round(value * config.axis(axis).counts_per_mm) for axis, value in zip(
        AXES, mm, strict=True)]


def test_a_hold_asked_while_idle_holds_the_next_lines_until_cycle_start(
        config: MachineConfig) -> None:
    """grbl's latch: ``!`` at rest shows Hold, lines written then wait (nothing moves, the
    window fills as it would), and ``~`` runs them as one program."""
    with _operated(config) as (session, operator, recorder, runs):
        operator.hold()
        assert operator.hold_pending and operator.status().hold_pending
        for line in ("G21 G90", "G0 X10 Y10", "G1 X30 F3000", "G1 Y20"):
            assert operator.submit(line)
        time.sleep(0.3)
        assert not operator.busy and runs == [], "nothing runs while held"
        assert operator.status().hold_pending and session.state is MachineState.IDLE
        moved = recorder.positions()
        assert len(moved) == 0 or (moved == moved[0]).all()
        operator.resume()
        assert operator.wait_idle(60)
        assert not operator.hold_pending and operator.status().state is MachineState.IDLE
        assert runs == [1] and operator.last_report is not None
        assert operator.last_report.completed
        assert recorder.positions()[-1].tolist() == _counts(config, 30, 20, 0)
        assert session.state is MachineState.IDLE


def test_a_hold_between_two_runs_holds_the_second(config: MachineConfig) -> None:
    """A program that played out its lines has ended its run; a ``!`` before the next line
    comes is kept, and that line waits for ``~``."""
    with _operated(config) as (_, operator, recorder, runs):
        assert operator.submit("G0 X5")
        assert operator.wait_idle(60) and runs == [1]
        operator.hold()
        assert operator.submit("G0 X15")
        time.sleep(0.2)
        assert runs == [1] and recorder.positions()[-1].tolist() == _counts(config, 5, 0, 0)
        operator.resume()
        assert operator.wait_idle(60) and runs == [1, 1]
        assert recorder.positions()[-1].tolist() == _counts(config, 15, 0, 0)


def test_a_reset_while_held_drops_the_lines_that_waited(config: MachineConfig) -> None:
    with _operated(config) as (_, operator, recorder, runs):
        operator.hold()
        assert operator.submit("G0 X10")
        operator.drop_held()
        assert not operator.hold_pending and operator.status().state is MachineState.IDLE
        operator.resume()
        assert operator.submit("G0 Y4")
        assert operator.wait_idle(60) and runs == [1]
        assert recorder.positions()[-1].tolist() == _counts(config, 0, 4, 0)


def test_a_run_waits_for_lines_its_front_says_are_coming(config: MachineConfig) -> None:
    """While the front says lines are on their way (a sender's receive buffer), a run that
    played out what it has stays, at rest, and takes them: one run, not one per gap."""
    with _operated(config) as (_, operator, recorder, runs):
        coming = [True]
        operator.lines_waiting = lambda: coming[0]
        assert operator.submit("G0 X5")
        deadline = time.monotonic() + 30
        while recorder.positions()[-1:].tolist() != [_counts(config, 5, 0, 0)]:
            assert time.monotonic() < deadline
            time.sleep(0.01)
        time.sleep(0.1)
        assert operator.busy and runs == [1], "the run waits"
        assert operator.submit("G0 X12")
        coming[0] = False
        assert operator.wait_idle(60) and runs == [1]
        assert operator.last_report is not None and operator.last_report.completed
        assert recorder.positions()[-1].tolist() == _counts(config, 12, 0, 0)


def test_a_sender_streaming_short_moves_runs_the_whole_path(config: MachineConfig) -> None:
    """A sender streaming an engraving of short moves, every line the moment the feed has
    room: the devices execute the program's own path, with no jump and no fault, in the
    time of the whole program's plan."""
    lines = engraving(700, seed=3)
    _, reference, whole = _record(config, _whole(text="\n".join(lines) + "\n"))
    feeds: list[ProgramFeed] = []
    waiting = list(reversed(lines))

    def go(session: MachineSession) -> RunReport:
        feed = session.open_feed(file="<sender>")
        feeds.append(feed)
        return session.run_feed(feed)[0] if act(session, 0) is None else whole

    def act(session: MachineSession, tick: int) -> None:
        while waiting and feeds[0].add(waiting[-1]):
            waiting.pop()

    _, positions, report = _record(config, go, act)
    assert not waiting and report.completed, report.stop_reason
    check_limits(config, positions, reference)
    check_same_path(positions, reference)
    assert abs(report.executed_time_s - whole.executed_time_s) <= 0.01 * whole.executed_time_s
