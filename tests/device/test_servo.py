"""core1 behaviour: faults, clock, synchronised start, position set, modes, diagnostics,
and the virtual-time API (big blocks equal tick-by-tick)."""

from __future__ import annotations

import pytest

from usbmotion.device import Device, Gains, MotorParams
from usbmotion.errors import DeviceParameterError
from usbmotion.protocol import ReplyKind, parse_reply

from .helpers import send, take

VELOCITY_GAINS = ("9 7 -3", "10 1 0", "11 0 0")


def test_watchdog_disables_the_servo_after_silence() -> None:
    device = Device()
    send(device, "28 50", "3 1")
    device.run(49)
    assert device.state.enable == 1
    send(device, "2 -1")  # any command restarts the watchdog
    device.run(49)
    assert device.state.enable == 1
    device.run(1)
    state = device.state
    assert (state.enable, state.fault, state.fault_tick) == (0, 1, 99)
    assert device.take_output() == b"ALARM 1 99\n", "the fault is announced unasked"
    assert send(device, "30 -1") == ["FAULT 1 99"]
    assert send(device, "3 1")[0].startswith("ERR 3 fault 1 (watchdog) is latched")
    assert device.state.enable == 0
    assert send(device, "30 0", "3 1", "3 -1") == ["SERVO_ENABLE 1"]


def test_watchdog_is_quiet_while_disabled() -> None:
    device = Device()
    send(device, "28 10")
    device.run(1000)
    assert device.state.fault == 0


def test_following_error_fault_and_clear() -> None:
    device = Device()
    send(device, "29 20", "3 1", "0 1000")
    device.run(1)
    assert device.state.fault == 2
    assert device.state.enable == 0
    assert device.take_output() == b"ALARM 2 1\n"
    assert send(device, "20 -1")[0].endswith(" 0 1 0 2")
    send(device, "30 0")
    assert device.state.fault == 0
    send(device, "29 0", "3 1", "0 1000")
    device.run(400)
    assert (device.state.fault, device.state.enable) == (0, 1)
    assert abs(device.state.actual - 1000) <= 2


def test_limit_switch_closing_in_position_mode_faults() -> None:
    device = Device()
    send(device, "34 -300 300", "3 1", "0 1000")
    device.run(400)
    state = device.state
    assert state.fault == 3
    assert state.enable == 0
    assert state.limits == 2
    assert device.take_output().decode().splitlines() == [f"ALARM 3 {state.fault_tick}"]
    assert send(device, "24 -1") == ["LIMITS 0 1"]
    assert 300 <= state.actual <= 300 + 200 + 1, "stopped at or before the hard stop"


def test_limit_switch_in_velocity_mode_is_not_a_fault() -> None:
    device = Device()
    send(device, "34 -300 300", "7 2", *VELOCITY_GAINS, "6 100", "3 1")
    send(device, "1 10 " + " ".join(["-3000"] * 10))
    device.run(600)
    state = device.state
    assert state.fault == 0
    assert state.limits == 1
    assert send(device, "24 -1") == ["LIMITS 1 0"]
    assert state.actual <= -300


def test_homing_then_position_mode_on_the_switch_does_not_fault() -> None:
    device = Device()
    send(device, "34 -300 300", "7 2", *VELOCITY_GAINS, "6 100", "3 1")
    send(device, "1 5 " + " ".join(["-3000"] * 5))
    device.run(500)
    assert device.state.limits == 1
    send(device, "23 0", "7 1", "9 1 0", "10 1 0", "11 7 -3", "3 1", "0 400")
    device.run(400)
    state = device.state
    assert (state.fault, state.limits) == (0, 0)
    assert abs(state.actual - 400) <= 2


def test_travel_ends_must_be_ordered() -> None:
    device = Device()
    assert send(device, "34 10 10")[0].startswith("ERR 34 lower end 10 must be below")
    assert send(device, "34 -1 -1") == ["SIM_TRAVEL -2147483648 2147483647"]


def test_clock_zero_and_query() -> None:
    device = Device()
    device.run(1234)
    assert send(device, "22 -1") == ["CLOCK 1234"]
    assert device.clock == 1234
    send(device, "22 0")
    device.run(5)
    assert send(device, "22 -1") == ["CLOCK 5"]


def test_synchronised_start_holds_the_queue_until_the_tick() -> None:
    device = Device()
    send(device, "22 0", "31 100", "1 3 11 22 33", "3 1")
    device.run(100)
    assert device.state.desired == 0
    assert device.queue_values() == (11, 22, 33)
    assert send(device, "31 -1") == ["START_TICK 100"]
    device.run(1)
    assert device.state.desired == 11
    assert send(device, "31 -1") == ["START_TICK -1"]
    device.run(2)
    assert device.state.desired == 33


