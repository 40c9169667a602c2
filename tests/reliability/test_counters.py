"""Counters at their boundaries: the int32 position counter wraps, and velocity mode resets
the counter every 60 s, as the hardware does.

``tests/device/test_servo.py`` shows one forward move across the wrap and the reset at 1 ms
ticks; these tests go to the edges: both directions one count at a time with a following
error limit armed, the velocity reading across the wrap and across the reset (exact, at
1 kHz and 10 kHz), servo periods that do not divide a minute (no drift over five resets),
the minute counted from entering velocity mode, and a homing that outlasts a minute.
"""

from __future__ import annotations

import itertools
import math

import pytest

from usbmotion.device import Device
from usbmotion.device.core1 import wrap_int32
from usbmotion.device.motor import MICRO
from usbmotion.host.config import parse_config
from usbmotion.protocol import ReplyKind, parse_reply
from usbmotion.protocol.table import INT32_MAX, INT32_MIN
from usbmotion.session import home_position_mm
from usbmotion.sim.machine import connect_session

VELOCITY_GAINS = ("9 7 -3", "10 1 0", "11 0 0")
MINUTE_US = 60_000_000


def _send(device: Device, *lines: str) -> list[str]:
    device.feed("".join(line + "\n" for line in lines).encode("ascii"))
    return device.take_output().decode("ascii").splitlines()


def _count(device: Device) -> int:
    """The shaft position in whole counts from power-up (never wraps)."""
    return device.state.shaft_micro_counts // MICRO


@pytest.mark.parametrize("step", [1, -1])
def test_the_counter_crosses_its_end_one_count_at_a_time_without_a_fault(step: int) -> None:
    device = Device()
    start = INT32_MAX - 19 if step > 0 else INT32_MIN + 19
    targets = [wrap_int32(start + step * k) for k in range(1, 41)]
    assert any(t == INT32_MAX for t in targets) and any(t == INT32_MIN for t in targets)
    assert _send(device, "29 20", f"23 {start}", "6 20", "3 1") == []
    shaft = _count(device)
    assert _send(device, f"1 {len(targets)} " + " ".join(map(str, targets))) == []
    previous = start
    for _ in range(len(targets) * 20 + 300):
        device.run(1)
        actual = device.state.actual
        assert abs(wrap_int32(actual - previous)) <= 3, "no jump at the end of the range"
        previous = actual
    state = device.state
    assert (state.fault, state.enable) == (0, 1), "the wrap is no following error"
    assert abs(wrap_int32(state.actual - targets[-1])) <= 2
    assert abs(_count(device) - shaft - 40 * step) <= 2, "the shaft went the short way"
    status = parse_reply(_send(device, "20 -1")[0])
    assert status.kind is ReplyKind.QUERY and INT32_MIN <= status.values[1] <= INT32_MAX


