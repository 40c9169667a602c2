"""The compiled kernel against the reference core1, and the switch between them.

Bit-for-bit: random gains, motor parameters, control modes, setpoint streams, curve
positions and block lengths give the kernel exactly the reference's state (positions,
velocities, integrator, fault, queue, every entry) after every block, and two whole
devices, one on each path, print the same bytes and report the same state after every
run. Through the whole chain in virtual time (host streams into ``sim://`` devices) the
kernel runs long blocks and ends where the reference ends, and the main job (home, stream,
report) reports the same figures on both paths. Without numba the reference path runs
and a one-line notice says so.
"""

from __future__ import annotations

import logging
import sys
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from usbmotion.device import Device, core0, core1, kernel
from usbmotion.device.core1 import IntArray
from usbmotion.device.kernel_code import MachineKernel
from usbmotion.errors import DeviceParameterError
from usbmotion.host.device import DeviceClient
from usbmotion.host.stream import SetpointStream, run_streams, wait_until_drained
from usbmotion.protocol import QUEUE_CAPACITY
from usbmotion.sim import SimWorld, drop_world, set_world
from usbmotion.sim.machine import connect_session

from .helpers import send, take

needs_numba = pytest.mark.skipif(not kernel.numba_available(), reason="numba is not installed")


@pytest.fixture(scope="module")
def compiled() -> kernel.BlockFunction:
    """The kernel, compiled (or loaded from numba's cache) once for the session."""
    kernel.warm_up()
    return kernel.compile_kernel()


@pytest.fixture(scope="module")
def machine_code(compiled: kernel.BlockFunction) -> kernel.BlockFunction:
    """The kernel the devices run: its machine code loaded from its file (made first)."""
    function = kernel.load()
    assert isinstance(function, MachineKernel)
    return function


