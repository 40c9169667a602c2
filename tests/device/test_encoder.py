"""Call 49: an absolute encoder makes the counter the angle within a turn at once, and it
counts on across turns; refused where there is no encoder to read, or while enabled."""

from __future__ import annotations

from usbmotion.device import Device

from .helpers import send


def test_the_counter_becomes_the_angle_within_the_turn_and_counts_on() -> None:
    device = Device()
    assert send(device, "49 1 5000", "20 -1") == ["STATUS 0 1160 1160 0 0 0 1 0 0"]
    # 5000 counts from the magnet's zero is 2 turns of 1920 and 1160 counts more
    send(device, "3 1", "1 2 2000 4000")
    device.run(2000)
    state = device.state
    assert abs(state.actual - 4000) <= 2, "across the turn's end the counter goes on"
    shaft = state.shaft_micro_counts // 1_000_000
    assert state.actual - shaft == 1160


def test_a_closed_loop_stepper_counts_its_turn_in_microsteps() -> None:
    device = Device()
    send(device, "44 2", "45 200 16", "16 4000")
    assert send(device, "49 1 3300", "20 -1") == ["STATUS 0 100 100 0 0 0 1 0 0"]


def test_where_there_is_nothing_to_read_or_the_servo_runs_it_is_refused() -> None:
    device = Device()
    send(device, "44 1")
    assert send(device, "49 1 0") == [
        "ERR 49 an open-loop stepper (drive 1) counts its steps: it has no encoder to read"]
    send(device, "44 0", "3 1")
    assert send(device, "49 1 0") == [
        "ERR 49 the servo is enabled: disable it (call 3 0) before changing its encoder"]
    assert send(device, "49 -1 0") == ["ENCODER 0 0"]


def test_an_incremental_encoder_keeps_its_count() -> None:
    device = Device()
    send(device, "23 777", "49 0 5")
    assert send(device, "20 -1") == ["STATUS 0 777 777 0 0 0 1 0 0"]
