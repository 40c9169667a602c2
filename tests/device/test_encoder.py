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
    assert send(device, "49 -1 0") == ["ENCODER 0 0 0"]


def test_an_incremental_encoder_keeps_its_count() -> None:
    device = Device()
    send(device, "23 777", "49 0 5")
    assert send(device, "20 -1") == ["STATUS 0 777 777 0 0 0 1 0 0"]


def test_the_query_says_where_the_turns_begin_in_the_counters_coordinates() -> None:
    """``zero``: the counter value (within a turn) at which the encoder reads angle 0; it
    follows every shift of the counter and the velocity-mode reset."""
    device = Device()
    send(device, "49 1 5000")
    # the counter is the angle: the turns begin at 0
    assert send(device, "49 -1 0") == ["ENCODER 1 5000 0"]
    send(device, "37 100")
    assert send(device, "49 -1 0") == ["ENCODER 1 5000 100"]
    send(device, "23 -50")   # 1160 + 100 -> -50: a shift of -1310
    assert send(device, "49 -1 0") == ["ENCODER 1 5000 710"]   # (100 - 1310) mod 1920
    send(device, "3 1", "1 2 2000 4000")
    device.run(2000)
    state = device.state
    assert send(device, "49 -1 0") == ["ENCODER 1 5000 710"], "moving moves no turn"
    shaft = state.shaft_micro_counts // 1_000_000
    # the absolute angle of the counter, through zero, is the magnet's
    assert (state.actual - 710) % 1920 == (shaft + 5000) % 1920
    send(device, "3 0", "2 2", "3 1")
    device.run(600_001)   # the 60 s reset of velocity mode moves the counter to 0
    state = device.state
    shaft = state.shaft_micro_counts // 1_000_000
    zero = int(send(device, "49 -1 0")[0].split()[3])
    assert (state.actual - zero) % 1920 == (shaft + 5000) % 1920
