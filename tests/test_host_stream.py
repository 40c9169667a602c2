"""Streaming setpoints with flow control: the same suite on sim:// and on pseudo-terminals."""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from usbmotion.device import Device
from usbmotion.errors import ArgumentError, OutOfRangeError, QueueFullError, QueueUnderrunError
from usbmotion.host.device import DeviceClient
from usbmotion.host.stream import SetpointStream, StreamProgress, run_streams, wait_until_drained
from usbmotion.host.transport import LineTransport
from usbmotion.protocol import Replaced, values_crc32
from usbmotion.sim import SimWorld, drop_world, set_world

SETPOINTS = 20_000
AXES = ("X", "Y", "Z")


@dataclass
class Rig:
    clients: list[DeviceClient]
    realtime: bool


def _setpoints(index: int) -> np.ndarray:
    """A distinct, recognisable ramp per axis: small steps the motor can follow."""
    base = np.arange(SETPOINTS, dtype=np.int64)
    return (base // 4) * (index + 1)


@pytest.fixture
def sim_rig() -> Iterator[Rig]:
    world = SimWorld()
    for name in AXES:
        world.add(Device(), key=name)
    set_world("stream-test", world)
    clients = [DeviceClient.open(f"sim://{name}?world=stream-test", name=name) for name in AXES]
    yield Rig(clients, realtime=False)
    for client in clients:
        client.close()
    drop_world("stream-test")


@pytest.fixture
def pty_rig(tmp_path: Path) -> Iterator[Rig]:
    process = subprocess.Popen(
        [sys.executable, "-m", "usbmotion", "sim", "--pty", "3",
         "--flash-dir", str(tmp_path)],
        stdout=subprocess.PIPE, text=True,
    )
    try:
        assert process.stdout is not None
        paths = [process.stdout.readline().rsplit(" ", 1)[1].strip() for _ in AXES]
        clients = [DeviceClient(LineTransport.open(path), name=name, timeout_s=2.0)
                   for name, path in zip(AXES, paths, strict=True)]
        yield Rig(clients, realtime=True)
        for client in clients:
            client.close()
    finally:
        process.terminate()
        process.wait(timeout=10)


def _stream_everything(rig: Rig) -> None:
    clients = rig.clients
    for client in clients:
        client.set_servo_interval_dms(1)  # 10 kHz: 20,000 setpoints are 2 s of device time
        client.set_servo_enable(True)
    period_s = clients[0].motion_period_s()
    progress: list[StreamProgress] = []
    # verify: the device acknowledges every batch it queues (ADDED N CRC c) and the stream
    # checks it; the acknowledgements must cover the setpoints once, in order
    acked: dict[int, list[tuple[int, int]]] = {i: [] for i in range(len(clients))}
    streams = [SetpointStream(c, _setpoints(i), period_s=period_s, verify=True,
                              on_progress=progress.append,
                              on_acknowledgement=lambda n, crc, i=i: acked[i].append((n, crc)))
               for i, c in enumerate(clients)]
    run_streams(streams)
    wait_until_drained(clients, period_s=period_s)
    for index, (client, stream) in enumerate(zip(clients, streams, strict=True)):
        wanted, start = _setpoints(index), 0
        for count, crc in acked[index]:
            assert crc == values_crc32(wanted[start : start + count]), "in order, intact"
            start += count
        assert start == SETPOINTS, "every value once"
        assert stream.garbled_lines == stream.errors == stream.timeouts == 0
        assert client.refusals == 0, "no E0/E1 in normal operation"
        result = stream.result()
        assert result.refusals == 0
        assert result.sent == SETPOINTS
        assert result.max_queued <= 1000
        status = client.status()
        assert status.queued == 0
        assert status.desired_counts == int(_setpoints(index)[-1])
    assert progress, "progress was reported"
    assert progress[-1].sent == SETPOINTS


def test_stream_20000_setpoints_to_3_sim_devices(sim_rig: Rig) -> None:
    _stream_everything(sim_rig)


@pytest.mark.realtime
def test_stream_20000_setpoints_to_3_devices_on_ptys(pty_rig: Rig) -> None:
    _stream_everything(pty_rig)


def test_a_stalled_consumer_makes_the_host_wait_without_overflow(sim_rig: Rig) -> None:
    client = sim_rig.clients[0]
    client.set_servo_enable(False)  # the device consumes nothing while disabled
    period_s = client.motion_period_s()
    seen: list[StreamProgress] = []
    stream = SetpointStream(client, list(range(3000)), period_s=period_s,
                            on_progress=seen.append)
    clock = client.transport.clock
    started = clock.now()
    while clock.now() - started < 2.0:
        stream.service()
        clock.sleep(max(0.0, min(stream.wake_time(), started + 2.0) - clock.now()))
    queued, free = client.queue_status()
    assert queued == stream.sent, "everything sent is still queued: nothing consumed or lost"
    assert 300 < queued <= 900, "filled above the low watermark, never past the high one"
    assert free == 1000 - queued
    assert client.refusals == 0
    assert len(seen) >= 5, "the waiting host kept polling and reporting progress"
    assert {p.sent for p in seen[-5:]} == {queued}
    client.set_servo_enable(True)  # the consumer resumes: the rest flows in
    run_streams([stream])
    wait_until_drained([client], period_s=period_s)
    assert stream.sent == 3000
    assert client.refusals == 0
    assert client.status().desired_counts == 2999


def test_a_slow_consumer_is_followed(sim_rig: Rig) -> None:
    client = sim_rig.clients[1]
    client.set_motion_scalar(7)  # one value every 7 ticks
    client.set_servo_enable(True)
    period_s = client.motion_period_s()
    stream = SetpointStream(client, list(range(2500)), period_s=period_s)
    run_streams([stream])
    wait_until_drained([client], period_s=period_s)
    assert stream.result().refusals == 0
    assert client.status().desired_counts == 2499


def test_a_refused_batch_is_resent_exactly(sim_rig: Rig) -> None:
    client = sim_rig.clients[2]
    device = client.transport.port.link.world.device("Z")
    desired: list[int] = []
    client.on_diagnostics = lambda line: desired.append(line.desired)
    client.set_diagnostics_interval(1)  # the device reports its desired value every tick
    client.set_servo_enable(True)
    stream = SetpointStream(client, list(range(1500)), period_s=client.motion_period_s())
    real_status = stream._status
    calls = [0]

    def status_then_interference() -> tuple[int, int]:
        answer = real_status()
        calls[0] += 1
        if calls[0] == 1:  # right after the stream sized its first batch on this answer
            device.feed(("1 700" + " -7" * 700 + "\n").encode())  # another host fills it
        return answer

    stream._status = status_then_interference  # type: ignore[method-assign]
    stream.service()
    assert stream.refusals == 1, "the device answered E1 to the first batch"
    assert stream.sent == 0, "a refused batch counts as not sent"
    run_streams([stream])
    wait_until_drained([client], period_s=stream.period_s)
    client.set_diagnostics_interval(0)
    executed = [v for i, v in enumerate(desired) if v != -7 and (i == 0 or v != desired[i - 1])]
    assert executed[0] == 0 and executed[-1] == 1499
    assert [v for v in executed if v >= 0] == list(range(1500)), (
        "resent exactly: nothing lost, doubled or reordered"
    )


@pytest.mark.parametrize(
    ("call", "message"),
    [
        (lambda c: c.set_servo_interval_dms(0), "interval_dms 0 is out of range 1..10000"),
        (lambda c: c.set_motion_scalar(-1), "scalar -1 is out of range 1..65535"),
        (lambda c: c.set_control_mode(4), "mode 4 is not a control mode"),
        (lambda c: c.set_servo_enable(2), "enable 2 must be True or False"),
        (lambda c: c.add_setpoint(2**31), "value 2147483648 is out of range"),
        (lambda c: c.add_setpoints([1] * 1001), "count 1001 is out of range 1..1000"),
        (lambda c: c.set_gains(kp=-1.0, ki=0.0, kd=0.0), "kp -1.0 is negative"),
        (lambda c: c.set_gains(kp=1e9, ki=0.0, kd=0.0), "exponent 7 is out of range -12..6"),
        (lambda c: c.set_gains(kp=float("nan"), ki=0.0, kd=0.0), "kp nan is not a finite"),
        (lambda c: c.set_name("X" * 26), "longer than 25 characters"),
        (lambda c: c.set_name("caf\u00e9"), "only printable ASCII"),
        (lambda c: c.set_sim_travel(10, 10), "lower 10 must be below upper 10"),
        (lambda c: c.set_watchdog_ms(-5), "timeout_ms -5 is out of range 0..600000"),
        (lambda c: c.set_following_error_limit(-1), "counts -1 is out of range"),
        (lambda c: c.start_at(-3), "tick -3 is out of range"),
        (lambda c: c.set_diagnostics_interval(-2), "ticks -2 is out of range"),
        (lambda c: c.set_position(2**31), "position 2147483648 is out of range"),
        (lambda c: c.set_debug_flag(99, 1), "call 99 is out of range 0..63"),
        (lambda c: c.set_sim_counts_per_revolution(0), "counts 0 is out of range"),
        (lambda c: c.set_sim_value(13, -12.0, label="source_voltage_v"), "coefficient -1200"),
    ],
)
def test_every_method_validates_before_sending(sim_rig: Rig, call, message: str) -> None:  # type: ignore[no-untyped-def]
    client = sim_rig.clients[0]
    before = client.transport.bytes_written
    with pytest.raises(OutOfRangeError) as caught:
        call(client)
    assert message in str(caught.value)
    assert client.transport.bytes_written == before, "nothing was sent"


def test_stream_arguments_are_validated(sim_rig: Rig) -> None:
    client = sim_rig.clients[0]
    with pytest.raises(ArgumentError, match="period_s 0"):
        SetpointStream(client, [1], period_s=0)
    with pytest.raises(ArgumentError, match="low 900, high 800"):
        SetpointStream(client, [1], period_s=0.001, low_water=900, high_water=800)
    with pytest.raises(ArgumentError, match="outside int32"):
        SetpointStream(client, [2**40], period_s=0.001)
    with pytest.raises(ArgumentError, match="must be integers"):
        SetpointStream(client, np.array([1.5]), period_s=0.001)


def _queue_half_a_stream(client: DeviceClient) -> tuple[SetpointStream, int, int]:
    """A stream of 2000 ramp values filling a running device's queue to ~1000: the stream,
    the index of the value due ~800 values ahead of the device, and that value's tick."""
    client.set_servo_enable(True)
    stream = SetpointStream(client, np.arange(2000, dtype=np.int64) // 8,
                            period_s=client.motion_period_s(), low_water=850, high_water=1000)
    clock = client.transport.clock
    while stream.sent < 1000:
        stream.service()
        clock.sleep(max(0.0, stream.wake_time() - clock.now()))
    status = client.status()
    consumed = stream.sent - status.queued
    return stream, consumed + 800, status.clock + 800


@pytest.mark.parametrize("estimate_short", [False, True])
def test_a_replacement_takes_what_the_queue_has_room_for(sim_rig: Rig,
                                                          estimate_short: bool) -> None:
    """Call 38 from a tick far ahead, where the device keeps most of its queue: the stream
    sends only what fits beside the values kept (a refusal, which changes nothing, when its
    estimate of the room was short, is tried again with fewer), then streams the rest: the
    device plays the kept values and every new one, in order, and the stream's account of
    its queue is the device's."""
    client = sim_rig.clients[0]
    stream, index, tick = _queue_half_a_stream(client)
    steps = np.arange(700, dtype=np.int64)
    new = (index + steps) // 8 + steps // 8  # the ramp, from the seam on twice as steep
    real = client.replace_from
    carried: list[tuple[int, str]] = []

    def replace_from(at: int, values: list[int]) -> Replaced:
        if estimate_short and not carried:
            carried.append((len(values), "E38"))
            raise QueueFullError("E38 (as if the room was less than estimated)")
        answer = real(at, values)
        carried.append((len(values), "ok"))
        return answer

    client.replace_from = replace_from  # type: ignore[method-assign]
    desired: list[int] = []
    client.on_diagnostics = lambda line: desired.append(line.desired)
    client.set_diagnostics_interval(1)
    count = stream.replace_from(tick, index, new, most=600)
    assert 0 < count <= 200 and carried[-1] == (count, "ok"), carried
    if estimate_short:
        assert carried[0][0] == 2 * count, "tried again with half as many"
    queued, _ = client.queue_status()
    assert abs(queued - (stream.sent - stream.consumed_estimate)) <= 1
    run_streams([stream])
    wait_until_drained([client], period_s=stream.period_s)
    client.read_pending()
    assert stream.sent == index + new.size
    played = np.array(desired)
    assert played[-1] == new[-1]
    steps = np.abs(np.diff(played))
    assert steps.max() <= 1, "kept values, then every new one in order: no jump"


def _ran_dry(rig: Rig, values: np.ndarray) -> tuple[SetpointStream, int]:
    """X's stream of ``values`` (dry_is_late) after its device ran its first batch and 1 s
    more: the refill finds the queue empty. Returns the stream and the device tick its
    value 0 was due on."""
    client = rig.clients[0]
    client.set_servo_enable(True)
    stream = SetpointStream(client, values, period_s=0.001, dry_is_late=True)
    start = client.clock()
    stream.service()
    client.link_clock.sleep(1.0)
    with pytest.raises(QueueUnderrunError, match="motion queue ran dry with") as caught:
        stream.service()
    assert caught.value.confirmed == stream.sent == 600
    return stream, start


def test_a_stream_that_ran_dry_where_it_stands_still_is_taken_up_on_schedule(
        sim_rig: Rig) -> None:
    values = np.concatenate((np.zeros(2000, dtype=np.int64), np.arange(1000, dtype=np.int64)))
    stream, start = _ran_dry(sim_rig, values)
    index = (sim_rig.clients[0].clock() - start) - 5  # a row already due
    assert stream.rejoin_at_rest(start + index, index, ahead=100, most=600)
    assert stream.sent == index + 600
    queued, _ = sim_rig.clients[0].queue_status()
    assert queued == stream.sent - (sim_rig.clients[0].clock() - start), (
        "the rows already past were skipped: the queue runs on the schedule")


def test_a_stream_that_ran_dry_at_rest_to_its_end_is_done(sim_rig: Rig) -> None:
    stream, start = _ran_dry(sim_rig, np.zeros(1200, dtype=np.int64))
    assert stream.rejoin_at_rest(start + stream.total, stream.total, ahead=100, most=600)
    assert stream.done_sending


def test_a_stream_that_ran_dry_where_it_was_to_move_is_not_taken_up(sim_rig: Rig) -> None:
    values = np.concatenate((np.zeros(900, dtype=np.int64), np.arange(1000, dtype=np.int64)))
    stream, start = _ran_dry(sim_rig, values)
    index = sim_rig.clients[0].clock() - start
    assert not stream.rejoin_at_rest(start + index, index, ahead=100, most=600)
    assert stream.sent == 600 and sim_rig.clients[0].queue_status()[0] == 0, "nothing sent"
