"""Automation sequences against dummy inputs and outputs: seed 002's tests and more."""

from __future__ import annotations

from dataclasses import dataclass, field

import pytest

from usbmotion.automation import (
    All,
    Chain,
    Complete,
    Failure,
    FailureKind,
    Home,
    Incomplete,
    LimitSwitchState,
    MoveAxisHome,
    SwitchEdgeReading,
    Transition,
    run_sequence,
)
from usbmotion.errors import ArgumentError, SequenceFaultError, StopRequestedError


@dataclass
class Carriage:
    """One axis in the homing orientation: a carriage that moves at the commanded velocity
    (no ramp), a switch closed at and below ``switch_mm``, and the device's edge latch."""

    position_mm: float
    switch_mm: float = 0.0
    velocity_mm_s: float = 0.0
    edges: int = 0
    edge_closed: bool = False
    edge_mm: float = 0.0
    stuck: bool = False
    """The switch never opens (a welded contact)."""
    upper_mm: float = 1e9

    @property
    def closed(self) -> bool:
        return self.stuck or self.position_mm <= self.switch_mm

    def advance(self, dt: float) -> None:
        before = self.closed
        self.position_mm += self.velocity_mm_s * dt
        if self.closed != before:
            self.edges += 1
            self.edge_closed = self.closed
            self.edge_mm = self.switch_mm if self.closed else self.position_mm


@dataclass
class Bench:
    """Homing inputs and outputs over carriages, advanced ``dt`` per poll."""

    carriages: dict[str, Carriage]
    dt: float = 0.02
    commands: list[tuple[str, float]] = field(default_factory=list)
    zeroed: list[tuple[str, float, float]] = field(default_factory=list)
    moving: dict[str, float] = field(default_factory=dict)
    """Axis -> where a planned pull-off is going."""

    def limit_switches(self, axis: str) -> LimitSwitchState | None:
        carriage = self.carriages.get(axis)
        if carriage is None:
            return None
        return LimitSwitchState(carriage.closed, carriage.position_mm >= carriage.upper_mm)

    def position_mm(self, axis: str) -> float:
        return self.carriages[axis].position_mm

    def switch_edge(self, axis: str) -> SwitchEdgeReading:
        c = self.carriages[axis]
        return SwitchEdgeReading(c.edges, c.edge_closed, c.edge_mm)

    def at_rest(self, axis: str) -> bool:
        return self.carriages[axis].velocity_mm_s == 0 and axis not in self.moving

    def set_target_velocity(self, axis: str, velocity_mm_s: float) -> None:
        self.commands.append((axis, velocity_mm_s))
        self.carriages[axis].velocity_mm_s = velocity_mm_s

    def zero_and_pull_off(self, axis: str, edge: SwitchEdgeReading, pull_off_mm: float) -> None:
        self.zeroed.append((axis, edge.position_mm, pull_off_mm))
        self.moving[axis] = edge.position_mm + pull_off_mm

    def step(self) -> None:
        for name, carriage in self.carriages.items():
            carriage.advance(self.dt)
            if name in self.moving:
                before = carriage.closed
                carriage.position_mm = self.moving.pop(name)
                if carriage.closed != before:
                    carriage.edges += 1
                    carriage.edge_closed = carriage.closed
                    carriage.edge_mm = carriage.position_mm

    def run(self, sequence: MoveAxisHome | Home, *, polls: int = 100_000) -> Transition:
        for _ in range(polls):
            result = sequence.poll(self, self)
            if result is not Incomplete:
                return result
            self.step()
        raise AssertionError("homing did not finish")


def test_polling_without_hitting_limits_makes_an_axis_move_backwards() -> None:
    bench = Bench({"7": Carriage(50.0)})
    seq = MoveAxisHome("7", 100.0)
    assert seq.poll(bench, bench) is Incomplete
    assert bench.commands == [("7", -100.0)]
    assert seq.phase == "seek"


def test_actuating_the_upper_limit_is_a_fault() -> None:
    bench = Bench({"7": Carriage(50.0, upper_mm=40.0)})
    seq = MoveAxisHome("7", 100.0)
    assert seq.poll(bench, bench) == Failure.unexpected_upper_limit("7")
    assert bench.commands[-1] == ("7", 0.0)


def test_the_seeds_sequence_zeroes_on_the_seek_edge_without_a_back_off() -> None:
    bench = Bench({"X": Carriage(3.0)})
    assert bench.run(MoveAxisHome("X", 10.0)) is Complete
    assert bench.zeroed == [("X", 0.0, 0.0)]
    assert ("X", 0.0) in bench.commands, "stopped on the switch first"


def test_homing_an_axis_that_does_not_exist_is_a_fault() -> None:
    seq = MoveAxisHome("9", 100.0)
    bench = Bench({})
    assert seq.poll(bench, bench) == Failure.axis_not_found("9")


