"""The motion queue: capacity, refusals, order, and how core1 consumes it."""

from __future__ import annotations

from usbmotion.device import Device

from .helpers import desired_positions, send


def test_a_thousand_single_values_fit_and_the_next_is_refused() -> None:
    device = Device()
    device.feed(b"".join(f"0 {i * 3 - 1000}\n".encode() for i in range(1000)))
    assert device.take_output() == b""
    assert send(device, "0 99999") == ["E0"]
    assert send(device, "2 -1") == ["MOTION_QUEUE 1000 0"]
    assert device.queue_values() == tuple(i * 3 - 1000 for i in range(1000))


def test_a_batch_that_does_not_fit_is_refused_whole() -> None:
    device = Device()
    first = list(range(990))
    send(device, "1 990 " + " ".join(map(str, first)))
    assert send(device, "1 11 " + " ".join(["7"] * 11)) == ["E1"]
    assert device.queue_values() == tuple(first)
    assert send(device, "1 10 " + " ".join(["7"] * 10)) == []
    assert device.queue_values() == (*first, *[7] * 10)
    assert send(device, "1 1 5") == ["E1"]
    assert send(device, "0 5") == ["E0"]


def test_nothing_queued_is_lost_or_reordered_by_refusals_and_consumption() -> None:
    device = Device()
    values = [(-1) ** i * i * 1000 for i in range(1000)]
    device.feed(("1 1000 " + " ".join(map(str, values)) + "\n").encode())
    assert send(device, "0 1", "1 2 3 4") == ["E0", "E1"]
    send(device, "6 1")  # clears the queue: the scalar changed
    assert device.queue_values() == ()
    device.feed(("1 1000 " + " ".join(map(str, values)) + "\n").encode())
    send(device, "3 1")
    consumed = desired_positions(device, 400)
    send(device, "1 400 " + " ".join(map(str, range(400))))
    assert send(device, "0 1") == ["E0"]
    consumed += desired_positions(device, 1000)
    assert consumed == values + list(range(400))
    assert send(device, "2 -1") == ["MOTION_QUEUE 0 1000"]


def test_one_value_every_scalar_ticks_starting_with_the_first_tick() -> None:
    device = Device()
    send(device, "6 3", "1 4 10 20 30 40", "3 1")
    assert desired_positions(device, 13) == [10, 10, 10, 20, 20, 20, 30, 30, 30, 40, 40, 40, 40]


def test_an_empty_queue_holds_the_last_position() -> None:
    device = Device()
    send(device, "3 1", "0 300")
    device.run(500)
    state = device.state
    assert (state.desired, state.queued) == (300, 0)
    assert abs(state.actual - 300) <= 2


def test_the_queue_waits_while_the_servo_is_disabled() -> None:
    device = Device()
    send(device, "1 3 1 2 3")
    device.run(100)
    assert device.queue_values() == (1, 2, 3)
    send(device, "3 1")
    assert desired_positions(device, 3) == [1, 2, 3]


def test_calls_that_clear_the_queue() -> None:
    for line in ("4 0", "5 10", "6 1", "7 1", "23 0"):
        device = Device()
        send(device, "1 3 1 2 3", line)
        assert device.queue_values() == (), line
    device = Device()
    send(device, "1 3 1 2 3", "3 1", "9 1 0", "21 5", "3 0", "28 10", "29 10")
    assert device.queue_values() == (1, 2, 3)


def test_queue_values_are_refused_in_curve_mode() -> None:
    device = Device()
    send(device, "7 3")
    lines = send(device, "0 5", "1 1 5")
    assert [line.split()[:2] for line in lines] == [["ERR", "0"], ["ERR", "1"]]
    assert device.queue_values() == ()