@pytest.fixture
def no_environment(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv(kernel.ENVIRONMENT_VARIABLE, raising=False)


# --- strategies -------------------------------------------------------------------------

_realistic_sci = st.tuples(st.integers(1, 9999), st.integers(-4, 1))
_any_sci = st.tuples(st.integers(1, 9999), st.integers(-12, 6))
_gain = st.one_of(
    st.tuples(st.integers(0, 999), st.integers(-4, 0)),
    st.tuples(st.integers(0, 999), st.integers(-12, 6)),
)


def _sci_line(call: int, pair: tuple[int, int]) -> str:
    return f"{call} {pair[0]} {pair[1]}"


@st.composite
def configurations(draw: st.DrawFn) -> list[str]:
    """Command lines that configure a device: gains, motor, period, mode, limits, faults."""
    interval_dms = draw(st.sampled_from([1, 2, 5, 10, 20]), label="interval_dms")
    steps = draw(st.integers(1, 6), label="motor steps per tick")
    sim_dms = max(1, interval_dms // steps)
    mode = draw(st.sampled_from([1, 2, 3]), label="mode")
    drive = draw(st.sampled_from([0, 0, 1, 2]), label="drive")
    lines = [f"44 {drive}", f"5 {interval_dms}", f"12 {sim_dms}", f"7 {mode}"]
    if drive != 0:
        if draw(st.booleans(), label="set 45"):
            full = draw(st.sampled_from([200, 400, 1]), label="full steps")
            lines.append(f"45 {full} {draw(st.sampled_from([1, 8, 16, 256]), label='micro')}")
        if draw(st.booleans(), label="set 46"):
            pulse = draw(st.sampled_from([100, 1000, 2000, 20_000]), label="pulse ns")
            lines.append(f"46 {pulse} {draw(st.sampled_from([0, 20, 1000]), label='setup')}")
        if draw(st.booleans(), label="set 47"):
            holding = draw(st.integers(1, 5000), label="holding")
            detent = draw(st.integers(0, holding), label="detent")
            lines.append(f"47 {holding} {detent} {draw(st.integers(1, 5000), label='corner')}")
    for call in (9, 10, 11):
        lines.append(_sci_line(call, draw(_gain, label=f"gain {call}")))
    motor_sci = st.one_of(_realistic_sci, _realistic_sci, _any_sci)
    for call in (13, 14, 15, 17, 32):
        if draw(st.booleans(), label=f"set {call}"):
            lines.append(_sci_line(call, draw(motor_sci, label=f"motor {call}")))
    if draw(st.booleans(), label="set 33"):
        load = draw(st.tuples(st.integers(0, 9999), st.integers(-4, 2)), label="load")
        lines.append(_sci_line(33, load))
    if draw(st.booleans(), label="set 16"):
        lines.append(f"16 {draw(st.integers(1, 1_000_000), label='counts per rev')}")
    if draw(st.booleans(), label="travel"):
        lower = draw(st.integers(-50_000, -1), label="lower")
        upper = draw(st.integers(1, 50_000), label="upper")
        lines.append(f"34 {lower} {upper}")
    lines.append(f"6 {draw(st.integers(1, 5), label='scalar')}")
    lines.append(f"21 {draw(st.sampled_from([0, 0, 1, 7, 50]), label='diagnostics')}")
    lines.append(f"28 {draw(st.sampled_from([0, 0, 0, 3, 40]), label='watchdog ms')}")
    lines.append(f"29 {draw(st.sampled_from([0, 0, 0, 5, 500]), label='following limit')}")
    if draw(st.booleans(), label="armed start"):
        lines.append(f"31 {draw(st.integers(0, 200), label='start tick')}")
    lines.append("3 1")
    return lines


_setpoint = st.one_of(
    st.integers(-3000, 3000),
    st.integers(-(2**31), 2**31 - 1),
)


@st.composite
def blocks(draw: st.DrawFn) -> list[tuple[list[int], list[int], int, bool]]:
    """(values to queue, curve positions, ticks, recover from a fault first) per block."""
    count = draw(st.integers(1, 6), label="blocks")
    out = []
    for _ in range(count):
        values = draw(st.lists(_setpoint, max_size=40), label="values")
        ticks = draw(st.integers(0, 250), label="ticks")
        curve = draw(st.lists(st.integers(-5000, 5000), max_size=ticks), label="curve")
        out.append((values, curve, ticks, draw(st.booleans(), label="recover")))
    return out


def _arrays(device: Device) -> tuple[IntArray, IntArray, IntArray]:
    """Copies of a device's core1 state, params and queue (the block's whole input)."""
    return device._state.copy(), device._params.copy(), device._queue.copy()


def _push(state: IntArray, queue: IntArray, values: list[int]) -> None:
    head = int(state[core1.S_QUEUE_HEAD])
    count = int(state[core1.S_QUEUE_COUNT])
    for value in values[: QUEUE_CAPACITY - count]:
        queue[(head + count) % QUEUE_CAPACITY] = value
        count += 1
    state[core1.S_QUEUE_COUNT] = count


def _between_blocks(state: IntArray, *, recover: bool) -> None:
    """What core0 does between blocks: clear the events, take a command; maybe clear a
    fault and enable again (calls 30 and 3)."""
    state[core1.S_EVENTS] = 0
    state[core1.S_SINCE_COMMAND_US] = 0
    if recover and state[core1.S_ENABLE] == 0:
        state[core1.S_FAULT] = 0
        state[core1.S_ENABLE] = 1
        state[core1.S_INTEGRAL] = 0
        state[core1.S_FRESH] = 1
        state[core1.S_MOTION_LEFT] = 0
        state[core1.S_DESIRED] = state[core1.S_ACTUAL]
        state[core1.S_DESIRED_VEL] = 0


# --- bit for bit ------------------------------------------------------------------------


@needs_numba
@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(configuration=configurations(), stream=blocks())
def test_the_kernel_equals_core1_after_every_block(
    compiled: kernel.BlockFunction,
    machine_code: kernel.BlockFunction,
    configuration: list[str],
    stream: list[tuple[list[int], list[int], int, bool]],
) -> None:
    """numba's dispatcher and the machine code the devices run, both against core1."""
    device = Device(fast=False)
    send(device, *configuration)
    state, params, queue = _arrays(device)
    fast = [(function, state.copy(), queue.copy()) for function in (compiled, machine_code)]
    for values, positions, ticks, recover in stream:
        for array in (state, *(each[1] for each in fast)):
            _between_blocks(array, recover=recover)
        for array, ring in ((state, queue), *((each[1], each[2]) for each in fast)):
            _push(array, ring, values)
        curve = np.asarray(positions, dtype=np.int64)
        left = ticks
        while True:
            done = core1.servo_block(state, params, queue, curve, left)
            for function, fast_state, fast_queue in fast:
                assert function(fast_state, params, fast_queue, curve, left) == done
                assert fast_state.tolist() == state.tolist()
                assert fast_queue.tolist() == queue.tolist()
            left -= done
            if left <= 0:
                break
            curve = curve[done:]
            for array in (state, *(each[1] for each in fast)):
                _between_blocks(array, recover=False)


@st.composite
def scripts(draw: st.DrawFn) -> list[str | int]:
    """Command lines (str) and runs (int ticks), interleaved."""
    steps: list[str | int] = []
    for _ in range(draw(st.integers(1, 10), label="steps")):
        kind = draw(st.sampled_from(["run", "run", "run", "stream", "command", "keyframe"]))
        if kind == "run":
            steps.append(draw(st.integers(0, 400), label="run ticks"))
        elif kind == "stream":
            values = draw(st.lists(st.integers(-4000, 4000), min_size=1, max_size=60))
            steps.append(f"1 {len(values)} {' '.join(map(str, values))}")
        elif kind == "keyframe":
            duration = draw(st.integers(1, 80), label="duration ms")
            position = draw(st.integers(-3000, 3000), label="position")
            tangents = draw(st.tuples(st.integers(-2000, 2000), st.integers(-2000, 2000)))
            steps.append(f"25 {duration} {position} {tangents[0]} {tangents[1]}")
        else:
            steps.append(draw(st.sampled_from([
                "3 0", "3 1", "4 0", "30 0", "23 150", "7 1", "7 2", "7 3", "21 0", "21 13",
                "22 0", "0 -700", "26 0", "29 0", "28 0",
            ]), label="command"))
    return steps


@needs_numba
@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(configuration=configurations(), script=scripts())
def test_a_kernel_device_equals_a_reference_device_after_every_run(
    compiled: kernel.BlockFunction, configuration: list[str], script: list[str | int]
) -> None:
    reference, fast = Device(fast=False), Device(fast=True)
    assert (reference.fast, fast.fast) == (False, True)
    for device in (reference, fast):
        send(device, *configuration)
    for step in script:
        for device in (reference, fast):
            if isinstance(step, int):
                device.run(step)
            else:
                device.feed(f"{step}\n".encode("ascii"))
        assert take(fast) == take(reference)
        assert fast.state == reference.state
    assert fast.settings == reference.settings
    assert fast._state.tolist() == reference._state.tolist()


def test_the_stepper_near_its_speed_bound_in_one_second_steps() -> None:
    """A 1 s tick in one 1 s integration step, the fastest pulses and a tiny rotor: the
    shaft reaches the model's speed bound (10^13 micro-microsteps/s), whose travel over the
    step (10^19 micro-microsteps x 10^-6) does not fit an int64; the kernel computes it as
    the reference does (stepper.travel)."""
    script = ["44 1", "5 10000", "12 10000", "17 1 -12", "33 0 0", "32 0 0", "46 100 0",
              "3 1", "0 2000000000"]
    devices = [Device(fast=False)] + ([Device(fast=True)] if kernel.numba_available() else [])
    for device in devices:
        send(device, *script)
        device.run(3)
    reference = devices[0].state
    assert reference.shaft_micro_counts == 2 * 10**13
    assert all(device.state == reference for device in devices)


def test_the_stepper_under_the_largest_speed_change() -> None:
    """Call 17's smallest inertia and the full holding torque: a speed change of about
    2e19 micro-microsteps/s in one step, beyond an int64; the kernel caps it
    (stepper.speed_change) and ends where the reference's exact change does."""
    script = [*(f"{call} 1 -12" for call in (9, 10, 11, 13, 14, 15, 17, 32, 33)), "16 1",
              "44 2", "46 100 0", "45 1000 256", "21 1", "3 1", "1 3 -2147483648 2147483647 0"]
    devices = [Device(fast=False)] + ([Device(fast=True)] if kernel.numba_available() else [])
    outputs = []
    for device in devices:
        send(device, *script)
        device.run(40)
        outputs.append(take(device))
    assert all(output == outputs[0] for output in outputs)
    assert all(device.state == devices[0].state for device in devices)


# --- the whole chain in virtual time ------------------------------------------------------


class _Counting:
    """Counts the kernel's blocks and ticks (wraps the compiled function)."""

    def __init__(self, function: kernel.BlockFunction) -> None:
        self.function = function
        self.blocks = 0
        self.ticks = 0

    def __call__(
        self, state: IntArray, params: IntArray, queue: IntArray, curve: IntArray, n: int
    ) -> int:
        done = self.function(state, params, queue, curve, n)
        self.blocks += 1
        self.ticks += done
        return done


def _stream_in_virtual_time(*, fast: bool, world_name: str) -> tuple[list[Device], int]:
    """Stream 30,000 setpoints into each of 3 sim:// devices at 10 kHz; returns devices."""
    world = SimWorld()
    devices = [Device(fast=fast) for _ in range(3)]
    for name, device in zip("XYZ", devices, strict=True):
        world.add(device, key=name)
    set_world(world_name, world)
    clients = [DeviceClient.open(f"sim://{name}?world={world_name}", name=name) for name in "XYZ"]
    try:
        for client in clients:
            client.set_servo_interval_dms(1)
            client.set_motion_scalar(10)
            client.set_servo_enable(True)
        period_s = clients[0].motion_period_s()
        ramp = np.arange(3000, dtype=np.int64)
        streams = [SetpointStream(client, (ramp * (i + 1)) // 3, period_s=period_s)
                   for i, client in enumerate(clients)]
        run_streams(streams)
        wait_until_drained(clients, period_s=period_s)
        queries = sum(stream.status_queries for stream in streams)
    finally:
        for client in clients:
            client.close()
        drop_world(world_name)
    return devices, queries


@needs_numba
def test_streaming_into_sim_devices_runs_long_kernel_blocks(
    compiled: kernel.BlockFunction, monkeypatch: pytest.MonkeyPatch
) -> None:
    counting = _Counting(compiled)
    monkeypatch.setattr("usbmotion.device.core0.block_function", lambda: counting)
    fast_devices, queries = _stream_in_virtual_time(fast=True, world_name="kernel-chain")
    monkeypatch.undo()
    # 3 axes x 3000 setpoints x 10 ticks: no per-tick (or per-setpoint) round trips
    assert counting.ticks >= 3 * 3000 * 10
    assert counting.ticks / counting.blocks >= 100, (counting.ticks, counting.blocks)
    assert queries <= 3 * 3000 / 100
    reference_devices, _ = _stream_in_virtual_time(fast=False, world_name="reference-chain")
    for fast_device, reference_device in zip(fast_devices, reference_devices, strict=True):
        assert fast_device.state == reference_device.state
        assert fast_device.state.fault == 0
        assert fast_device.state.desired == fast_device.state.actual or abs(
            fast_device.state.desired - fast_device.state.actual
        ) <= 3


# --- the switch -------------------------------------------------------------------------


@needs_numba
def test_devices_take_the_kernel_when_numba_is_there(no_environment: None) -> None:
    assert Device().fast is True
    assert Device(fast=False).fast is False


@needs_numba
@pytest.mark.parametrize(("value", "fast"), [("0", False), ("1", True), ("", True), (" 0 ", False)])
def test_the_environment_variable_chooses_the_path(
    monkeypatch: pytest.MonkeyPatch, value: str, fast: bool
) -> None:
    monkeypatch.setenv(kernel.ENVIRONMENT_VARIABLE, value)
    assert Device().fast is fast
    assert Device(fast=not fast).fast is (not fast), "an explicit argument wins"


def test_a_bad_environment_value_is_refused(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(kernel.ENVIRONMENT_VARIABLE, "yes")
    with pytest.raises(DeviceParameterError, match=r"USBMOTION_KERNEL='yes' is not allowed"):
        Device()


def test_a_bad_fast_argument_is_refused() -> None:
    with pytest.raises(DeviceParameterError, match=r"fast 1 is not True, False or None"):
        Device(fast=1)  # type: ignore[arg-type]


@pytest.fixture
def without_numba(monkeypatch: pytest.MonkeyPatch, no_environment: None) -> Iterator[None]:
    """numba cannot be imported; the notice has not been printed yet in this process."""
    monkeypatch.setitem(sys.modules, "numba", None)
    monkeypatch.setattr(kernel, "_noticed", False)
    yield


def test_without_numba_the_reference_runs_and_a_notice_says_so_once(
    without_numba: None, caplog: pytest.LogCaptureFixture
) -> None:
    assert kernel.numba_available() is False
    with caplog.at_level(logging.WARNING, logger="usbmotion.device.kernel"):
        device = Device()
        Device()
    assert device.fast is False
    assert [record.getMessage() for record in caplog.records] == [kernel.NOTICE]
    assert "\n" not in kernel.NOTICE
    send(device, "3 1", "0 100")
    device.run(500)
    assert abs(device.state.actual - 100) <= 2
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="usbmotion.device.kernel"):
        assert Device(fast=False).fast is False
    assert caplog.records == []


def test_without_numba_asking_for_the_kernel_is_an_error(
    without_numba: None, monkeypatch: pytest.MonkeyPatch
) -> None:
    with pytest.raises(DeviceParameterError, match=r"fast=True asks for the compiled servo"):
        Device(fast=True)
    monkeypatch.setenv(kernel.ENVIRONMENT_VARIABLE, "1")
    with pytest.raises(DeviceParameterError, match=r"USBMOTION_KERNEL=1 asks for the compiled"):
        Device()
    monkeypatch.setenv(kernel.ENVIRONMENT_VARIABLE, "0")
    assert Device().fast is False


def test_a_broken_numba_is_named_in_the_notice_and_the_error(
    monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture, no_environment: None,
    tmp_path: Path,
) -> None:
    """An installed numba is imported when a device first needs the kernel and its machine
    code has no file yet: one that does not import then leaves the device on the reference
    path, the notice naming why."""
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path))
    monkeypatch.setattr(kernel, "_numba_problem", lambda: ImportError("llvmlite is too old"))
    monkeypatch.setattr(kernel, "_noticed", False)
    monkeypatch.setattr(kernel, "_loaded", None)
    with caplog.at_level(logging.WARNING, logger="usbmotion.device.kernel"):
        device = Device()
        assert device.fast is True, "numba is installed: not imported yet"
        send(device, "3 1", "0 100")
        device.run(500)
        assert device.fast is False
    assert abs(device.state.actual - 100) <= 2
    assert [record.getMessage() for record in caplog.records] == [
        f"{kernel.NOTICE} [llvmlite is too old]"
    ]
    with pytest.raises(DeviceParameterError, match=r"numba cannot be imported \(llvmlite is"):
        Device(fast=True)


@needs_numba
def test_short_blocks_run_the_reference_until_a_long_one_loads_the_kernel(
    compiled: kernel.BlockFunction, monkeypatch: pytest.MonkeyPatch, no_environment: None
) -> None:
    """A device that takes the kernel for numba's presence answers queries and runs short
    blocks on the reference (a command that moves nothing never loads the kernel); its
    first long block loads it; its bytes and state stay the reference's throughout."""
    monkeypatch.setattr(kernel, "_loaded", None)  # as in a fresh process
    blocks: list[int] = []
    monkeypatch.setattr("usbmotion.device.core0.block_function",
                        lambda: lambda *args: blocks.append(args[-1]) or compiled(*args))
    lazy, reference = Device(), Device(fast=False)
    assert lazy.fast
    outputs: list[list[str]] = [[], []]
    ramp = " ".join(str(value) for value in range(0, 4000, 10))
    for device, out in zip((lazy, reference), outputs, strict=True):
        out += send(device, "18 -1", "3 1", f"1 400 {ramp}", "30 -1")
        for _ in range(5):
            device.run(core0.REFERENCE_BLOCK_TICKS)  # the queue runs: servo blocks
        out += take(device)
    assert not kernel.loaded() and blocks == []
    for device, out in zip((lazy, reference), outputs, strict=True):
        device.run(2000)
        out += send(device, "30 -1")
    assert kernel.loaded() and blocks and max(blocks) > core0.REFERENCE_BLOCK_TICKS
    assert outputs[0] == outputs[1] and lazy.state == reference.state
    assert abs(lazy.state.actual - 3990) <= 4


@needs_numba
def test_short_blocks_load_the_kernel_once_they_add_up(
    compiled: kernel.BlockFunction, monkeypatch: pytest.MonkeyPatch, no_environment: None
) -> None:
    monkeypatch.setattr(kernel, "_loaded", None)
    device = Device()
    send(device, "3 1")
    while device.clock < core0.REFERENCE_TICKS:
        send(device, "1 8 1 2 3 4 5 6 7 8")  # the queue runs: servo blocks of 8 ticks
        device.run(8)
    assert not kernel.loaded()
    send(device, "1 8 1 2 3 4 5 6 7 8")
    device.run(8)
    assert kernel.loaded()


@needs_numba
def test_asking_for_the_kernel_loads_it_with_the_device(
    compiled: kernel.BlockFunction, monkeypatch: pytest.MonkeyPatch, no_environment: None
) -> None:
    monkeypatch.setattr(kernel, "_loaded", None)
    Device(fast=True)
    assert kernel.loaded()
    monkeypatch.setattr(kernel, "_loaded", None)
    monkeypatch.setenv(kernel.ENVIRONMENT_VARIABLE, "1")
    Device()
    assert kernel.loaded()


@needs_numba
def test_a_world_in_real_time_loads_the_kernel_when_it_takes_a_device(
    compiled: kernel.BlockFunction, monkeypatch: pytest.MonkeyPatch, no_environment: None
) -> None:
    monkeypatch.setattr(kernel, "_loaded", None)
    SimWorld().add(Device())
    assert not kernel.loaded()
    SimWorld(realtime=True).add(Device())
    assert kernel.loaded()


@needs_numba
def test_an_exception_in_the_kernel_faults_and_keeps_the_clock(
    compiled: kernel.BlockFunction, monkeypatch: pytest.MonkeyPatch
) -> None:
    device = Device(fast=True)
    send(device, "3 1", "0 100")

    def broken(*args: object) -> int:
        raise ZeroDivisionError("oops")

    monkeypatch.setattr("usbmotion.device.core0.block_function", lambda: broken)
    device.run(50)
    assert device.clock == 50
    assert send(device, "30 -1") == [
        "ERR ? internal error in the servo loop (ZeroDivisionError: oops); fault 4 latched",
        "ALARM 4 0",
        "FAULT 4 0",
    ]
    monkeypatch.undo()
    device.run(10)
    assert device.clock == 60


@needs_numba
def test_the_cache_key_carries_the_sources(compiled: kernel.BlockFunction) -> None:
    py_func = compiled.py_func  # type: ignore[attr-defined]
    assert py_func.__closure__ is not None
    fingerprint = kernel.source_hash()
    assert fingerprint is not None
    assert 0 < fingerprint < 2**62
    assert [cell.cell_contents for cell in py_func.__closure__] == [fingerprint]


_MACHINE = """
name = "kernel test machine"
servo_interval_dms = 10
motion_scalar = 1
homing_order = [["X", "Y", "Z"]]
{axes}
"""
_AXIS = """
[axes.{name}]
url = "sim://{name}"
device = "{name} AXIS"
counts_per_mm = 240.0
max_velocity_mm_s = 20.0
max_accel_mm_s2 = 400.0
travel_mm = [0.0, 50.0]
following_error_limit_mm = 2.0
gains = {{ kp = 1.0, ki = 1.0, kd = 0.007 }}
sim = {{ start_mm = 5.0 }}

[axes.{name}.homing]
direction = -1
speed_mm_s = 10.0
slow_speed_mm_s = 2.0
backoff_mm = 1.0
position_mm = -1.0
"""
_PROGRAM = """G21 G90 G17
G0 Z5
G1 X10 Y10 F900
G2 X20 Y10 I5 J0
G3 X15 Y15 Z6 R5
G1 X5 Y5 Z5
M2
"""


def _run_job(monkeypatch: pytest.MonkeyPatch, *, kernel_switch: str) -> dict[str, object]:
    from usbmotion.host.config import parse_config  # noqa: PLC0415 - only this test

    monkeypatch.setenv(kernel.ENVIRONMENT_VARIABLE, kernel_switch)
    axes = "".join(_AXIS.format(name=name) for name in "XYZ")
    config = parse_config(_MACHINE.format(axes=axes), path="<kernel test>")
    world = SimWorld()
    with connect_session(config, world=world) as session:
        devices = [world.device(key) for key in world.keys]
        assert [isinstance(d, Device) and d.fast for d in devices] == [kernel_switch == "1"] * 3
        homing_s = session.home()
        prepared = session.prepare("<kernel test>", text=_PROGRAM)
        report, _ = session.run(prepared, homing_s=homing_s)
    return report.to_json()


@needs_numba
def test_the_main_job_reports_the_same_on_both_paths(
    compiled: kernel.BlockFunction, monkeypatch: pytest.MonkeyPatch
) -> None:
    fast = _run_job(monkeypatch, kernel_switch="1")
    reference = _run_job(monkeypatch, kernel_switch="0")
    assert fast["completed"] is True
    assert fast == reference
