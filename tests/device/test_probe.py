"""The probe input (calls 40 and 41): a simulated surface the motor's count touches, and the
edge latch a probing move stops on.

As with the limit switches (``test_edges.py``), a host takes the contact position from the
count core1 latched on the tick the probe changed, not from when it looked: these tests
watch every tick and check the latch against it, and the compiled kernel against core1.
"""

from __future__ import annotations

import pytest

from usbmotion.device import Device

from .helpers import send

VELOCITY_GAINS = ("9 7 -3", "10 1 0", "11 0 0")


def _probe(device: Device) -> tuple[int, int, int, int, int]:
    (line,) = send(device, "41 -1")
    key, *values = line.split()
    assert key == "PROBE"
    closed, edges, edge_closed, position, tick = map(int, values)
    return closed, edges, edge_closed, position, tick


def _drive(device: Device, counts_s: int) -> None:
    """Velocity mode at ``counts_s`` for a second of queue (one value per tick)."""
    send(device, "4 0", "1 1000 " + " ".join([str(counts_s)] * 1000))


def _until_touch_changes(device: Device, ticks: int) -> tuple[int, int]:
    """Run tick by tick until the probe input changes; (actual, clock) on that tick."""
    before = _probe(device)[0]
    for _ in range(ticks):
        device.run(1)
        if _probe(device)[0] != before:
            state = device.state
            return state.actual, state.clock
    raise AssertionError(f"the probe did not change within {ticks} ticks")


def test_no_surface_no_edge_at_power_up() -> None:
    device = Device()
    assert send(device, "40 -1 0") == ["SIM_PROBE 0 0"]
    assert _probe(device) == (0, 0, 0, 0, 0)
    assert send(device, "40 3 0") == ["ERR 40 side 3 is out of range 0..2"]


def test_a_plate_below_latches_the_contact_on_its_tick_and_the_lift_off() -> None:
    device = Device()
    send(device, "40 1 -400", "7 2", *VELOCITY_GAINS, "3 1")
    _drive(device, -3000)
    actual, clock = _until_touch_changes(device, 2000)
    assert actual <= -400 < actual + 10, "the first tick at or past the surface"
    assert _probe(device) == (1, 1, 1, actual, clock)
    device.run(30)
    assert _probe(device) == (1, 1, 1, actual, clock), "a later look reads the same edge"
    _drive(device, 2000)
    lifted, lifted_clock = _until_touch_changes(device, 2000)
    assert lifted > -400
    assert _probe(device) == (0, 2, 0, lifted, lifted_clock)


@pytest.mark.parametrize("late", [0, 7, 180])
def test_a_slow_probe_latches_the_surface_exactly_however_late_the_host_looks(
        late: int) -> None:
    device = Device()
    send(device, "40 2 250", "7 2", *VELOCITY_GAINS, "3 1")
    _drive(device, 300)
    device.run(900 + late)
    closed, edges, edge_closed, position, _ = _probe(device)
    assert (closed, edges, edge_closed, position) == (1, 1, 1, 250)


def test_moving_the_surface_is_no_edge_and_shifts_move_the_latch() -> None:
    device = Device()
    send(device, "40 1 0")
    assert _probe(device) == (1, 0, 0, 0, 0), "touching at once, no edge"
    send(device, "40 2 100")
    assert _probe(device) == (0, 0, 0, 0, 0)
    send(device, "40 1 -50", "7 2", *VELOCITY_GAINS, "3 1")
    _drive(device, -2000)
    actual, clock = _until_touch_changes(device, 1000)
    send(device, "3 0")  # hold still: the counter moves only by the shifts below
    send(device, "37 1000")
    assert _probe(device) == (1, 1, 1, actual + 1000, clock)
    before = device.state.actual
    send(device, "23 5")
    assert _probe(device) == (1, 1, 1, actual + 1000 + 5 - before, clock), (
        "call 23 moves the latch with the counter")


def test_a_power_cycle_forgets_the_surface_and_the_edge() -> None:
    device = Device()
    send(device, "40 1 -20", "7 2", *VELOCITY_GAINS, "3 1")
    _drive(device, -1000)
    device.run(200)
    assert _probe(device)[1] == 1
    device.restart()
    assert send(device, "40 -1 0") == ["SIM_PROBE 0 0"]
    assert _probe(device) == (0, 0, 0, 0, 0)


def test_the_kernel_latches_as_core1_does() -> None:
    pytest.importorskip("numba")
    outputs = []
    for fast in (False, True):
        device = Device(fast=fast)
        send(device, "40 1 -300", "7 1", "3 1")
        send(device, "1 60 " + " ".join(str(-10 * i) for i in range(1, 61)))
        device.run(700)
        send(device, "1 60 " + " ".join(str(-600 + 10 * i) for i in range(1, 61)))
        device.run(700)
        outputs.append((_probe(device), device.state.actual, device.state.clock))
    assert outputs[0] == outputs[1]
    assert outputs[0][0][1] == 2, "touched and lifted off"
