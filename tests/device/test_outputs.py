"""Outputs on a device tick (calls 42 and 43): a digital or PWM output set on the clock tick
the host names, queued, so a coolant or laser output changes exactly where the program says.

A change for tick T applies at the start of the tick that begins with the clock at T (the
tick ``31 T`` would start the motion on): read after each tick, its value shows with the
clock at T + 1 and never before, and ``last_change_tick`` says T. Every test runs on the
reference core1 and on the compiled kernel, which must agree to the tick, in long blocks
as in single ticks.
"""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from usbmotion.device import Device
from usbmotion.errors import ErrReplyError, OutOfRangeError, QueueFullError
from usbmotion.host.device import DeviceClient
from usbmotion.protocol import Outputs
from usbmotion.sim import SimWorld, drop_world, set_world

from .helpers import send


def _paths() -> list[bool]:
    try:
        import numba  # noqa: F401, PLC0415 - optional dependency
    except ImportError:
        return [False]
    return [False, True]


PATHS = pytest.mark.parametrize("fast", _paths(), ids=lambda fast: "kernel" if fast else "core1")


def _outputs(device: Device) -> tuple[int, ...]:
    (line,) = send(device, "43 0")
    key, *values = line.split()
    assert key == "OUTPUTS"
    return tuple(map(int, values))


def _first_clock_showing(device: Device, output: int, value: int, ticks: int) -> int:
    """Run tick by tick until ``output`` reads ``value``; the clock after that tick."""
    for _ in range(ticks):
        device.run(1)
        if _outputs(device)[output] == value:
            return device.clock
    raise AssertionError(f"output {output} did not take {value} within {ticks} ticks")


@PATHS
def test_a_change_applies_on_its_tick_read_tick_by_tick(fast: bool) -> None:
    device = Device(fast=fast)
    assert _outputs(device) == (0, 0, 0, 0, 0, -1), "all off at power-up, nothing applied"
    assert send(device, "42 0 1000 40", "42 2 375 40", "42 3 1000 57", "42 0 0 90") == []
    assert _outputs(device) == (0, 0, 0, 0, 4, -1)
    assert _first_clock_showing(device, 0, 1000, 200) == 41
    assert _outputs(device) == (1000, 0, 375, 0, 2, 40), "both changes of tick 40 together"
    assert _first_clock_showing(device, 3, 1000, 200) == 58
    assert _outputs(device) == (1000, 0, 375, 1000, 1, 57)
    assert _first_clock_showing(device, 0, 0, 200) == 91
    assert _outputs(device) == (0, 0, 375, 1000, 0, 90)


@PATHS
def test_a_change_inside_a_long_block_applies_on_its_exact_tick(fast: bool) -> None:
    """A device streaming positions runs in blocks of many ticks; one idle runs far ahead
    in one step: either way the change applies on its own tick."""
    streaming = Device(fast=fast)
    send(streaming, "3 1", "1 1000 " + " ".join(str(i) for i in range(1000)))
    send(streaming, "42 2 600 317", "42 1 1000 318", "42 2 0 777")
    streaming.run(900)
    assert _outputs(streaming) == (0, 1000, 0, 0, 0, 777)
    idle = Device(fast=fast)
    send(idle, "42 3 20 4321")
    idle.run(4321)
    assert _outputs(idle) == (0, 0, 0, 0, 1, -1), "not yet: the tick begins at clock 4321"
    idle.run(50_000)
    assert _outputs(idle) == (0, 0, 0, 20, 0, 4321)
    send(idle, "42 3 40 70000")
    idle.run(10_000)  # from clock 54321: one tick run, the rest skipped up to the change
    assert _outputs(idle) == (0, 0, 0, 20, 1, 4321)
    idle.run(50_000)
    assert _outputs(idle) == (0, 0, 0, 40, 0, 70000)
    send(idle, "42 3 0 0")
    idle.run(50_000)
    assert _outputs(idle) == (0, 0, 0, 0, 0, 114321), "a tick long past: the next tick"


