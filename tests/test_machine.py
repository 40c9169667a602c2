"""The machine layer: connect and configure axes, discovery by name, synchronised starts."""

from __future__ import annotations

import math
import socket
from pathlib import Path

import pytest

from usbmotion.clock import WALL_CLOCK
from usbmotion.device import Device, MemoryFlash
from usbmotion.errors import ConfigError, DeviceError, DeviceNotFoundError
from usbmotion.host.config import MachineConfig, load_config, parse_config
from usbmotion.host.device import ControlMode
from usbmotion.host.discovery import discover, probe, scan
from usbmotion.host.machine import Machine
from usbmotion.host.timesync import SyncReport, measure_clock, synchronise_start
from usbmotion.sim.machine import SimulatedMachine
from usbmotion.sim.registry import set_world
from usbmotion.sim.server import DeviceServer
from usbmotion.sim.world import SimWorld, VirtualClock

EXAMPLE = Path(__file__).resolve().parent.parent / "examples" / "machine.toml"

AXIS = """
[axes.{name}]
{where}
counts_per_mm = 240
max_velocity_mm_s = 20
max_accel_mm_s2 = 500
travel_mm = [0, 200]
following_error_limit_mm = 1.5
gains = {{ kp = 0.5, ki = 5.0, kd = 0.002 }}
velocity_gains = {{ kp = 0.001, ki = 0.5, kd = 0 }}
{extra}
"""


def machine_text(axes: dict[str, str], *, top: str = "", extra: str = "") -> str:
    """A machine file: ``axes`` maps a letter to its ``url = ...``/``device = ...`` lines."""
    text = "watchdog_ms = 0\n" + top
    for name, where in axes.items():
        text += AXIS.format(name=name, where=where, extra=extra)
    return text


def named(name: str) -> Device:
    """A simulated device with ``name`` in its flash."""
    device = Device(flash=MemoryFlash())
    codes = " ".join(str(ord(c)) for c in name)
    device.feed(f"18 {len(name)} {codes}\n".encode("ascii"))
    device.take_output()
    return device


def serving(world: SimWorld) -> DeviceServer:
    """Serve ``world`` on pseudo-terminals, once its devices have run their first tick.

    The first tick may compile the servo kernel, which holds the serving thread for a
    while: probes sent meanwhile would be answered after their timeout.
    """
    server = DeviceServer(world, pty=True).start()
    deadline = WALL_CLOCK.now() + 60
    while world.time_us == 0 and WALL_CLOCK.now() < deadline:
        WALL_CLOCK.sleep(0.01)
    return server


# --- connect and configure, virtual time -----------------------------------------------


def test_connect_and_configure_the_example_machine() -> None:
    config = load_config(EXAMPLE)
    with SimulatedMachine.connect(config) as machine:
        assert list(machine.axes) == ["X", "Y", "Z"]
        assert isinstance(machine.clock, VirtualClock)
        world = machine.world
        assert world is not None
        assert machine.clock.world is world
        machine.configure()
        for name, axis in machine.axes.items():
            settings = world.device(name).settings
            wanted = config.axis(name)
            assert settings.name == wanted.device
            assert axis.client.device_name() == wanted.device
            assert settings.servo_update_interval_us == config.servo_interval_dms * 100
            assert settings.motion_update_interval_scalar == config.motion_scalar
            assert settings.control_mode == 1
            assert settings.gains.kp == (500, -3)
            assert settings.gains.ki == (500, -2)
            assert settings.gains.kd == (200, -5)
            assert settings.following_error_limit == round(
                wanted.following_error_limit_mm * 240
            )
            assert settings.watchdog_ms == config.watchdog_ms
            assert wanted.sim is not None
            motor = settings.motor
            travel = wanted.sim_travel_counts
            assert (motor.travel_lower_counts, motor.travel_upper_counts) == travel
            assert motor.counts_per_revolution == 1920
            inertia = motor.inertia_kg_m2[0] * 10.0 ** motor.inertia_kg_m2[1]
            assert inertia == pytest.approx(wanted.sim.inertia_kg_m2)
            load = motor.load_torque_mnm[0] * 10.0 ** motor.load_torque_mnm[1]
            assert load == pytest.approx(wanted.sim.load_torque_mnm)
            assert axis.scale.to_counts(1.0) == 240
        status = machine.status()
        assert all(not s.enabled and s.fault == 0 for s in status.values())
        assert machine.positions_mm() == {"X": 0.0, "Y": 0.0, "Z": 0.0}
        assert machine.ping() == {"X": (0, 1000), "Y": (0, 1000), "Z": (0, 1000)}
    machine.close()