def test_two_devices_start_together() -> None:
    a, b = Device(), Device()
    a.run(17)
    b.run(3)
    for device in (a, b):
        send(device, "22 0", "31 50", "1 2 100 200", "3 1")
    a.run(50)
    b.run(50)
    assert a.state.desired == b.state.desired == 0
    a.run(1)
    b.run(1)
    assert a.state.desired == b.state.desired == 100


def test_position_set_moves_the_counter_not_the_shaft() -> None:
    device = Device()
    send(device, "3 1", "0 500")
    device.run(300)
    before = device.state
    send(device, "1 2 9 9", "23 -70")
    state = device.state
    error = before.desired - before.actual
    assert (state.actual, state.desired, state.queued) == (-70, -70 + error, 0)
    assert (state.integrator, state.velocity) == (before.integrator, before.velocity), (
        "a change of coordinates: the loop goes on undisturbed"
    )
    device.run(200)
    assert abs(device.state.actual - device.state.desired) <= 2
    assert abs(device.state.shaft_micro_counts - before.shaft_micro_counts) < 3_000_000


def test_setting_the_position_while_moving_changes_nothing_of_the_motion() -> None:
    """Two devices on the same run, one of them renumbered mid-move (call 23, then 37):
    their shafts move exactly alike, tick by tick; only the counters differ."""
    plain, shifted = Device(), Device()
    ramp = " ".join(str(4 * k) for k in range(1, 301))
    for device in (plain, shifted):
        send(device, "3 1", f"1 300 {ramp}")
        device.run(120)
    send(plain, "4 0")
    send(shifted, "23 5000")
    offset = shifted.state.actual - plain.state.actual
    for device, extra in ((plain, 0), (shifted, offset)):
        rest = " ".join(str(4 * k + extra) for k in range(121, 301))
        send(device, f"1 180 {rest}")
    for _ in range(40):
        plain.run(5)
        shifted.run(5)
        assert shifted.state.shaft_micro_counts == plain.state.shaft_micro_counts
        assert shifted.state.actual == plain.state.actual + offset
        assert shifted.state.velocity == plain.state.velocity
    send(shifted, "37 -5000")
    plain.run(100)
    shifted.run(100)
    assert shifted.state.shaft_micro_counts == plain.state.shaft_micro_counts
    assert shifted.state.actual == plain.state.actual + offset - 5000


def test_the_counter_wraps_like_an_int32() -> None:
    device = Device()
    send(device, "23 2147483600", "3 1", "0 -2147483546")  # 150 counts forward, across the wrap
    device.run(300)
    state = device.state
    assert state.actual == -2147483546 or abs(state.actual + 2147483546) <= 2
    assert 149_000_000 <= state.shaft_micro_counts <= 151_000_000


def test_velocity_mode_resets_the_counter_every_60_s() -> None:
    device = Device()
    send(device, "7 2", *VELOCITY_GAINS, "6 1000", "3 1")
    send(device, "1 70 " + " ".join(["2000"] * 70))
    device.run(59_999)
    before = device.state.actual
    assert 110_000 < before < 120_000
    device.run(1)
    assert device.state.actual == 0
    assert 1000 <= device.state.velocity <= 3000, "the reset does not disturb the velocity"
    device.run(1000)
    assert 1900 < device.state.actual < 2100
    device.run(59_000)
    assert device.state.actual < 2100, "reset again 60 s after the first"


def test_velocity_mode_brakes_to_zero_when_the_queue_runs_dry() -> None:
    device = Device()
    send(device, "7 2", *VELOCITY_GAINS, "6 100", "3 1", "1 3 4000 4000 4000")
    device.run(300)
    assert device.state.velocity > 3000
    assert device.state.desired_velocity == 4000
    device.run(1)
    assert device.state.desired_velocity == 0
    device.run(300)
    assert device.state.velocity == 0
    assert device.state.shaft_speed_micro_counts_s == 0


def test_diagnostics_lines_at_the_right_ticks() -> None:
    device = Device()
    send(device, "3 1", "0 100", "21 10")
    device.run(35)
    lines = take(device)
    assert len(lines) == 3
    for line, tick in zip(lines, (10, 20, 30), strict=True):
        reply = parse_reply(line)
        assert reply.kind is ReplyKind.DIAGNOSTICS
        clock, desired, actual, velocity, output_mv, queued, peak = reply.values
        assert (clock, desired, queued) == (tick, 100, 0)
        assert 0 < actual <= 102
        assert abs(peak) >= abs(desired - actual), "the line's own tick is in its peak"
        assert velocity >= 0
        assert -12_000 <= output_mv <= 12_000
    send(device, "21 0")
    device.run(100)
    assert take(device) == []
    send(device, "22 0", "21 4")
    device.run(9)
    assert [line.split()[1] for line in take(device)] == ["4", "8"]


