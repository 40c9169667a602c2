"""Call 35 (motion statistics), the peak following error of diagnostics lines, ALARM lines
and diagnostics stamped with their own tick."""

from __future__ import annotations

from collections.abc import Callable

import pytest
from tests.device.helpers import send, take

from usbmotion.device import Device, core0, core1
from usbmotion.device.core1 import STATS_SUM_CAP, wrap_int32
from usbmotion.device.kernel import numba_available
from usbmotion.host.device import DeviceClient, MotionStats
from usbmotion.sim.registry import drop_world, set_world
from usbmotion.sim.world import SimWorld

PATHS = [False, pytest.param(True, marks=pytest.mark.skipif(
    not numba_available(), reason="numba is not installed"))]


def stats(device: Device) -> MotionStats:
    """The device's answer to ``35 -1``."""
    (line,) = [line for line in send(device, "35 -1") if not line.startswith("D ")]
    head, *values = line.split()
    assert head == "MOTION_STATS"
    return MotionStats(*(int(v) for v in values))


def ramp(count: int, step: int) -> str:
    return f"1 {count} " + " ".join(str(step * (i + 1)) for i in range(count))


@pytest.mark.parametrize("fast", PATHS)
def test_statistics_count_every_running_tick(fast: bool) -> None:
    device = Device(fast=fast)
    send(device, "5 1", "6 10", "31 300", "3 1", "35 0", ramp(200, 40))
    counted, peak, peak_tick, total, last_take = 0, 0, 0, 0, -1
    for _ in range(2600):
        before = device.state
        device.run(1)
        after = device.state
        running = before.enable == 1 and (before.start_tick < 0 or before.clock >= 300)
        if after.queued < before.queued:
            last_take = before.clock
        if running:
            counted += 1
            size = abs(wrap_int32(after.desired - after.actual))
            if size > peak:
                peak, peak_tick = size, after.clock
            total += size * size
    assert counted == 2600 - 300, "the ticks before the armed start are not counted"
    assert peak > 0
    assert last_take == 300 + 199 * 10, "the last of 200 values, one every 10 ticks"
    assert stats(device) == MotionStats(counted, peak, peak_tick, total, last_take)


@pytest.mark.parametrize("fast", PATHS)
def test_statistics_are_the_same_whatever_the_blocks(fast: bool) -> None:
    """Tick by tick, one long run, and jumps from event to event (idle ticks skipped)."""
    lines = ["5 1", "6 10", "3 1", "35 0", ramp(100, -30), "33 90 0", "21 37"]
    stepped, blocked, jumping = Device(fast=fast), Device(fast=fast), Device(fast=fast)
    for device in (stepped, blocked, jumping):
        send(device, *lines)
    total = 5000
    for _ in range(total):
        stepped.run(1)
    blocked.run(total)
    done = 0
    while done < total:
        step = min(jumping.ticks_until_event(diagnostics=False) or total, total - done)
        jumping.run(step)
        done += step
    expected = stats(stepped)
    assert expected.ticks == total and expected.sum_sq_error > 0
    assert stats(blocked) == expected
    assert stats(jumping) == expected


NO_DRIVE = ("33 0 0", "9 0 0", "10 0 0", "11 0 0")
"""No load and no gain: the output is 0 V and the shaft stays where it is, so the following
error of each tick is exactly the desired position minus the counter."""


@pytest.mark.parametrize("fast", PATHS)
def test_the_peak_is_signed_and_the_earlier_tick_wins_a_tie(fast: bool) -> None:
    device = Device(fast=fast)
    send(device, *NO_DRIVE, "1 6 5 -5 3 -7 7 -2", "3 1", "21 3")
    device.run(6)
    assert take(device) == ["D 3 3 0 0 0 3 5", "D 6 -2 0 0 0 0 -7"]


@pytest.mark.parametrize("fast", PATHS)
def test_the_peak_is_the_wrapped_error(fast: bool) -> None:
    """-2^31 - (2^31 - 1) wraps to 1, -1 - (2^31 - 1) to -2^31 (the largest magnitude)."""
    device = Device(fast=fast)
    send(device, *NO_DRIVE, "23 2147483647", "1 2 -2147483648 -1", "3 1", "21 1")
    device.run(2)
    assert take(device) == ["D 1 -2147483648 2147483647 0 0 1 1",
                            "D 2 -1 2147483647 0 0 0 -2147483648"]


