"""Link faults injected on the sim:// link and on a real pseudo-terminal.

The invariant in every case: the host either recovers with every setpoint executed once, in
order, or raises a typed error; what the device executed is always an exact prefix of what
was meant (a mangled batch is caught before the device reaches it, and the queue cleared).
"""

from __future__ import annotations

import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
import serial

from usbmotion.device import Device
from usbmotion.errors import (
    DeviceTimeoutError,
    LinkCorruptedError,
    LinkLostError,
    UsbMotionError,
)
from usbmotion.host.device import DeviceClient
from usbmotion.host.stream import SetpointStream, run_streams, wait_until_drained
from usbmotion.protocol import parse_reply
from usbmotion.sim import SimLink, SimWorld, drop_world, set_world


class RecordingDevice:
    """A device that records its desired value at every tick: the device-side truth."""

    def __init__(self) -> None:
        self.inner = Device()
        self.executed: list[int] = []

    def __getattr__(self, name: str) -> object:
        return getattr(self.inner, name)

    @property
    def name(self) -> str:
        return self.inner.name

    @property
    def tick_us(self) -> int:
        return self.inner.tick_us

    def feed(self, data: bytes) -> None:
        self.inner.feed(data)

    def take_output(self) -> bytes:
        return self.inner.take_output()

    def take_timed_output(self) -> list[tuple[int, bytes]]:
        return self.inner.take_timed_output()

    def ticks_until_event(self, *, diagnostics: bool = True) -> int | None:
        return self.inner.ticks_until_event(diagnostics=diagnostics)

    def run(self, ticks: int) -> None:
        for _ in range(ticks):
            self.inner.run(1)
            desired = self.inner.state.desired
            if not self.executed or self.executed[-1] != desired:
                self.executed.append(desired)


WANTED = list(range(1, 3001))


@pytest.fixture
def rig() -> Iterator[tuple[DeviceClient, RecordingDevice, SimLink]]:
    world = SimWorld()
    device = RecordingDevice()
    world.add(device, key="X")  # type: ignore[arg-type]
    set_world("link-faults", world)
    client = DeviceClient.open("sim://X?world=link-faults", name="X")
    client.set_servo_enable(True)
    link = client.transport.port.link
    yield client, device, link
    client.close()
    drop_world("link-faults")


def _stream(client: DeviceClient, device: RecordingDevice) -> UsbMotionError | None:
    stream = SetpointStream(client, WANTED, period_s=0.001, verify=True, max_batch=200,
                            low_water=200, high_water=600)
    try:
        run_streams([stream])
        wait_until_drained([client], period_s=0.001)
    except UsbMotionError as error:
        return error
    return None


def _executed(device: RecordingDevice) -> list[int]:
    return [v for v in device.executed if v != 0]


def _assert_prefix(device: RecordingDevice, error: UsbMotionError | None,
                   client: DeviceClient, link: SimLink) -> None:
    if error is not None:
        link.faults.drop_every = link.faults.corrupt_every = 0
        link.faults.stalled = False
        client.transport.discard_input()
        client.clear_queue()  # what the job does: stop before a mangled batch is reached
        client.sync()
        link.world.advance(200_000)
    executed = _executed(device)
    assert executed == WANTED[: len(executed)], "the device executed an exact prefix"
    if error is None:
        assert executed == WANTED, "recovered: every setpoint once, in order"


@pytest.mark.parametrize("every", [89, 397, 1499, 4001])
def test_dropped_bytes_host_to_device(rig, every: int) -> None:  # type: ignore[no-untyped-def]
    client, device, link = rig
    link.faults.drop_every = every
    error = _stream(client, device)
    assert error is None or isinstance(error, (LinkCorruptedError, DeviceTimeoutError))
    _assert_prefix(device, error, client, link)


@pytest.mark.parametrize("every", [97, 499, 2003, 7919])
def test_corrupted_bytes_device_to_host(rig, every: int) -> None:  # type: ignore[no-untyped-def]
    client, device, link = rig
    link.faults.corrupt_every = every
    error = _stream(client, device)
    assert error is None or isinstance(error, (LinkCorruptedError, DeviceTimeoutError))
    _assert_prefix(device, error, client, link)


def test_garbled_answers_are_asked_again(rig) -> None:  # type: ignore[no-untyped-def]
    client, device, link = rig
    link.faults.corrupt_every = 97  # without echoes only the short answers come back to hit
    stream = SetpointStream(client, WANTED, period_s=0.001, max_batch=100,
                            low_water=200, high_water=400)
    try:
        run_streams([stream])
        wait_until_drained([client], period_s=0.001)
    except (LinkCorruptedError, DeviceTimeoutError) as error:
        assert stream.garbled_lines > 0, "the garbled lines were seen, not mistaken"
        _assert_prefix(device, error, client, link)
        return
    assert stream.garbled_lines > 0, "garbled answers were seen and re-asked"
    assert _executed(device) == WANTED


def test_a_stalled_link_times_out_with_a_typed_error(rig) -> None:  # type: ignore[no-untyped-def]
    client, device, link = rig
    stream = SetpointStream(client, WANTED, period_s=0.001, verify=True)
    stream.service()
    link.faults.stalled = True
    with pytest.raises(DeviceTimeoutError) as caught:
        client.status()
    assert caught.value.device == "X" and caught.value.call == 20
    with pytest.raises(DeviceTimeoutError, match="stalled or gone; 600 setpoints were confirmed"):
        for _ in range(10):
            stream.service()
            link.world.advance(500_000)
    _assert_prefix(device, caught.value, client, link)