def test_restart_keeps_flash_and_resets_ram() -> None:
    device = Device()
    send(device, "18 2 65 66", "19 2", "5 5", "6 3", "3 1", "0 100", "21 5")
    device.run(50)
    device.feed(b"2 -")
    device.restart()
    assert device.take_output() == b""
    state = device.state
    assert (state.clock, state.actual, state.enable, state.queued, state.mode) == (0, 0, 0, 0, 2)
    assert send(device, "18 -1", "5 -1", "6 -1", "21 -1") == [
        "DEVICE_NAME AB",
        "SERVO_UPDATE_INTERVAL_US 1000",
        "MOTION_UPDATE_INTERVAL_SCALAR 1",
        "DIAGNOSTICS_INTERVAL 0",
    ]
    assert device.name == "AB"


def test_constructor_and_run_reject_bad_arguments() -> None:
    with pytest.raises(DeviceParameterError, match="ticks -1"):
        Device().run(-1)
    with pytest.raises(DeviceParameterError, match="inertia_kg_m2 coefficient"):
        MotorParams(inertia_kg_m2=(0, 0))
    with pytest.raises(DeviceParameterError, match="kp"):
        Gains(kp=(1000, 0))
    with pytest.raises(DeviceParameterError, match="travel_lower_counts"):
        MotorParams(travel_lower_counts=5, travel_upper_counts=5)
    with pytest.raises(TypeError):
        Device().feed("3 1\n")  # type: ignore[arg-type]


# --- virtual time: blocks equal ticks -------------------------------------------------------

SCENARIOS = {
    "idle": [],
    "enabled hold": ["3 1"],
    "step and settle": ["3 1", "0 700"],
    "stream": ["3 1", "6 5", "1 6 100 200 300 250 150 0"],
    "diagnostics": ["21 37", "3 1", "0 -300"],
    "watchdog": ["28 333", "3 1", "0 50"],
    "armed start": ["31 400", "3 1", "1 2 500 -500"],
    "velocity": ["7 2", *VELOCITY_GAINS, "6 50", "3 1", "1 4 1000 -500 0 200"],
    "curve": ["7 3", "3 1", "25 120 600 0 0", "25 200 -200 512 512", "21 100"],
    "ten kHz": ["5 1", "3 1", "0 1000", "21 333"],
}


@pytest.mark.parametrize("name", sorted(SCENARIOS))
def test_running_in_blocks_equals_running_tick_by_tick(name: str) -> None:
    lines = SCENARIOS[name]
    total = 3000
    stepped, blocked, jumping = Device(), Device(), Device()
    for device in (stepped, blocked, jumping):
        send(device, *lines)
    for _ in range(total):
        stepped.run(1)
    blocked.run(total)
    done = 0
    while done < total:
        step = jumping.ticks_until_event() or total
        step = min(step, total - done)
        jumping.run(step)
        done += step
    expected = (stepped.state, stepped.take_output(), stepped.settings)
    assert (blocked.state, blocked.take_output(), blocked.settings) == expected
    assert (jumping.state, jumping.take_output(), jumping.settings) == expected


def test_ticks_until_event_names_the_next_event() -> None:
    device = Device()
    assert device.ticks_until_event() is None
    send(device, "21 10")
    assert device.ticks_until_event() == 10
    device.run(9)
    assert device.ticks_until_event() == 1
    device.run(1)
    assert take(device) == ["D 10 0 0 0 0 0 0"]
    send(device, "21 0", "28 20", "3 1")
    assert device.ticks_until_event() == 20
    send(device, "28 0", "6 4", "1 3 1 2 3")
    assert device.ticks_until_event() == 9, "the third value is taken on the ninth tick"
    send(device, "4 0", "31 500", "1 1 5")
    assert device.ticks_until_event() == 500 - device.clock + 1
    send(device, "3 0")
    assert device.ticks_until_event() is None


def test_an_idle_device_runs_a_long_time_fast() -> None:
    device = Device()
    send(device, "3 1", "0 100")
    device.run(10_000_000)
    state = device.state
    assert state.clock == 10_000_000
    assert abs(state.actual - 100) <= 2


def test_a_block_of_ticks_equals_its_ticks_one_by_one_after_a_stale_derivative_history() -> None:
    """A tick that changes nothing is rest only when the derivative's error history holds
    one value: an older error still in the ring comes round later (extreme gains show it)."""
    lines = ("9 1 -12", "10 999 6", "11 999 6", "13 9999 3", "14 1 -12", "15 1 -12", "17 1 -12",
             "32 1 -12", "33 999 6", "5 1", "12 1", "16 1", "7 1", "21 1", "3 1",
             "1 3 -2147483648 2147483647 -2147483648")
    whole, stepped = Device(), Device()
    for device in (whole, stepped):
        send(device, *lines)
    whole.run(14)
    for _ in range(14):
        stepped.run(1)
    assert whole.take_timed_output() == stepped.take_timed_output()
    assert whole.state == stepped.state