def trapezoid_counts(axis_velocity_mm_s: float, accel_mm_s2: float, cruise_s: float,
                     counts_per_mm: float, period_s: float) -> list[int]:
    """Positions every ``period_s`` of accelerate, cruise, decelerate, from 0."""
    ramp_s = axis_velocity_mm_s / accel_mm_s2
    total_s = 2 * ramp_s + cruise_s
    ramp_mm = 0.5 * accel_mm_s2 * ramp_s**2
    out: list[int] = []
    for i in range(1, round(total_s / period_s) + 1):
        t = i * period_s
        if t < ramp_s:
            mm = 0.5 * accel_mm_s2 * t * t
        elif t < ramp_s + cruise_s:
            mm = ramp_mm + axis_velocity_mm_s * (t - ramp_s)
        else:
            left = total_s - t
            mm = 2 * ramp_mm + axis_velocity_mm_s * cruise_s - 0.5 * accel_mm_s2 * left * left
        out.append(round(mm * counts_per_mm))
    return out


def test_the_example_limits_are_followed_within_a_tenth_of_a_millimetre() -> None:
    config = load_config(EXAMPLE)
    with SimulatedMachine.connect(config) as machine:
        assert machine.world is not None
        machine.configure()
        machine.enable(True)
        for name in "XZ":
            axis = config.axis(name)
            machine.axis(name).client.add_setpoints(trapezoid_counts(
                axis.max_velocity_mm_s, axis.max_accel_mm_s2, 0.3, axis.counts_per_mm,
                config.motion_period_s,
            ))
        worst = {"X": 0, "Z": 0}
        for _ in range(600):
            machine.world.advance(1000)
            for name in "XZ":
                state = machine.world.device(name).state
                worst[name] = max(worst[name], abs(state.desired - state.actual))
        assert max(worst.values()) < 0.1 * 240, worst
        assert all(s.fault == 0 and s.queued == 0 for s in machine.status().values())


def test_set_mode_switches_the_gains_with_the_mode() -> None:
    config = load_config(EXAMPLE)
    with SimulatedMachine.connect(config) as machine:
        machine.configure()
        machine.set_mode(ControlMode.VELOCITY, axes=["Z"])
        assert machine.world is not None
        z = machine.world.device("Z").settings
        assert z.control_mode == 2
        assert (z.gains.kp, z.gains.ki, z.gains.kd) == ((100, -5), (500, -3), (0, 0))
        assert machine.world.device("X").settings.control_mode == 1
        machine.set_mode(ControlMode.POSITION)
        assert machine.world.device("Z").settings.gains.kp == (500, -3)
        with pytest.raises(KeyError, match="no axis 'Q'; this machine has X, Y, Z"):
            machine.set_mode(ControlMode.POSITION, axes=["Q"])


def test_connect_uses_devices_already_in_the_given_world() -> None:
    world = SimWorld()
    mine = named("PRE-MADE X")
    world.add(mine, key="X")
    config = parse_config(machine_text({"X": 'url = "sim://X"', "Y": 'url = "sim://Y"'}))
    with SimulatedMachine.connect(config, world=world) as machine:
        assert machine.world is world
        assert world.device("X") is mine
        assert machine.axis("X").client.device_name() == "PRE-MADE X"
        assert machine.axis("Y").client.device_name() == "Y"
    assert set(world.keys) == {"X", "Y"}