def test_the_kernel_equals_core1_with_outputs_pending() -> None:
    pytest.importorskip("numba")
    states = []
    for fast in (False, True):
        device = Device(fast=fast)
        send(device, "21 97", "3 1", "1 500 " + " ".join(str(3 * i) for i in range(500)))
        send(device, *(f"42 {i % 4} {1000 * (i % 2)} {37 * i}" for i in range(16)))
        lines = []
        for ticks in (1, 13, 200, 5, 400):
            device.run(ticks)
            lines += send(device, "43 0", "20 -1")
        states.append((lines, device.take_output(), device.state))
    assert states[0] == states[1]


@PATHS
def test_a_tick_already_past_applies_on_the_next_tick(fast: bool) -> None:
    device = Device(fast=fast)
    device.run(100)
    send(device, "42 1 1000 20", "42 2 500 100")
    assert _outputs(device) == (0, 0, 0, 0, 2, -1), "nothing applies between ticks"
    device.run(1)
    assert _outputs(device) == (0, 1000, 500, 0, 0, 100)


def test_the_queue_holds_16_and_refuses_the_17th_with_e42() -> None:
    device = Device()
    assert send(device, *(f"42 3 {i} {i}" for i in range(16))) == []
    assert send(device, "42 3 999 16") == ["E42"]
    assert _outputs(device) == (0, 0, 0, 0, 16, -1), "nothing lost, nothing added"
    device.run(3)
    assert send(device, "42 3 999 16") == [], "room again once changes applied"
    assert _outputs(device) == (0, 0, 0, 2, 14, 2)


def test_bad_changes_are_refused_and_change_nothing() -> None:
    device = Device()
    send(device, "42 2 100 50")
    assert send(device, "42 0 500 60") == [
        "ERR 42 output 0 is digital: value 500 must be 0 or 1000"]
    assert send(device, "42 1 1 60") == [
        "ERR 42 output 1 is digital: value 1 must be 0 or 1000"]
    assert send(device, "42 3 100 49") == [
        "ERR 42 tick 49 is before the last pending change's tick 50"]
    assert send(device, "42 4 0 60") == ["ERR 42 output 4 is out of range 0..3"]
    assert send(device, "42 2 1001 60") == ["ERR 42 value 1001 is out of range 0..1000"]
    assert send(device, "42 2 0 -1") == ["ERR 42 tick -1 is out of range 0..2147483647"]
    assert send(device, "43 2") == ["ERR 43 clear 2 is out of range 0..1"]
    assert _outputs(device) == (0, 0, 0, 0, 1, -1)
    assert send(device, "42 3 100 50", "42 0 1000 50") == [], "the same tick again is in order"


@PATHS
def test_a_fault_turns_every_output_off_on_its_tick_and_drops_the_pending(fast: bool) -> None:
    device = Device(fast=fast)
    send(device, "42 0 1000 0", "42 1 1000 0", "42 2 800 0", "42 3 300 0", "42 2 100 5000")
    device.run(10)
    assert _outputs(device) == (1000, 1000, 800, 300, 1, 0)
    send(device, "29 5", "3 1", "0 3000")  # a following error beyond 5 counts at once
    device.run(40)
    (alarm,) = send(device)
    assert alarm.startswith("ALARM 2 ")
    lines = send(device, "30 -1", "43 0")
    assert lines[1] == "OUTPUTS 0 0 0 0 0 0", "all off, nothing pending, no change applied"
    assert send(device, "42 0 1000 0") == [
        "ERR 42 fault 2 (following error) is latched; clear it with call 30 before setting"
        " an output"]
    send(device, "30 0")
    assert send(device, "42 0 1000 0") == []
    device.run(1)
    assert _outputs(device)[0] == 1000