@pytest.mark.parametrize(("between", "peak"), [
    (("35 0",), 1),
    (("21 3",), 1),
    (("21 0", "21 3"), 1),
    (("35 -1",), 9),
    (("21 -1",), 9),
    (("22 0",), 9),
    (("23 0", "1 2 1 1"), 9),
    (("37 5", "1 2 1 1"), 9),
    (("3 0", "3 1", "1 2 1 1"), 9),
    (("30 0", "8 35 1"), 9),
], ids=lambda value: " ".join(value) if isinstance(value, tuple) else str(value))
def test_the_peak_restarts_with_the_interval_and_the_statistics_reset_only(
        between: tuple[str, ...], peak: int) -> None:
    """A tick of error 9, the lines ``between``, then ticks of a smaller error (1, or -4
    after 37 5): the peak of the next diagnostics line."""
    device = Device()
    send(device, *NO_DRIVE, "1 3 9 1 1", "3 1", "21 3")
    device.run(1)
    send(device, *between)
    device.run(3)
    lines = [line for line in take(device) if line.startswith("D ")]
    assert int(lines[0].split()[-1]) == peak, lines


def pick_peak(errors: list[int]) -> int:
    """The error of the largest magnitude, the first on a tie; 0 for none."""
    peak = 0
    for error in errors:
        if abs(error) > abs(peak):
            peak = error
    return peak


PEAK_STEPS: list[tuple[tuple[str, ...], int]] = [
    (("31 40", "3 1", ramp(60, 40), "1 60 " + " ".join(str(2400 - 40 * i) for i in range(60)),
      "21 7"), 300),
    (("35 0",), 31),
    (("21 5",), 40),
    (("22 0", "23 100", "1 20 " + " ".join(["-300"] * 20)), 33),
    ((*NO_DRIVE, "0 700"), 1500),
    (("21 300",), 10),
    (("0 -100",), 1000),
    (("3 0",), 700),
    (("3 1", "21 5", "29 50", "0 -2000"), 30),
]
"""Moves both ways after an armed start, the statistics reset and the interval set between
two lines, the clock zeroed and the counter set; then no drive: the shaft stops and the error
stands (ticks core0 skips at rest), lines far apart, a smaller error standing after a larger
one in the same interval, the servo disabled (ticks not counted); and a following-error
fault: counted on its tick, nothing counted after it."""


def peak_oracle(device: Device) -> list[tuple[str, int]]:
    """Run PEAK_STEPS a tick at a time: each diagnostics line printed, with the peak that
    call 21's notes define, from the desired and actual positions of each tick counted."""
    found: list[tuple[str, int]] = []
    pending: list[int] = []
    for lines, ticks in PEAK_STEPS:
        send(device, *lines)
        if any(line.split()[:1] == ["21"] or line == "35 0" for line in lines):
            pending = []
        for _ in range(ticks):
            before = device.state
            device.run(1)
            after = device.state
            if (before.enable == 1 and before.mode != 2
                    and (before.start_tick < 0 or before.clock >= before.start_tick)):
                pending.append(wrap_int32(after.desired - after.actual))
            for line in take(device):
                if line.startswith("D "):
                    found.append((line, pick_peak(pending)))
                    pending = []
    return found


def run_steps(device: Device, run: Callable[[Device, int], None]) -> list[str]:
    printed: list[str] = []
    for lines, ticks in PEAK_STEPS:
        printed += send(device, *lines)
        run(device, ticks)
        printed += take(device)
    return printed


def run_in_blocks(device: Device, ticks: int) -> None:
    device.run(ticks)


def run_from_event_to_event(device: Device, ticks: int) -> None:
    done = 0
    while done < ticks:
        step = min(device.ticks_until_event(diagnostics=False) or ticks, ticks - done)
        device.run(step)
        done += step


@pytest.mark.parametrize("fast", PATHS)
def test_each_line_carries_the_peak_of_every_tick_since_the_line_before(
        fast: bool, monkeypatch: pytest.MonkeyPatch) -> None:
    expected = peak_oracle(Device(fast=fast))
    for line, peak in expected:
        assert int(line.split()[-1]) == peak, line
    peaks = [peak for _, peak in expected]
    assert min(peaks) < -500 and max(peaks) > 500, "both signs"
    assert peaks[:5] == [0, 0, 0, 0, 0], "none counted before the armed start"
    assert peaks[-1] == 0, "none counted after the fault"
    skipped: list[int] = []

    def idle_advance(state: core1.IntArray, params: core1.IntArray, ticks: int) -> None:
        skipped.append(int(state[core1.S_DIAG_PEAK]))
        core1.idle_advance(state, params, ticks)

    monkeypatch.setattr(core0, "idle_advance", idle_advance)
    lines = [line for line, _ in expected]
    for run in (run_in_blocks, run_from_event_to_event):
        printed = run_steps(Device(fast=fast), run)
        assert [line for line in printed if line.startswith("D ")] == lines, run.__name__
    assert any(peak != 0 for peak in skipped), "idle ticks skipped with an error standing"