def test_a_url_that_answers_to_another_name_is_refused() -> None:
    world = SimWorld()
    world.add(named("SOMETHING ELSE"), key="X")
    config = parse_config(machine_text({"X": 'url = "sim://X"\ndevice = "X AXIS"'}))
    with pytest.raises(DeviceNotFoundError, match="answers to 'SOMETHING ELSE', not to the"
                       " configured device 'X AXIS'"):
        SimulatedMachine.connect(config, world=world)


def test_axes_named_by_device_are_found_in_the_world() -> None:
    world = SimWorld()
    for key, name in (("0", "BENCH X"), ("1", "BENCH Y")):
        world.add(named(name), key=key)
    config = parse_config(
        machine_text({"X": 'device = "BENCH X"', "Y": 'device = "BENCH Y"'})
    )
    with SimulatedMachine.connect(config, world=world, search_ports=False) as machine:
        assert machine.axis("X").url.startswith("sim://0?world=")
        assert machine.axis("Y").url.startswith("sim://1?world=")
        assert machine.axis("Y").client.device_name() == "BENCH Y"


def test_simulated_and_real_axes_cannot_share_a_machine(default_world: str) -> None:
    config = parse_config(machine_text({"X": 'url = "sim://X"', "Y": 'url = "loop://"'}))
    with pytest.raises(ConfigError, match="must all be simulated in one world"):
        Machine.connect(config)


def test_stop_clears_and_disables_every_axis_and_reports_failures_together() -> None:
    config = load_config(EXAMPLE)
    with SimulatedMachine.connect(config) as machine:
        machine.configure()
        machine.enable(True)
        for axis in machine.axes.values():
            axis.client.add_setpoints([10] * 500)
        machine.stop()
        for s in machine.status().values():
            assert (s.queued, s.enabled) == (0, False)
        machine.enable(True)
        for axis in machine.axes.values():
            axis.client.add_setpoints([10] * 500)
        link = machine.axis("Y").client.transport.port.link
        link.faults.disconnected = True
        with pytest.raises(DeviceError, match=r"stop failed on 2 step\(s\): Y \(clear queue\)"
                           r".*Y \(disable\)") as caught:
            machine.stop()
        assert caught.value.device == "Y"
        link.faults.disconnected = False
        status = machine.status()
        assert (status["X"].queued, status["X"].enabled) == (0, False)
        assert (status["Z"].queued, status["Z"].enabled) == (0, False)
        assert status["Y"].enabled


def test_enable_refused_by_one_axis_leaves_every_axis_disabled() -> None:
    config = load_config(EXAMPLE)
    with SimulatedMachine.connect(config) as machine:
        machine.configure()
        assert machine.world is not None
        machine.world.device("Y").feed(b"29 1\n3 1\n0 500\n")
        machine.clock.sleep(0.05)
        assert machine.axis("Y").client.fault()[0] == 2
        with pytest.raises(DeviceError, match="axis Y could not be enabled") as caught:
            machine.enable(True)
        assert caught.value.device == "Y"
        assert not any(s.enabled for s in machine.status().values())
        machine.clear_faults()
        machine.configure()
        machine.enable(True)
        assert all(s.enabled for s in machine.status().values())


# --- discovery -------------------------------------------------------------------------------


def test_discovery_finds_names_on_sim_urls(world_name: str) -> None:
    world = SimWorld()
    set_world(world_name, world)
    for key, name in (("a", "LEFT LEG"), ("b", "RIGHT ARM")):
        world.add(named(name), key=key)
    urls = [f"sim://a?world={world_name}", f"sim://b?world={world_name}&latency_us=500"]
    found = discover(["RIGHT ARM", "LEFT LEG"], urls=urls, search_ports=False)
    assert found == {"RIGHT ARM": urls[1], "LEFT LEG": urls[0]}
    answer = probe(urls[0])
    assert (answer.name, answer.problem) == ("LEFT LEG", "")
    assert answer.describe() == f"{urls[0]}: 'LEFT LEG'"


