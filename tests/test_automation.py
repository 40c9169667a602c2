"""Automation sequences against dummy inputs and outputs: seed 002's tests and more."""

from __future__ import annotations

from dataclasses import dataclass, field

import pytest

from usbmotion.automation import (
    All,
    Chain,
    Complete,
    Fault,
    FaultKind,
    Home,
    Incomplete,
    LimitSwitchState,
    MoveAxisHome,
    Transition,
    run_sequence,
)
from usbmotion.errors import OutOfRangeError, SequenceFaultError


@dataclass
class DummyLimits:
    switches: dict[str, LimitSwitchState] = field(default_factory=dict)
    positions: dict[str, float] = field(default_factory=dict)

    def limit_switches(self, axis: str) -> LimitSwitchState | None:
        return self.switches.get(axis)

    def position_mm(self, axis: str) -> float:
        return self.positions.get(axis, 0.0)


@dataclass
class DummyAxes:
    velocities: dict[str, float] = field(default_factory=dict)
    zeroed: list[str] = field(default_factory=list)

    def set_target_velocity(self, axis: str, velocity_mm_s: float) -> None:
        self.velocities[axis] = velocity_mm_s

    def zero_position(self, axis: str) -> None:
        self.zeroed.append(axis)


def test_polling_without_hitting_limits_makes_an_axis_move_backwards() -> None:
    seq = MoveAxisHome("7", 100.0)
    axes, limits = DummyAxes(), DummyLimits({"7": LimitSwitchState()})
    assert seq.poll(limits, axes) is Incomplete
    assert axes.velocities == {"7": -100.0}


def test_actuating_the_upper_limit_is_a_fault() -> None:
    seq = MoveAxisHome("7", 100.0)
    axes = DummyAxes()
    limits = DummyLimits({"7": LimitSwitchState(at_upper_limit=True)})
    assert seq.poll(limits, axes) == Fault.unexpected_upper_limit("7")
    assert axes.velocities["7"] == 0.0


def test_actuating_the_lower_limit_completes_the_sequence() -> None:
    seq = MoveAxisHome("7", 100.0)
    axes = DummyAxes()
    limits = DummyLimits({"7": LimitSwitchState(at_lower_limit=True)})
    assert seq.poll(limits, axes) is Complete
    assert axes.velocities["7"] == 0.0
    assert axes.zeroed == ["7"]


def test_homing_an_axis_that_does_not_exist_is_a_fault() -> None:
    seq = MoveAxisHome("9", 100.0)
    assert seq.poll(DummyLimits(), DummyAxes()) == Fault.axis_not_found("9")


def test_backoff_and_slow_reapproach() -> None:
    seq = MoveAxisHome("X", 20.0, slow_speed_mm_s=2.0, backoff_mm=1.0)
    axes = DummyAxes()
    limits = DummyLimits({"X": LimitSwitchState()}, {"X": 5.0})
    assert seq.poll(limits, axes) is Incomplete
    assert axes.velocities["X"] == -20.0
    limits.switches["X"] = LimitSwitchState(at_lower_limit=True)
    limits.positions["X"] = -0.2
    assert seq.poll(limits, axes) is Incomplete
    assert seq.phase == "back off"
    assert axes.velocities["X"] == 2.0
    limits.switches["X"] = LimitSwitchState()
    limits.positions["X"] = 0.3
    assert seq.poll(limits, axes) is Incomplete
    assert axes.velocities["X"] == 2.0, "keeps backing off until the distance is cleared"
    limits.positions["X"] = 0.9
    assert seq.poll(limits, axes) is Incomplete
    assert seq.phase == "slow approach"
    assert axes.velocities["X"] == -2.0
    assert axes.zeroed == []
    limits.switches["X"] = LimitSwitchState(at_lower_limit=True)
    assert seq.poll(limits, axes) is Complete
    assert axes.velocities["X"] == 0.0
    assert axes.zeroed == ["X"]


def test_a_switch_that_never_opens_is_a_fault() -> None:
    seq = MoveAxisHome("X", 20.0, backoff_mm=1.0)
    axes = DummyAxes()
    limits = DummyLimits({"X": LimitSwitchState(at_lower_limit=True)}, {"X": 0.0})
    assert seq.poll(limits, axes) is Incomplete
    limits.positions["X"] = 10.0
    result = seq.poll(limits, axes)
    assert isinstance(result, Fault)
    assert result.kind is FaultKind.LIMIT_NOT_RELEASED
    assert axes.velocities["X"] == 0.0


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
    fault = Fault(FaultKind.DEVICE, "Y", "following error")
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
    fault = Fault(FaultKind.DEVICE, "Z")
    log.clear()
    c = Script("c", [fault], log)
    d = Script("d", [Complete], log)
    chain = Chain([c, d])
    assert chain.poll(None, None) == fault
    assert chain.poll(None, None) is Complete
    assert log == ["c"], "nothing runs after a fault"


def test_home_in_order_z_first() -> None:
    axes = DummyAxes()
    limits = DummyLimits({n: LimitSwitchState() for n in "XYZ"})
    home = Home("XYZ", lambda n: MoveAxisHome(n, 10.0), order=["Z", ["X", "Y"]])
    assert home.poll(limits, axes) is Incomplete
    assert axes.velocities == {"Z": -10.0}, "Z homes alone first"
    limits.switches["Z"] = LimitSwitchState(at_lower_limit=True)
    assert home.poll(limits, axes) is Incomplete
    assert axes.velocities == {"Z": 0.0, "X": -10.0, "Y": -10.0}
    limits.switches["X"] = LimitSwitchState(at_lower_limit=True)
    limits.switches["Y"] = LimitSwitchState(at_lower_limit=True)
    assert home.poll(limits, axes) is Complete
    assert axes.zeroed == ["Z", "X", "Y"]


def test_home_rejects_an_axis_named_twice() -> None:
    with pytest.raises(OutOfRangeError, match="twice"):
        Home("XY", lambda n: MoveAxisHome(n, 1.0), order=["X", ["X", "Y"]])


@pytest.mark.parametrize(("kwargs", "word"), [
    ({"homing_speed_mm_s": 0.0}, "homing_speed_mm_s"),
    ({"homing_speed_mm_s": float("nan")}, "homing_speed_mm_s"),
    ({"homing_speed_mm_s": 5.0, "backoff_mm": -1.0}, "backoff_mm"),
    ({"homing_speed_mm_s": 5.0, "slow_speed_mm_s": -1.0}, "slow_speed_mm_s"),
])
def test_bad_homing_parameters(kwargs: dict[str, float], word: str) -> None:
    with pytest.raises(OutOfRangeError, match=word):
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
    bad = Script("b", [Incomplete, Fault(FaultKind.DEVICE, "X", "watchdog")], log)
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
