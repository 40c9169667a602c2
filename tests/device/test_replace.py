"""Call 38: replacing the motion queue's future from a device tick, without a seam.

The property a host relies on: sending the queue's own future again from any tick, however
late the line arrives, changes nothing of the motion; sending another future changes it from
exactly that tick.
"""

from __future__ import annotations

import zlib

import numpy as np
import pytest

from usbmotion.device import Device

from .helpers import send


def _ramp(n: int, *, offset: int = 0) -> list[int]:
    return [offset + 3 * k for k in range(1, n + 1)]


def _line(tick: int, values: list[int]) -> str:
    return f"38 {tick} {len(values)} " + " ".join(map(str, values))


def _twins(scalar: int) -> tuple[Device, Device]:
    twins = (Device(), Device())
    for device in twins:
        send(device, "8 38 1", f"6 {scalar}", "3 1", "1 400 " + " ".join(map(str, _ramp(400))))
    return twins


@pytest.mark.parametrize("scalar", [1, 3])
@pytest.mark.parametrize("lead", [-25, -1, 0, 1, 17])
def test_sending_the_same_future_again_changes_nothing(scalar: int, lead: int) -> None:
    """``lead`` ticks ahead of the next due value (negative: the line arrives late)."""
    plain, replaced = _twins(scalar)
    for device in (plain, replaced):
        device.run(60 * scalar + 1)
    state = replaced.state
    assert state.queued == 400 - 61
    next_due = state.clock + (scalar - 1 if scalar > 1 else 0)
    assert next_due >= state.clock
    taken = 61
    tick = next_due + lead * scalar
    index = taken + lead
    (ack,) = send(replaced, _line(tick, _ramp(400)[index:]))
    kept, skipped, added = map(int, ack.split()[1:4])
    assert kept == max(0, lead)
    assert skipped == max(0, -lead)
    assert kept + added == 400 - taken
    assert replaced.queue_values() == plain.queue_values()
    for _ in range(10):
        plain.run(37)
        replaced.run(37)
        assert replaced.state == plain.state


def test_a_new_future_starts_on_its_tick() -> None:
    device = Device()
    send(device, "8 38 1", "3 1", "1 100 " + " ".join(map(str, _ramp(100))))
    device.run(10)
    clock = device.state.clock
    assert send(device, _line(clock + 5, [1000, 1001])) == [
        f"REPLACED 5 0 2 CRC {zlib.crc32(np.asarray([1000, 1001], '<i4').tobytes())}"]
    assert device.queue_values() == (*_ramp(100)[10:15], 1000, 1001)
    desired = []
    for _ in range(8):
        device.run(1)
        desired.append(device.state.desired)
    assert desired == [*_ramp(100)[10:15], 1000, 1001, 1001]


def test_an_armed_start_dates_the_queue_from_its_tick() -> None:
    device = Device()
    send(device, "8 38 1", "31 50", "3 1", "1 4 1 2 3 4")
    assert send(device, _line(52, [7, 8])) == [
        f"REPLACED 2 0 2 CRC {zlib.crc32(np.asarray([7, 8], '<i4').tobytes())}"]
    assert device.queue_values() == (1, 2, 7, 8)


def test_a_disabled_servo_has_nothing_due_and_the_queue_is_replaced_whole() -> None:
    device = Device()
    send(device, "8 38 1", "1 3 1 2 3")
    assert send(device, _line(0, [9]))[0].startswith("REPLACED 0 0 1 CRC ")
    assert device.queue_values() == (9,)


def test_zero_values_cut_the_queue_and_the_axis_holds() -> None:
    device = Device()
    send(device, "3 1", "1 100 " + " ".join(map(str, _ramp(100))))
    device.run(20)
    send(device, f"38 {device.state.clock + 3} 0")
    device.run(50)
    assert device.state.desired == _ramp(100)[22]
    assert device.state.queued == 0


def test_a_result_that_does_not_fit_is_refused_and_changes_nothing() -> None:
    device = Device()
    send(device, "3 1", "1 1000 " + " ".join(["5"] * 1000))
    before = device.queue_values()
    clock = device.state.clock
    assert send(device, _line(clock + 10, [1] * 991)) == ["E38"]
    assert device.queue_values() == before
    assert send(device, _line(clock + 10, [1] * 990)) == []
    assert len(device.queue_values()) == 1000


def test_curve_mode_refuses_it() -> None:
    device = Device()
    send(device, "7 3")
    (line,) = send(device, "38 0 1 5")
    assert line.startswith("ERR 38 curve mode (3) plays keyframes")
