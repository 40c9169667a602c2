"""A simulated world in real time: its devices live at the wall clock's pace while the host
talks to them or idles, and the time its host spends computing (the machine running the
simulation busy) is time the world stood still, never a silence its devices would see."""

from __future__ import annotations

import time
from collections.abc import Iterator

import pytest

from usbmotion.device import Device
from usbmotion.host.device import DeviceClient
from usbmotion.sim import SimWorld, drop_world, set_world
from usbmotion.sim.world import IDLE_STEP_S, REALTIME_SLACK_S

pytestmark = pytest.mark.realtime

WATCHDOG_MS = 300


@pytest.fixture
def enabled() -> Iterator[tuple[SimWorld, DeviceClient]]:
    world = SimWorld(realtime=True)
    world.add(Device(), key="X")  # type: ignore[arg-type]
    set_world("realtime-world", world)
    client = DeviceClient.open("sim://X?world=realtime-world", name="X")
    client.set_watchdog_ms(WATCHDOG_MS)
    client.set_servo_enable(True)
    yield world, client
    client.close()
    drop_world("realtime-world")


def _busy(seconds: float) -> None:
    """The host computing: no call to the world."""
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        pass


def test_a_host_busy_computing_is_not_a_silence_the_watchdog_sees(
        enabled: tuple[SimWorld, DeviceClient]) -> None:
    world, client = enabled
    for _ in range(3):
        _busy(3 * WATCHDOG_MS / 1000)
        world.keep_pace()  # an idle front's keep-alive, first thing after the computing
        status = client.status()
        assert status.fault == 0 and status.enabled, status
    assert world.time_us / 1e6 < 3 * (IDLE_STEP_S + REALTIME_SLACK_S) + 1.0


def test_an_idle_host_that_says_nothing_trips_the_watchdog(
        enabled: tuple[SimWorld, DeviceClient]) -> None:
    """The world still runs at the wall clock's pace while the host idles: a watchdog
    counts real silence."""
    world, client = enabled
    started = world.time_us
    deadline = time.monotonic() + 3 * WATCHDOG_MS / 1000
    while time.monotonic() < deadline:
        world.keep_pace()
        time.sleep(0.02)
    assert (world.time_us - started) / 1e6 >= 2 * WATCHDOG_MS / 1000
    status = client.status()
    assert status.fault == 1 and not status.enabled, status


def test_a_world_that_fell_behind_catches_up_only_its_slack(
        enabled: tuple[SimWorld, DeviceClient]) -> None:
    world, _ = enabled
    before = world.time_us
    _busy(0.5)
    started = time.monotonic()
    world.advance(1000)  # the host waits a millisecond on a device
    world.advance(int(REALTIME_SLACK_S * 1e6) + 20_000)  # then longer: in real time again
    waited_s = time.monotonic() - started
    assert (world.time_us - before) / 1e6 < 0.5
    assert waited_s >= 0.015, "past the slack it sleeps: real time, not a catch-up"