@PATHS
def test_the_outputs_go_off_on_the_fault_tick_itself(fast: bool) -> None:
    device = Device(fast=fast)
    send(device, "42 2 1000 0", "28 5", "3 1")  # the watchdog: 5 ms of silence
    for _ in range(20):
        device.run(1)
        state = device.state
        values = device.checkpoint().state  # read without a call: a call feeds the watchdog
        if state.fault:
            assert state.fault_tick == state.clock == 5
            assert values[_output_index(2)] == 0
            return
        assert values[_output_index(2)] == 1000
    raise AssertionError("no watchdog fault")


def _output_index(output: int) -> int:
    from usbmotion.device import core1  # noqa: PLC0415 - the state layout, for one test

    return core1.S_OUTPUTS + output


def test_an_internal_error_turns_the_outputs_off(monkeypatch: pytest.MonkeyPatch) -> None:
    device = Device(fast=False)
    send(device, "42 1 1000 0", "42 3 5 900")
    device.run(1)

    def broken(call: object) -> None:
        raise RuntimeError("bad thing")

    monkeypatch.setitem(device._handlers, 24, broken)
    send(device, "24 -1")
    assert _outputs(device) == (0, 0, 0, 0, 0, 0)


def test_clear_drops_the_pending_and_keeps_the_outputs() -> None:
    device = Device()
    send(device, "42 0 1000 2", "42 0 0 30", "42 2 250 31")
    device.run(10)
    assert send(device, "43 1") == ["OUTPUTS 1000 0 0 0 0 2"]
    device.run(100)
    assert _outputs(device) == (1000, 0, 0, 0, 0, 2), "the dropped changes never apply"


def test_zeroing_the_clock_drops_the_pending_and_shifts_change_nothing() -> None:
    device = Device()
    send(device, "42 2 700 5", "42 3 10 60")
    device.run(10)
    send(device, "23 500", "37 -20")
    assert _outputs(device) == (0, 0, 700, 0, 1, 5), "a change of coordinates: no change"
    send(device, "22 0")
    assert _outputs(device) == (0, 0, 700, 0, 0, 5), "pending dropped, outputs as they are"
    device.run(100)
    assert _outputs(device) == (0, 0, 700, 0, 0, 5)


def test_a_power_cycle_turns_everything_off() -> None:
    device = Device()
    send(device, "42 0 1000 0", "42 1 1000 500")
    device.run(3)
    device.restart()
    assert _outputs(device) == (0, 0, 0, 0, 0, -1)


# --- the host's side ----------------------------------------------------------------------


@pytest.fixture
def client() -> Iterator[DeviceClient]:
    world = SimWorld()
    world.add(Device(), key="X")  # type: ignore[arg-type]
    set_world("outputs-client", world)
    client = DeviceClient.open("sim://X?world=outputs-client", name="X")
    yield client
    client.close()
    drop_world("outputs-client")


def test_the_client_queues_changes_and_reads_them_back(client: DeviceClient) -> None:
    tick = client.clock() + 200
    assert client.set_output_at(2, 450, tick) == Outputs((0, 0, 0, 0), 1, -1)
    after = client.set_output_at(0, 1000, tick + 1)
    assert (after.pending, after.free) == (2, 14)
    with pytest.raises(ErrReplyError, match="digital"):
        client.set_output_at(1, 300, tick + 2)
    with pytest.raises(ErrReplyError, match="before the last pending"):
        client.set_output_at(3, 300, tick)
    with pytest.raises(OutOfRangeError):
        client.set_output_at(4, 0, tick)
    for i in range(14):
        client.set_output_at(3, i, tick + 2)
    with pytest.raises(QueueFullError):
        client.set_output_at(3, 0, tick + 2)
    assert client.outputs(clear=True) == Outputs((0, 0, 0, 0), 0, -1)
    client.set_output_at(2, 450, tick)
    client.link_clock.sleep(0.5)
    now = client.outputs()
    assert (now.values, now.pending, now.last_change_tick) == ((0, 0, 450, 0), 0, tick)