def test_a_missing_name_lists_every_port_searched_and_its_answer(
    world_name: str, tmp_path: Path
) -> None:
    world = SimWorld()
    set_world(world_name, world)
    world.add(named("X AXIS"), key="x")
    silent = socket.create_server(("127.0.0.1", 0))
    try:
        quiet_url = f"socket://127.0.0.1:{silent.getsockname()[1]}"
        missing = str(tmp_path / "ttyNOPE")
        urls = [f"sim://x?world={world_name}", quiet_url, missing, "loop://"]
        with pytest.raises(DeviceNotFoundError) as caught:
            discover(["X AXIS", "Z AXIS"], urls=urls, search_ports=False, timeout_s=0.1)
    finally:
        silent.close()
    error = caught.value
    message = str(error)
    assert error.name == "Z AXIS"
    assert error.searched == tuple(urls)
    assert "device 'Z AXIS' not found; searched 4 port(s)" in message
    assert f"sim://x?world={world_name}: 'X AXIS'" in message
    assert f"{quiet_url}: no answer within 0.1 s" in message
    assert f"{missing}: no such port" in message
    assert "loop://: answered '21 0', not a device name" in message


def test_a_name_on_two_ports_is_ambiguous(world_name: str) -> None:
    world = SimWorld()
    set_world(world_name, world)
    world.add(named("TWIN"), key="a")
    world.add(named("TWIN"), key="b")
    urls = [f"sim://a?world={world_name}", f"sim://b?world={world_name}"]
    with pytest.raises(DeviceNotFoundError, match="'TWIN' answers on 2 ports"):
        discover(["TWIN"], urls=urls, search_ports=False)
    assert [a.name for a in scan(urls + urls[:1])] == ["TWIN", "TWIN"]


@pytest.mark.realtime
def test_discovery_over_pseudo_terminals() -> None:
    world = SimWorld()
    for index, name in enumerate(("PTY X", "PTY Y")):
        world.add(named(name), key=str(index))
    with serving(world) as server:
        paths = [endpoint.path for endpoint in server.endpoints]
        found = discover(["PTY Y", "PTY X"], urls=paths, search_ports=False)
        assert found == {"PTY X": paths[0], "PTY Y": paths[1]}
        with pytest.raises(DeviceNotFoundError) as caught:
            discover(["PTY Z"], urls=paths, search_ports=False, timeout_s=0.2)
        assert caught.value.searched == tuple(paths)
        assert f"{paths[0]}: 'PTY X'; {paths[1]}: 'PTY Y'" in str(caught.value)


# --- synchronised start ---------------------------------------------------------------------