def test_an_answer_that_comes_late_is_not_taken_for_the_next_one(rig) -> None:  # type: ignore[no-untyped-def]
    client, _device, link = rig
    link.faults.stalled = True
    with pytest.raises(DeviceTimeoutError):
        client.status()
    link.faults.stalled = False  # the held STATUS line now arrives, late
    assert client.queue_status() == (0, 1000), "the answer to this query, not the late one"
    assert client.servo_enabled()
    client.set_watchdog_ms(0)
    assert client.stray_lines == 1, "the late STATUS line was skipped"


def test_a_late_answer_is_realigned_without_losing_an_alarm(rig) -> None:  # type: ignore[no-untyped-def]
    client, _device, link = rig
    client.set_following_error_limit(1)
    link.faults.stalled = True
    with pytest.raises(DeviceTimeoutError):
        client.status()
    client.send(0, 500)  # a jump the servo cannot follow: following error, ALARM 2
    link.world.advance(50_000)
    link.faults.stalled = False
    code, _tick = client.fault()
    assert code == 2
    assert [alarm.fault for alarm in client.alarms] == [2], "the alarm read on the way is kept"


def test_a_disconnect_mid_stream_says_how_many_were_confirmed(rig) -> None:  # type: ignore[no-untyped-def]
    client, _device, link = rig
    stream = SetpointStream(client, WANTED, period_s=0.001, verify=True)
    stream.service()
    link.world.advance(500_000)
    stream.service()
    confirmed = stream.sent
    link.faults.disconnected = True
    with pytest.raises(LinkLostError) as caught:
        for _ in range(5):
            stream.service()
    assert caught.value.confirmed == confirmed
    assert f"after {confirmed} of 3000 setpoints" in str(caught.value)


def test_a_line_split_at_every_position_means_the_same() -> None:
    lines = [b"1 4 10 -20 30 40\n", b"3 1\n", b"9 12 -3\n", b"8 3 1\n", b"3 0\n", b"20 -1\n",
             b"18 3 65 66 67\n", b"2 -1\n"]
    whole = Device()
    for line in lines:
        whole.feed(line)
        whole.run(3)
    expected = whole.take_output()
    for line_index, line in enumerate(lines):
        for cut in range(1, len(line)):
            device = Device()
            for i, other in enumerate(lines):
                if i == line_index:
                    device.feed(other[:cut])
                    device.run(1)
                    device.feed(other[cut:])
                    device.run(2)
                else:
                    device.feed(other)
                    device.run(3)
            out = device.take_output()
            assert out.replace(b"STATUS", b"").split(b"\n")[0] == expected.replace(
                b"STATUS", b"").split(b"\n")[0]
            assert [parse_reply(x).key for x in out.splitlines()] == [
                parse_reply(x).key for x in expected.splitlines()]


@pytest.mark.parametrize("corrupt_every", [0, 97])
def test_the_sim_ports_one_call_read_reads_what_pyserial_reads(corrupt_every: int) -> None:
    """A ``sim://`` port hands over what has arrived in one call; the same lines come as
    through pyserial's ``in_waiting``, ``timeout`` and ``read``, damaged bytes and all."""
    heard: dict[bool, list[bytes]] = {}
    for one_call in (True, False):
        world = SimWorld()
        world.add(Device(), key="X")  # type: ignore[arg-type]
        set_world("reads", world)
        try:
            client = DeviceClient.open("sim://X?world=reads", name="X")
            transport = client.transport
            assert (transport._read_arrived is not None) is True
            if not one_call:
                transport._read_arrived = None
            transport.port.link.faults.corrupt_every = corrupt_every
            client.set_diagnostics_interval(7)
            client.set_servo_enable(True)
            lines: list[bytes] = []
            for step in range(40):
                transport.write(b"2\n3 1\n" if step % 3 else b"2\n")
                lines.append(transport.read_line(0.01))
                world.advance(20_300)
                lines += transport.poll_lines()
            heard[one_call] = lines
            client.close()
        finally:
            drop_world("reads")
    assert len(heard[True]) > 100
    assert heard[True] == heard[False]


@pytest.fixture
def served_pty(tmp_path: Path) -> Iterator[tuple[subprocess.Popen[str], str]]:
    process = subprocess.Popen(
        [sys.executable, "-m", "usbmotion", "sim", "--pty", "1", "--flash-dir", str(tmp_path)],
        stdout=subprocess.PIPE, text=True,
    )
    assert process.stdout is not None
    path = process.stdout.readline().rsplit(" ", 1)[1].strip()
    yield process, path
    if process.poll() is None:
        process.terminate()
        process.wait(timeout=10)


@pytest.mark.realtime
def test_byte_by_byte_through_a_real_pty(served_pty) -> None:  # type: ignore[no-untyped-def]
    _, path = served_pty
    with serial.Serial(path, timeout=2) as port:
        for byte in b"8 3 1\n3 1\n3 -1\n":
            port.write(bytes([byte]))
            time.sleep(0.002)
        assert port.readline() == b"SERVO ENABLE MODIFIED TO 1\n"
        assert port.readline() == b"SERVO_ENABLE 1\n"


@pytest.mark.realtime
def test_the_device_process_dies_mid_stream(served_pty) -> None:  # type: ignore[no-untyped-def]
    process, path = served_pty
    client = DeviceClient.open(path, name="X")
    client.set_servo_enable(True)
    stream = SetpointStream(client, list(range(100_000)), period_s=client.motion_period_s(),
                            verify=True)
    stream.service()
    confirmed = stream.sent
    assert confirmed > 0
    process.kill()
    process.wait(timeout=10)
    with pytest.raises((LinkLostError, DeviceTimeoutError)) as caught:
        for _ in range(50):
            stream.service()
            time.sleep(0.05)
    assert f"{confirmed}" in str(caught.value)
    client.close()