def test_velocity_mode_and_a_disabled_servo_are_not_counted() -> None:
    device = Device()
    send(device, "35 0")
    device.run(100)
    assert stats(device).ticks == 0, "disabled"
    send(device, "7 2", "3 1", "35 0", "1 3 100 100 100")
    started = device.clock
    device.run(100)
    assert stats(device) == MotionStats(0, 0, 0, 0, started + 2), "velocity mode: queue takes"


def test_a_reset_keeps_the_clock_and_forgets_the_rest() -> None:
    device = Device()
    send(device, "3 1", "35 0", "1 3 50 100 150")
    device.run(20)
    assert stats(device).ticks == 20
    assert send(device, "8 35 1", "35 0") == ["MOTION STATS RESET"]
    assert stats(device) == MotionStats(0, 0, 0, 0, -1)
    assert device.clock == 20


@pytest.mark.parametrize("fast", PATHS)
def test_the_sum_of_squares_stops_at_its_cap(fast: bool) -> None:
    device = Device(fast=fast)
    send(device, "3 1", "35 0", "0 1000")
    device._state[core1.S_STATS_SUM_SQ] = STATS_SUM_CAP - 5
    device.run(3)
    assert stats(device).sum_sq_error == STATS_SUM_CAP


@pytest.mark.parametrize("fast", PATHS)
def test_a_fault_is_announced_at_its_tick(fast: bool) -> None:
    device = Device(fast=fast)
    send(device, "29 60", "3 1", "21 5", ramp(300, 8))
    device.run(100)
    lines = take(device)
    state = device.state
    assert state.fault == 2
    assert state.fault_tick > 10
    alarms = [i for i, line in enumerate(lines) if not line.startswith("D ")]
    assert [lines[i] for i in alarms] == [f"ALARM 2 {state.fault_tick}"], "once"
    ticks = [int(line.split()[1]) for line in lines if line.startswith("D ")]
    assert ticks == list(range(5, 101, 5)), "diagnostics go on while disabled"
    before = alarms[0]
    assert int(lines[before - 1].split()[1]) <= state.fault_tick < int(lines[before + 1].split()[1])


@pytest.mark.parametrize("fast", PATHS)
def test_diagnostics_in_one_block_are_stamped_with_their_own_tick(fast: bool) -> None:
    device = Device(fast=fast)
    send(device, "5 1", "6 10", "3 1", ramp(500, 3), "21 7")
    event = device.ticks_until_event(diagnostics=False)
    assert event is not None and event > 1000, "the block runs through the diagnostics"
    device.run(1000)
    runs = device.take_timed_output()
    assert len(runs) == 1000 // 7
    for ticks_ago, data in runs:
        (line,) = data.decode("ascii").splitlines()
        assert device.clock - int(line.split()[1]) == ticks_ago


def test_the_world_delivers_each_diagnostics_line_at_its_time() -> None:
    world = SimWorld()
    device = Device()
    world.add(device, key="A")
    link = world.connect("A", latency_us=250)
    device.feed(b"3 1\n" + ramp(300, 5).encode() + b"\n21 10\n")
    device.take_output()
    world.advance(200_000)
    arrivals = [due for due, _ in link._outbox]
    assert len(arrivals) == 20
    assert arrivals == [(i + 1) * 10_000 + 250 for i in range(20)]


def test_read_pending_takes_alarms_and_counts_stray_lines() -> None:
    world = SimWorld()
    world.add(Device(), key="A")
    set_world("stats-test", world)
    client = DeviceClient.open("sim://A?world=stats-test", name="A")
    try:
        seen: list[tuple[int, int]] = []
        client.on_alarm = lambda alarm: seen.append((alarm.fault, alarm.tick))
        client.transport.write(b"29 10\n3 1\n0 4000\n2 -1\n")
        world.advance(50_000)
        client.read_pending()
        assert len(seen) == 1 and seen[0][0] == 2
        assert client.alarms[0].fault_name == "following error"
        assert client.stray_lines == 1, "the answer to 2 -1 that nobody awaited"
        assert client.fault() == seen[0], "the alarm carries what call 30 reports"
    finally:
        client.close()
        drop_world("stats-test")