def start_world_times_us(world: SimWorld, keys: list[str], report: SyncReport) -> list[int]:
    """The world time at which each device's clock reaches its armed start tick.

    Brings every device to the same whole tick first: the world's devices were added
    together and tick in step, so clock differences there are origin differences.
    """
    tick_us = world.device(keys[0]).tick_us
    common_us = (world.time_us // tick_us + 2) * tick_us
    world.advance_to(common_us)
    return [
        common_us + (d.start_tick - world.device(key).clock) * tick_us
        for key, d in zip(keys, report.devices, strict=True)
    ]


def latency_config(latencies_us: tuple[int, ...]) -> MachineConfig:
    axes = {
        name: f'url = "sim://{name}?latency_us={latency}"'
        for name, latency in zip("XYZ", latencies_us, strict=True)
    }
    return parse_config(machine_text(axes))


def test_time_sync_starts_every_axis_on_the_same_world_tick() -> None:
    config = latency_config((0, 700, 3000))
    with SimulatedMachine.connect(config) as machine:
        machine.configure()
        world = machine.world
        assert world is not None
        world.advance(12_345)
        machine.enable(True)
        report = machine.synchronise()
        rtts = [d.estimate.rtt_s for d in report.devices]
        assert rtts[0] < rtts[1] < rtts[2]
        assert rtts[2] >= 0.006
        assert report.estimated_skew_s < 0.0005
        assert report.lead_s > 0
        ticks = {d.start_tick for d in report.devices}
        assert all(world.device(k).state.start_tick == d.start_tick
                   for k, d in zip("XYZ", report.devices, strict=True))
        for axis in machine.axes.values():
            axis.client.add_setpoints([240 * (i + 1) for i in range(50)])
        assert all(world.device(k).state.desired == 0 for k in "XYZ")
        starts = start_world_times_us(world, list("XYZ"), report)
        assert len(set(starts)) == 1, starts
        assert abs(starts[0] / 1e6 - report.start_s) <= 0.0005
        assert len(ticks) == 3
        tick_us = world.device("X").tick_us
        first_change: dict[str, int] = {}
        while len(first_change) < 3:
            world.advance(tick_us)
            for key in "XYZ":
                if key not in first_change and world.device(key).state.desired != 0:
                    first_change[key] = world.time_us
        assert len(set(first_change.values())) == 1, first_change
        assert 0 <= first_change["X"] - starts[0] <= tick_us


@pytest.mark.parametrize("latencies", [(0, 0, 0), (250, 1250, 40), (999, 1, 4500)])
def test_time_sync_is_exact_for_other_latencies(latencies: tuple[int, ...]) -> None:
    with SimulatedMachine.connect(latency_config(latencies)) as machine:
        machine.configure()
        assert machine.world is not None
        machine.world.advance(777)
        machine.enable(True)
        report = machine.synchronise(samples=8)
        starts = start_world_times_us(machine.world, list("XYZ"), report)
        assert len(set(starts)) == 1, (latencies, starts, report.describe())


def test_measure_clock_and_arguments() -> None:
    with SimulatedMachine.connect(latency_config((0, 0, 2000))) as machine:
        z = machine.axis("Z").client
        estimate = measure_clock(z, samples=3)
        assert estimate.samples == 3
        assert estimate.tick_s == pytest.approx(0.001)
        assert estimate.rtt_s == pytest.approx(0.004, abs=0.0011)
        now_ticks = estimate.ticks_at(machine.clock.now())
        assert math.isclose(estimate.host_time_of(now_ticks), machine.clock.now())
        assert abs(now_ticks - z.clock()) <= 3
        with pytest.raises(ValueError, match="samples 0 must be an integer >= 1"):
            measure_clock(z, samples=0)
        with pytest.raises(ValueError, match="margin_s -1 must be >= 0"):
            synchronise_start(machine.clients, margin_s=-1)


@pytest.mark.realtime
def test_real_time_start_skew_over_pseudo_terminals(capsys: pytest.CaptureFixture[str]) -> None:
    world = SimWorld()
    names = ("RT X", "RT Y", "RT Z")
    for index, name in enumerate(names):
        world.add(named(name), key=str(index))
    server = serving(world)
    try:
        paths = [endpoint.path for endpoint in server.endpoints]
        axes = {letter: f'device = "{name}"' for letter, name in zip("XYZ", names, strict=True)}
        ports = f"ports = {paths!r}\n".replace("'", '"')
        config = parse_config(machine_text(axes, top="servo_interval_dms = 1\n" + ports,
                                           extra="sim = { start_mm = 100.0 }"))
        with Machine.connect(config, search_ports=False) as machine:
            assert machine.clock is WALL_CLOCK
            assert [a.url for a in machine.axes.values()] == paths
            machine.configure()
            machine.enable(True)
            for axis in machine.axes.values():
                axis.client.set_position(0)
            report = machine.synchronise(margin_s=0.05)
            for axis in machine.axes.values():
                axis.client.add_setpoints([2 * (i + 1) for i in range(20)])
            WALL_CLOCK.sleep(max(0.0, report.start_s - WALL_CLOCK.now()) + 0.05)
            statuses = machine.status()
            machine.stop()
    finally:
        server.close()
    assert all(s.desired_counts == 40 and s.fault == 0 for s in statuses.values()), statuses
    starts = start_world_times_us(world, ["0", "1", "2"], report)
    measured_s = (max(starts) - min(starts)) / 1e6
    with capsys.disabled():
        print(f"\n{report.describe()}\nmeasured start skew over ptys: {measured_s * 1e6:.0f} us")
    assert report.skew_bound_s < 0.02
    assert measured_s < 0.005