def test_grbls_cycle_seek_back_off_locate_pull_off() -> None:
    bench = Bench({"X": Carriage(5.0)})
    seq = MoveAxisHome("X", 20.0, slow_speed_mm_s=2.0, backoff_mm=1.0, pull_off_mm=1.0)
    phases: list[str] = []
    for _ in range(10_000):
        result = seq.poll(bench, bench)
        if not phases or phases[-1] != seq.phase:
            phases.append(seq.phase)
        if result is not Incomplete:
            break
        bench.step()
    assert result is Complete
    assert phases == ["seek", "seek stop", "back off", "back-off stop", "locate", "locate stop",
                      "pull off", "done"]
    speeds = [v for _, v in bench.commands]
    assert speeds[0] == -20.0 and 2.0 in speeds and -2.0 in speeds, "slow back off and locate"
    (zero,) = bench.zeroed
    assert zero == ("X", 0.0, 1.0), "zeroed on the locate edge the device latched"
    assert seq.reference is not None and seq.reference.closed
    carriage = bench.carriages["X"]
    assert carriage.position_mm == 1.0 and not carriage.closed


def test_no_switch_within_the_search_distance_is_a_fault_naming_it() -> None:
    bench = Bench({"X": Carriage(50.0, switch_mm=-1e6)})
    result = bench.run(MoveAxisHome("X", 10.0, search_mm=30.0))
    assert isinstance(result, Failure)
    assert result.kind is FailureKind.SWITCH_NOT_FOUND
    assert result.axis == "X" and "within 30 mm" in result.detail
    assert bench.commands[-1] == ("X", 0.0), "the axis is stopped"
    assert 30.0 < 50.0 - bench.carriages["X"].position_mm < 30.5


def test_a_switch_that_never_opens_is_a_fault() -> None:
    bench = Bench({"X": Carriage(0.0, stuck=True)})
    result = bench.run(MoveAxisHome("X", 20.0, backoff_mm=1.0))
    assert isinstance(result, Failure)
    assert result.kind is FailureKind.LIMIT_NOT_RELEASED
    assert bench.commands[-1] == ("X", 0.0)


def test_a_switch_still_closed_after_the_pull_off_is_a_fault() -> None:
    bench = Bench({"X": Carriage(4.0)})
    seq = MoveAxisHome("X", 20.0, pull_off_mm=1.0)
    for _ in range(10_000):
        result = seq.poll(bench, bench)
        if seq.phase == "pull off":
            bench.carriages["X"].stuck = True
        if result is not Incomplete:
            break
        bench.step()
    assert isinstance(result, Failure)
    assert result.kind is FailureKind.LIMIT_NOT_RELEASED
    assert "after homing" in result.detail


def test_a_stop_brings_the_axis_to_rest_and_ends_the_sequence() -> None:
    bench = Bench({"X": Carriage(40.0)})
    seq = MoveAxisHome("X", 20.0)
    assert seq.poll(bench, bench) is Incomplete
    seq.stop(bench)
    assert bench.commands[-1] == ("X", 0.0)
    assert seq.poll(bench, bench) is Complete


class Script:
    """A sequence that answers a scripted list of transitions and records its polls."""

    def __init__(self, name: str, answers: list[Transition], log: list[str]) -> None:
        self.name, self.answers, self.log = name, list(answers), log
        self.stopped = False

    def poll(self, inputs: object, outputs: object) -> Transition:
        self.log.append(self.name)
        return self.answers.pop(0)

    def stop(self, outputs: object) -> None:
        self.stopped = True


def test_all_polls_every_live_child_and_completes_when_all_have() -> None:
    log: list[str] = []
    a = Script("a", [Incomplete, Complete], log)
    b = Script("b", [Complete], log)
    c = Script("c", [Incomplete, Incomplete, Complete], log)
    seq = All([a, b, c])
    assert seq.poll(None, None) is Incomplete
    assert log == ["a", "b", "c"]
    assert seq.poll(None, None) is Incomplete
    assert log[3:] == ["a", "c"], "completed children are not polled again"
    assert seq.poll(None, None) is Complete
    assert log[5:] == ["c"]


def test_all_first_fault_wins_and_stops_the_rest() -> None:
    log: list[str] = []
    fault = Failure(FailureKind.DEVICE, "Y", "following error")
    a = Script("a", [Incomplete, Incomplete], log)
    b = Script("b", [fault], log)
    c = Script("c", [Incomplete], log)
    seq = All([a, b, c])
    assert seq.poll(None, None) == fault
    assert log == ["a", "b"], "children after the fault are not polled"
    assert a.stopped and c.stopped
    assert seq.poll(None, None) is Complete