@pytest.mark.parametrize("interval_dms", [10, 1])
def test_the_velocity_reading_is_exact_across_the_wrap(interval_dms: int) -> None:
    device = Device()
    tick_us = interval_dms * 100
    window = min(10, max(1, 1000 // tick_us))
    scalar = 4000 // tick_us
    ramp = [wrap_int32(INT32_MAX - 3000 + (k * k) // 2000) for k in range(0, 4000, 4)]
    assert _send(device, f"5 {interval_dms}", f"6 {scalar}", f"23 {INT32_MAX - 3000}",
                 "3 1") == []
    assert _send(device, f"1 {len(ramp)} " + " ".join(map(str, ramp))) == []
    counters: list[int] = []
    shafts: list[int] = []
    for _ in range(len(ramp) * scalar + 200 * window):
        device.run(1)
        state = device.state
        counters.append(state.actual)
        shafts.append(_count(device))
        if len(counters) > window:
            moved = wrap_int32(counters[-1] - counters[-1 - window])
            assert moved == shafts[-1] - shafts[-1 - window]
            assert state.velocity == moved * 1_000_000 // (window * tick_us)
    pairs = list(itertools.pairwise(counters))
    assert sum(a > 0 > b for a, b in pairs) == 1, "the move crossed the end once, forward"
    assert sum(a < 0 < b for a, b in pairs) == 0
    assert device.state.fault == 0


def test_setting_the_counter_to_either_end_and_stepping_over_it() -> None:
    for set_to, then in ((INT32_MAX, INT32_MIN), (INT32_MIN, INT32_MAX)):
        device = Device()
        assert _send(device, "29 5", f"23 {set_to}", "3 1", f"0 {then}") == []
        shaft = _count(device)
        device.run(300)
        state = device.state
        assert (state.actual, state.fault) == (then, 0)
        assert _count(device) - shaft == (1 if set_to == INT32_MAX else -1)


def _reset_ticks(tick_us: int, resets: int) -> list[int]:
    """Ticks after entering velocity mode at which the counter resets: the first tick at or
    after each whole minute (the remainder carries over, so there is no drift)."""
    return [math.ceil(k * MINUTE_US / tick_us) for k in range(1, resets + 1)]


@pytest.mark.parametrize("interval_dms", [70, 130])
def test_the_reset_falls_on_the_first_tick_of_each_minute_with_no_drift(
    interval_dms: int,
) -> None:
    tick_us = interval_dms * 100
    assert MINUTE_US % tick_us != 0, "a period that does not divide a minute"
    device = Device()
    twin = Device()
    lines = (f"5 {interval_dms}", "7 2", *VELOCITY_GAINS, "6 65535", "3 1", "0 2000")
    for each in (device, twin):
        assert _send(each, *lines) == []
    entered = device.clock
    done = 0
    for reset in _reset_ticks(tick_us, 5):
        device.run(reset - 1 - done)
        assert device.state.actual > 1000, "counting up to the last tick of the minute"
        device.run(1)
        assert device.state.actual == 0, f"reset on tick {reset} after entering mode 2"
        done = reset
    twin.run(device.clock - entered)
    assert twin.state == device.state, "one long run resets on the same ticks"
    assert device.state.fault == 0


def test_the_minute_is_counted_in_velocity_mode_from_entering_it() -> None:
    device = Device()
    device.run(30_000)
    assert _send(device, "7 2", "23 5000") == []
    device.run(45_000)
    assert _send(device, "7 1", "7 2", "22 0", "23 5000") == [], "leave and re-enter at 45 s"
    device.run(59_999)
    assert device.state.actual == 5000, "the minute restarted on entering mode 2 again"
    device.run(1)
    assert device.state.actual == 0, "reset while the servo is off too: it is the counter's"
    assert device.clock == 60_000, "zeroing the clock does not move the reset"
    device.run(60_000)
    assert device.state.actual == 0


def test_the_velocity_reading_is_exact_across_the_reset_at_10_khz() -> None:
    device = Device()
    assert _send(device, "5 1", "7 2", *VELOCITY_GAINS, "6 65535", "3 1",
                 "1 10" + " 3000" * 10) == [], "3000 counts/s for 10 x 6.5 s"
    reset = _reset_ticks(100, 1)[0]
    device.run(reset - 30)
    counters: list[int] = []
    shafts: list[int] = []
    for _ in range(60):
        device.run(1)
        counters.append(device.state.actual)
        shafts.append(_count(device))
        if len(counters) > 10:
            moved = shafts[-1] - shafts[-11]
            assert device.state.velocity == moved * 1000, "counts over the last 1 ms, x1000"
            assert 2000 <= device.state.velocity <= 4000
    assert counters[28] > 100_000 and counters[29] == 0, "the reset is on its tick"


HOMING_MACHINE = """
name = "one slow axis"
homing_order = ["X"]
[axes.X]
url = "sim://X"
counts_per_mm = 240.0
max_velocity_mm_s = 25.0
max_accel_mm_s2 = 500.0
travel_mm = [0.0, 200.0]
gains = { kp = 1.0, ki = 1.0, kd = 0.007 }
homing = { direction = -1, speed_mm_s = 2.0, slow_speed_mm_s = 0.1, backoff_mm = 3.0 }
sim = { start_mm = 110.0 }
"""


def test_a_homing_that_outlasts_a_minute_still_zeroes_at_the_switch() -> None:
    config = parse_config(HOMING_MACHINE, path="slow.toml")
    axis = config.axis("X")
    travel = axis.sim_travel_counts
    assert travel is not None
    with connect_session(config) as session:
        machine = session.machine
        assert machine.world is not None
        device = machine.world.device("X")
        assert isinstance(device, Device)
        seconds = session.home()
        assert seconds > 60, "the counter reset at least once while homing in velocity mode"
        status = machine.axis("X").client.status()
        assert not status.lower_limit and status.fault == 0 and status.enabled
        assert status.desired_counts == axis.scale.to_counts(home_position_mm(axis))
        switch = axis.scale.to_counts(axis.homing.position_mm)
        shaft_at_edge = _count(device) - (status.actual_counts - switch)
        assert shaft_at_edge == travel[0], "the zero is the switch itself, to the count"
