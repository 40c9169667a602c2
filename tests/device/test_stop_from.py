"""Call 50: a stop that replaces the queue's future and, however late it arrives, is
delayed rather than cut short.

On time it is call 38 to the byte of the queue. Late, every value is used, from the next
motion update, offset so that the axis goes on from where the old motion had it: the
deceleration is whole, only later and further along.
"""

from __future__ import annotations

import zlib

import numpy as np
import pytest

from usbmotion.device import Device

from .helpers import send

SPEED = 3
"""Counts per value of the motion the stop interrupts."""


def _ramp(n: int) -> list[int]:
    return [SPEED * k for k in range(1, n + 1)]


def _stop(first: int) -> list[int]:
    """A stop planned from value ``first`` of the ramp (speed 3 counts a value) to rest."""
    values = [SPEED * (first + 1)]
    for speed in range(SPEED, -1, -1):  # 3, 2, 1 counts a value, then at rest
        values.append(values[-1] + speed)
    return values


def _crc(values: list[int]) -> int:
    return zlib.crc32(np.asarray(values, dtype="<i4").tobytes())


def _moving(scalar: int) -> Device:
    device = Device()
    send(device, "8 38 1", "8 50 1", f"6 {scalar}", "3 1",
         "1 400 " + " ".join(map(str, _ramp(400))))
    device.run(60 * scalar + 1)
    return device


def _next_due(device: Device, scalar: int) -> int:
    return device.state.clock + (scalar - 1 if scalar > 1 else 0)


@pytest.mark.parametrize("scalar", [1, 3])
@pytest.mark.parametrize("lead", [0, 1, 17])
def test_on_time_it_is_call_38(scalar: int, lead: int) -> None:
    stopping, replacing = _moving(scalar), _moving(scalar)
    tick = _next_due(stopping, scalar) + lead * scalar
    values = _stop(61 + lead)
    (stopped,) = send(stopping, f"50 {tick} {len(values)} " + " ".join(map(str, values)))
    (replaced,) = send(replacing, f"38 {tick} {len(values)} " + " ".join(map(str, values)))
    assert stopped == f"STOPPED {lead} 0 {len(values)} 0 CRC {_crc(values)}"
    assert replaced == f"REPLACED {lead} 0 {len(values)} CRC {_crc(values)}"
    assert stopping.queue_values() == replacing.queue_values()
    for _ in range(10):
        stopping.run(7)
        replacing.run(7)
        assert stopping.state == replacing.state


@pytest.mark.parametrize("scalar", [1, 3])
@pytest.mark.parametrize("late", [1, 2, 5, 40])
def test_late_it_decelerates_whole_from_where_the_axis_is(scalar: int, late: int) -> None:
    """``late`` value periods after the stop's first tick (40: after its whole length,
    where call 38 would leave nothing but a dead stop from speed)."""
    device = _moving(scalar)
    taken = 61
    tick = _next_due(device, scalar) - late * scalar
    values = _stop(taken - late)
    due = _ramp(400)[taken]
    (ack,) = send(device, f"50 {tick} {len(values)} " + " ".join(map(str, values)))
    offset = due - values[0]
    assert ack == f"STOPPED 0 {late} {len(values)} {offset} CRC {_crc(values)}"
    assert offset == late * SPEED
    assert device.queue_values() == tuple(v + offset for v in values)
    desired = [device.state.desired]
    for _ in range(len(values) + 3):
        device.run(scalar)
        desired.append(device.state.desired)
    steps = np.diff(desired)
    assert steps[0] == SPEED  # no jump: the step the old motion was taking
    assert np.all(np.diff(steps) <= 0) and np.all(np.diff(steps) >= -1)  # no harsher
    assert desired[-1] == values[-1] + offset and steps[-1] == 0


def test_call_38_late_by_the_whole_stop_leaves_a_dead_stop() -> None:
    """What call 50 is for: the same late stop through call 38 takes none of its values."""
    device = _moving(1)
    values = _stop(61 - 40)
    (ack,) = send(device, f"38 {_next_due(device, 1) - 40} {len(values)} "
                  + " ".join(map(str, values)))
    assert ack.startswith(f"REPLACED 0 {len(values)} 0 ")
    before = device.state.desired
    device.run(5)
    assert device.state.desired == before  # held from full speed: the servo brakes at once


def test_late_in_velocity_mode_the_values_are_delayed_not_offset() -> None:
    device = Device()
    send(device, "8 50 1", "7 2", "3 1", "1 100 " + " ".join(["500"] * 100))
    device.run(30)
    values = [400, 300, 200, 100, 0]
    (ack,) = send(device, f"50 {device.state.clock - 10} 5 " + " ".join(map(str, values)))
    assert ack == f"STOPPED 0 10 5 0 CRC {_crc(values)}"
    assert device.queue_values() == tuple(values)


def test_an_empty_queue_offsets_from_the_held_position() -> None:
    device = Device()
    send(device, "8 50 1", "3 1", "1 3 10 20 30")
    device.run(20)
    (ack,) = send(device, f"50 {device.state.clock - 15} 2 5 6")
    assert ack == f"STOPPED 0 15 2 25 CRC {_crc([5, 6])}"
    assert device.queue_values() == (30, 31)


def test_an_offset_beyond_int32_is_refused_and_changes_nothing() -> None:
    device = Device()
    send(device, "3 1", "1 3 2147483000 2147483100 2147483200")
    device.run(2)
    before = device.queue_values()
    assert send(device, "50 0 2 -5 2147483647") == ["E50"]
    assert device.queue_values() == before


def test_a_result_that_does_not_fit_is_refused() -> None:
    device = Device()
    send(device, "3 1", "1 1000 " + " ".join(["5"] * 1000))
    clock = device.state.clock
    assert send(device, f"50 {clock + 10} 991 " + " ".join(["1"] * 991)) == ["E50"]
    assert len(device.queue_values()) == 1000


def test_curve_mode_refuses_it() -> None:
    device = Device()
    send(device, "7 3")
    (line,) = send(device, "50 0 1 5")
    assert line.startswith("ERR 50 curve mode (3) plays keyframes")
