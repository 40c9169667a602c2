"""The switch-edge latch (call 36) and the change of coordinates (calls 23 and 37).

A host homes on the count core1 latched on the tick a switch changed, not on when it polled
the switch: these tests watch every tick and check the latch against it.
"""

from __future__ import annotations

import pytest

from usbmotion.device import Device

from .helpers import send

VELOCITY_GAINS = ("9 7 -3", "10 1 0", "11 0 0")


def _edge(device: Device, switch: int) -> tuple[int, int, int, int]:
    (line,) = send(device, f"36 {switch}")
    key, number, *values = line.split()
    assert (key, int(number)) == ("SWITCH_EDGE", switch)
    edges, closed, position, tick = map(int, values)
    return edges, closed, position, tick


def _drive(device: Device, counts_s: int) -> None:
    """Velocity mode at ``counts_s`` for a second of queue (one value per tick)."""
    send(device, "4 0", "1 1000 " + " ".join([str(counts_s)] * 1000))


def _watch_for_change(device: Device, ticks: int) -> tuple[int, int, int]:
    """Run tick by tick until the switch bits change; (limits, actual, clock) then."""
    before = device.state.limits
    for _ in range(ticks):
        device.run(1)
        state = device.state
        if state.limits != before:
            return state.limits, state.actual, state.clock
    raise AssertionError(f"no switch changed within {ticks} ticks")


def test_no_edge_before_the_first() -> None:
    device = Device()
    send(device, "34 -500 500")
    assert _edge(device, 1) == (0, 0, 0, 0)
    assert _edge(device, 2) == (0, 0, 0, 0)
    assert send(device, "36 3") == ["ERR 36 switch 3 is out of range 1..2"]
    assert send(device, "36 -1") == ["ERR 36 switch -1 is out of range 1..2"]


def test_closing_and_opening_edges_are_latched_on_their_tick() -> None:
    device = Device()
    send(device, "34 -400 5000", "7 2", *VELOCITY_GAINS, "3 1")
    _drive(device, -3000)
    limits, actual, clock = _watch_for_change(device, 2000)
    assert limits == 1
    assert actual <= -400 < actual + 10, "the first tick at or past the switch"
    assert _edge(device, 1) == (1, 1, actual, clock)
    device.run(30)
    assert _edge(device, 1) == (1, 1, actual, clock), "a later look reads the same edge"
    _drive(device, 2000)
    limits, opened_at, opened_clock = _watch_for_change(device, 2000)
    assert limits == 0 and opened_at > -400
    assert _edge(device, 1) == (2, 0, opened_at, opened_clock)
    assert _edge(device, 2) == (0, 0, 0, 0), "the other switch has its own latch"


def test_a_slow_approach_latches_the_switch_position_exactly() -> None:
    """At well under a count a tick the first count at the switch is the switch itself,
    however late anybody looks: the repeatable zero homing needs."""
    for late in (0, 7, 180):
        device = Device()
        send(device, "34 -250 5000", "7 2", *VELOCITY_GAINS, "3 1")
        _drive(device, -300)
        device.run(900)
        device.run(late)
        edges, closed, position, _ = _edge(device, 1)
        assert (edges, closed, position) == (1, 1, -250)


def test_the_edge_moves_with_the_counter() -> None:
    """Counter minus edge position is a distance: a change of coordinates keeps it."""
    device = Device()
    send(device, "34 -300 5000", "7 2", *VELOCITY_GAINS, "3 1")
    _drive(device, -3000)
    _, actual, clock = _watch_for_change(device, 2000)
    assert _edge(device, 1)[2] == actual
    distance = device.state.actual - actual
    send(device, "23 1000")
    assert _edge(device, 1)[2] == 1000 - distance
    send(device, "37 -123456")
    assert device.state.actual - _edge(device, 1)[2] == distance
    send(device, "23 2147483000")
    assert device.state.actual == 2147483000
    assert _edge(device, 1)[2] == 2147483000 - distance
    send(device, "37 1000")
    assert device.state.actual == 2147483000 + 1000 - 2**32, "wraps as the int32 counter"
    assert device.state.actual - _edge(device, 1)[2] == distance
    assert _edge(device, 1)[3] == clock, "the tick is a time: not moved"


def test_the_velocity_mode_reset_moves_the_edge_too() -> None:
    device = Device()
    send(device, "34 -300 100000000", "7 2", *VELOCITY_GAINS, "6 1000", "3 1")
    send(device, "1 3 -2000 -2000 0")
    _watch_for_change(device, 3000)
    device.run(2000)
    counter_minus_edge = device.state.actual - _edge(device, 1)[2]
    device.run(60_000 - device.state.clock)
    assert device.state.actual == 0, "the 60 s reset"
    assert device.state.actual - _edge(device, 1)[2] == counter_minus_edge


def test_moving_the_travel_is_no_edge() -> None:
    device = Device()
    send(device, "34 10 100")
    assert device.state.limits == 1
    device.run(5)
    assert _edge(device, 1) == (0, 0, 0, 0)


@pytest.mark.parametrize("line", ["23 77", "37 77"])
def test_a_change_of_coordinates_keeps_the_loop(line: str) -> None:
    device = Device()
    send(device, "3 1", "0 300")
    device.run(40)
    before = device.state
    send(device, line)
    after = device.state
    shift = after.actual - before.actual
    assert shift == (77 - before.actual if line.startswith("23") else 77)
    assert after.desired - after.actual == before.desired - before.actual
    assert (after.integrator, after.velocity, after.output_mv) == (
        before.integrator, before.velocity, before.output_mv)
    assert after.shaft_micro_counts == before.shaft_micro_counts