def test_chain_runs_one_after_another_and_stops_at_a_fault() -> None:
    log: list[str] = []
    a = Script("a", [Incomplete, Complete], log)
    b = Script("b", [Complete], log)
    seq = Chain([a, b])
    assert seq.poll(None, None) is Incomplete
    assert log == ["a"]
    assert seq.poll(None, None) is Complete
    assert log == ["a", "a", "b"], "a completed child hands over in the same poll"
    fault = Failure(FailureKind.DEVICE, "Z")
    log.clear()
    c = Script("c", [fault], log)
    d = Script("d", [Complete], log)
    chain = Chain([c, d])
    assert chain.poll(None, None) == fault
    assert chain.poll(None, None) is Complete
    assert log == ["c"], "nothing runs after a fault"


def test_home_in_order_z_first() -> None:
    bench = Bench({n: Carriage(2.0) for n in "XYZ"})
    home = Home("XYZ", lambda n: MoveAxisHome(n, 10.0), order=["Z", ["X", "Y"]])
    assert home.poll(bench, bench) is Incomplete
    assert bench.commands == [("Z", -10.0)], "Z homes alone first"
    assert bench.run(home) is Complete
    assert [axis for axis, _, _ in bench.zeroed] == ["Z", "X", "Y"]
    first_x = next(i for i, (axis, _) in enumerate(bench.commands) if axis == "X")
    z_done = max(i for i, (axis, _) in enumerate(bench.commands) if axis == "Z")
    assert first_x > z_done, "X starts once Z is done"


def test_home_rejects_an_axis_named_twice() -> None:
    with pytest.raises(ArgumentError, match="twice"):
        Home("XY", lambda n: MoveAxisHome(n, 1.0), order=["X", ["X", "Y"]])


@pytest.mark.parametrize(("kwargs", "word"), [
    ({"homing_speed_mm_s": 5.0, "search_mm": 0.0}, "search_mm"),
    ({"homing_speed_mm_s": 5.0, "pull_off_mm": -1.0}, "pull_off_mm"),
    ({"homing_speed_mm_s": 0.0}, "homing_speed_mm_s"),
    ({"homing_speed_mm_s": float("nan")}, "homing_speed_mm_s"),
    ({"homing_speed_mm_s": 5.0, "backoff_mm": -1.0}, "backoff_mm"),
    ({"homing_speed_mm_s": 5.0, "slow_speed_mm_s": -1.0}, "slow_speed_mm_s"),
])
def test_bad_homing_parameters(kwargs: dict[str, float], word: str) -> None:
    with pytest.raises(ArgumentError, match=word):
        MoveAxisHome("X", **kwargs)


class FakeClock:
    def __init__(self) -> None:
        self.t = 0.0

    def now(self) -> float:
        return self.t

    def sleep(self, seconds: float) -> None:
        self.t += seconds


def test_runner_polls_at_a_fixed_rate_and_raises_faults() -> None:
    clock = FakeClock()
    polls: list[float] = []
    log: list[str] = []
    seq = Script("a", [Incomplete] * 4 + [Complete], log)
    run_sequence(seq, None, None, clock=clock, rate_hz=50, on_poll=lambda n: polls.append(clock.t))
    assert polls == pytest.approx([0.0, 0.02, 0.04, 0.06, 0.08])
    bad = Script("b", [Incomplete, Failure(FailureKind.DEVICE, "X", "watchdog")], log)
    with pytest.raises(SequenceFaultError) as caught:
        run_sequence(bad, None, None, clock=clock)
    assert caught.value.axis == "X"
    assert "watchdog" in str(caught.value)


def test_runner_times_out_and_stops_the_sequence() -> None:
    clock = FakeClock()
    seq = Script("a", [Incomplete] * 1000, [])
    with pytest.raises(SequenceFaultError, match="still running after 1 s"):
        run_sequence(seq, None, None, clock=clock, rate_hz=100, timeout_s=1.0)
    assert seq.stopped


def test_runner_stops_the_sequence_when_asked_and_says_why() -> None:
    clock = FakeClock()
    seq = Script("a", [Incomplete] * 10, [])
    asked_at: list[float] = []

    def should_stop() -> str:
        if clock.t >= 0.015:
            asked_at.append(clock.t)
            return "interrupted by the user"
        return ""

    with pytest.raises(StopRequestedError, match="interrupted by the user") as caught:
        run_sequence(seq, None, None, clock=clock, rate_hz=50, should_stop=should_stop)
    assert seq.stopped
    assert caught.value.reason == "interrupted by the user"
    assert len(seq.answers) == 9, "polled once at 0 s, stopped before the poll at 20 ms"
    assert asked_at[0] == pytest.approx(0.016), "asked while waiting, every 2 ms"
