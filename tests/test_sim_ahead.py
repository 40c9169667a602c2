"""Devices run ahead of a virtual world's clock do exactly what they do run in step.

A host that promises quiet until some time lets the world run its devices ahead that far
in one block (``SimWorld.advance_to(..., quiet_until_us=...)``); input that comes earlier
after all takes a device back to the world's clock, from its checkpoint. Either way, every
byte the host reads arrives at the same time, and the devices end in the same state, as
when the world runs them only up to its clock."""

from __future__ import annotations

import math
import random
from pathlib import Path

import pytest

import usbmotion
from usbmotion.cli.run import default_machine
from usbmotion.device import Device
from usbmotion.device.core0 import Checkpoint
from usbmotion.errors import DeviceParameterError
from usbmotion.host.config import load_config
from usbmotion.sim.machine import connect_session
from usbmotion.sim.world import SimLink, SimWorld, VirtualClock

SETUP = b"5 1\n12 1\n6 10\n21 7\n3 1\n"
"""10 kHz servo, a diagnostics line every 7 ticks, setpoints every 10 ticks, enabled."""


def _sine(first: int, count: int) -> str:
    return " ".join(str(round(800 * math.sin(k / 150))) for k in range(first, first + count))


def _scenario(*, ahead: bool, seed: int, latency_us: int = 0,
              ) -> tuple[list[list[tuple[int, bytes]]], list[object], int]:
    """A host streaming setpoints to two devices, asking their status, reading everything
    as it comes, sleeping in between; with ``ahead``, each sleep promises quiet until a
    time that is sometimes kept and sometimes broken."""
    rng = random.Random(seed)
    world = SimWorld()
    links: list[SimLink] = []
    for key in ("A", "B"):
        world.add(Device(), key=key)
        links.append(world.connect(key, latency_us=latency_us))
        links[-1].write(SETUP)
    received: list[list[tuple[int, bytes]]] = [[] for _ in links]
    sent = [0, 0]
    for _ in range(120):
        for index, link in enumerate(links):
            roll = rng.random()
            if roll < 0.25:
                count = rng.randint(1, 40)
                link.write(f"1 {count} {_sine(sent[index], count)}\n2 -1\n".encode())
                sent[index] += count
            elif roll < 0.35:
                link.write(b"20 -1\n")
            if rng.random() < 0.5 and link.available():
                received[index].append((world.time_us, link.receive(1 << 20)))
        step = rng.choice((100, 700, 2_500, 9_000, 30_000))
        promise = world.time_us + rng.choice((0, step // 2, step, 3 * step, 200_000))
        if ahead:
            world.advance_to(world.time_us + step, quiet_until_us=promise)
        else:
            world.advance_to(world.time_us + step)
    for index, link in enumerate(links):
        received[index].append((world.time_us, link.receive(1 << 20)))
    states = [world.device(key).state for key in ("A", "B")]  # type: ignore[attr-defined]
    return received, states, world.rewinds


@pytest.mark.parametrize(("seed", "latency_us"), [(1, 0), (2, 0), (3, 250), (4, 1_000)])
def test_a_world_running_ahead_delivers_the_same_bytes_at_the_same_times(
        seed: int, latency_us: int) -> None:
    in_step, states, _ = _scenario(ahead=False, seed=seed, latency_us=latency_us)
    ahead, states_ahead, rewinds = _scenario(ahead=True, seed=seed, latency_us=latency_us)
    assert rewinds > 5  # the promise was broken, the devices taken back, many times
    assert sum(len(data) for runs in in_step for _, data in runs) > 10_000
    assert ahead == in_step
    assert states_ahead == states


def test_discarded_input_keeps_what_a_device_ahead_prints_later() -> None:
    world = SimWorld()
    world.add(Device(), key="A")
    link = world.connect("A")
    link.write(SETUP + b"1 30 " + _sine(0, 30).encode() + b"\n")
    world.advance_to(10_000, quiet_until_us=50_000)
    link.discard_input()
    assert link.available() == 0
    world.advance_to(20_000)
    later = link.receive(1 << 20)
    in_step = SimWorld()
    in_step.add(Device(), key="A")
    other = in_step.connect("A")
    other.write(SETUP + b"1 30 " + _sine(0, 30).encode() + b"\n")
    in_step.advance_to(10_000)
    other.discard_input()
    in_step.advance_to(20_000)
    assert later == other.receive(1 << 20) != b""


def test_a_device_rewinds_only_to_a_checkpoint_with_nothing_fed_since() -> None:
    device = Device()
    checkpoint = device.checkpoint()
    device.run(50)
    device.rewind(checkpoint)
    assert device.clock == 0
    device.feed(b"2 -1\n")
    with pytest.raises(DeviceParameterError, match="no input fed since"):
        device.rewind(checkpoint)
    assert isinstance(checkpoint, Checkpoint)


DEMO = Path(usbmotion.__file__).parent / "data" / "demos" / "1-rounded-square.ngc"


def _held_run(monkeypatch: pytest.MonkeyPatch, *, ahead: bool) -> tuple[dict[str, object], int]:
    """The demo, held 1.5 s into the program and resumed 1 s later (the requests made
    when the host's clock passes those times), in a world that runs its devices ahead or
    not: the report, and how often a device was taken back."""
    world = SimWorld()
    world.run_ahead = ahead
    config = load_config(default_machine())
    with connect_session(config, world=world) as session:
        homing_s = session.home()
        prepared = session.prepare(DEMO)
        start_us = world.time_us
        asked: list[str] = []

        def ask() -> None:
            elapsed = world.time_us - start_us
            if not asked and elapsed >= 1_500_000:
                session.request_hold()
                asked.append("hold")
            elif asked == ["hold"] and elapsed >= 2_500_000:
                session.request_resume()
                asked.append("resume")

        sleep, sleep_quiet = VirtualClock.sleep, VirtualClock.sleep_quiet

        def asking_sleep(clock: VirtualClock, seconds: float) -> None:
            ask()
            sleep(clock, seconds)

        def asking_sleep_quiet(clock: VirtualClock, seconds: float, *,
                               quiet_until: float) -> None:
            ask()
            sleep_quiet(clock, seconds, quiet_until=quiet_until)

        monkeypatch.setattr(VirtualClock, "sleep", asking_sleep)
        monkeypatch.setattr(VirtualClock, "sleep_quiet", asking_sleep_quiet)
        report, _ = session.run(prepared, homing_s=homing_s)
        monkeypatch.undo()
        assert session.last_run is not None and len(session.last_run.holds) == 1
    assert asked == ["hold", "resume"] and report.completed
    return report.to_json(), world.rewinds


def test_a_held_and_resumed_run_is_the_same_with_the_devices_run_ahead(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """A hold comes while the devices have run ahead (the host promised quiet until its
    next batch): they are taken back to the clock, and the run's report is the same, field
    for field, as in a world that never runs them ahead."""
    in_step, rewinds_in_step = _held_run(monkeypatch, ahead=False)
    ahead, rewinds = _held_run(monkeypatch, ahead=True)
    assert rewinds_in_step == 0 and rewinds >= 1
    assert ahead == in_step
