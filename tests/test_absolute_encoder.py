"""Absolute encoders (``encoder = "absolute"``, call 49): the machine file's key, the device
set up on connecting, the angle known before homing, and homing that names the turn: the
zero on the turn boundary nearest the switch's edge, repeating to the encoder's count when
the switch does not repeat."""

from __future__ import annotations

from pathlib import Path

import pytest

from commands import invoke
from usbmotion.device import Device
from usbmotion.device.motor import MICRO
from usbmotion.errors import ConfigError
from usbmotion.host.config import AbsoluteEncoder, MachineConfig, parse_config
from usbmotion.session import MachineSession
from usbmotion.sim.machine import SimulatedMachine, connect_session

MACHINE = """\
name = "absolute"
servo_interval_dms = 1
motion_scalar = 1
watchdog_ms = 0

[axes.X]
url = "sim://X"
counts_per_mm = 240
encoder = "absolute"
max_velocity_mm_s = 20
max_accel_mm_s2 = 500
travel_mm = [0, 100]
gains = { kp = 0.5, ki = 5.0, kd = 0.002 }
sim = { magnet_angle_deg = 100.0, start_mm = 40 }

[axes.Z]
url = "sim://Z"
kind = "stepper"
loop = "closed"
encoder = "absolute"
encoder_counts_per_rev = 4000
steps_per_mm = 400
step_pulse_ns = 100
dir_setup_ns = 20
max_velocity_mm_s = 20
max_accel_mm_s2 = 500
travel_mm = [-40, 0]
following_error_limit_mm = 1.0
gains = { kp = 0.5, ki = 1.0, kd = 0.005 }
homing = { direction = 1, speed_mm_s = 8.0, slow_speed_mm_s = 1.0, backoff_mm = 1.0 }

[axes.Z.sim]
magnet_angle_deg = 250.0
start_mm = -20
inertia_kg_m2 = 1.4e-5
load_torque_mnm = 40.0
viscous_friction_unm_per_rad_s = 80.0
"""
X_TURN = 1920
"""The simulated motor's counts per revolution (the default): X's turn is 8 mm."""
Z_TURN = 3200
"""200 full steps of 16 microsteps: Z's turn is 8 mm."""


def _config(tmp_path: Path, text: str = MACHINE) -> MachineConfig:
    path = tmp_path / "machine.toml"
    path.write_text(text, encoding="utf-8")
    return parse_config(text, path=path)


def _device(session: MachineSession, axis: str) -> Device:
    assert isinstance(session.machine, SimulatedMachine)
    device = session.machine.world.device(axis)
    assert isinstance(device, Device)
    return device


def _counter_minus_shaft(session: MachineSession, axis: str) -> int:
    """Where the axis's machine coordinates sit on its shaft: the counter less the shaft's
    count (the same after two homings exactly when both zeroes are the same)."""
    state = _device(session, axis).state
    return int(state.actual) - int(state.shaft_micro_counts) // MICRO


# --- the machine file ---------------------------------------------------------------------------


def test_the_file_names_each_axis_encoder_and_its_turn(tmp_path: Path) -> None:
    config = _config(tmp_path)
    # 100 degrees of 1920 counts, and 250 of 3200 microsteps
    assert config.axis("X").absolute_encoder == AbsoluteEncoder(turn_counts=X_TURN,
                                                                 magnet_counts=533)
    assert config.axis("Z").absolute_encoder == AbsoluteEncoder(turn_counts=Z_TURN,
                                                                 magnet_counts=2222)
    incremental = _config(tmp_path, MACHINE.replace('encoder = "absolute"\n', "")
                          .replace("magnet_angle_deg = 100.0, ", "")
                          .replace("magnet_angle_deg = 250.0\n", ""))
    assert incremental.axis("X").absolute_encoder is None
    assert incremental.axis("Z").absolute_encoder is None


@pytest.mark.parametrize(("change", "key", "words"), [
    (('encoder = "absolute"', 'encoder = "optical"', 1), "encoder",
     "'optical' is not a kind of encoder"),
    (('loop = "closed"', 'loop = "open"', 1), "encoder",
     "an open-loop stepper reads no encoder"),
    (('encoder = "absolute"', "encoder_counts_per_rev = 2000", 1), "encoder_counts_per_rev",
     "1920 (its counts_per_revolution)"),
    (('encoder = "absolute"\nmax_velocity_mm_s = 20',
      'encoder_counts_per_rev = 1920\nmax_velocity_mm_s = 20', 1), "encoder_counts_per_rev",
     "a servo's incremental encoder is scaled by counts_per_mm alone"),
    (("magnet_angle_deg = 100.0", "magnet_angle_deg = 360.0", 1), "magnet_angle_deg",
     "out of range"),
])
def test_a_wrong_encoder_is_named_with_what_is_allowed(
        tmp_path: Path, change: tuple[str, str, int], key: str, words: str) -> None:
    old, new, count = change
    text = MACHINE.replace(old, new, count)
    if old.startswith("loop"):
        text = text.replace("encoder_counts_per_rev = 4000\n", "").replace(
            "gains = { kp = 0.5, ki = 1.0, kd = 0.005 }\n", "")
    if new.startswith("encoder_counts_per_rev = 2000"):
        text = MACHINE.replace(old, f'{old}\n{new}', count)
    if new.startswith("encoder_counts_per_rev = 1920"):
        text = text.replace("magnet_angle_deg = 100.0, ", "")
    with pytest.raises(ConfigError) as raised:
        _config(tmp_path, text)
    assert key in str(raised.value) and words in str(raised.value)
    assert "allowed" in str(raised.value)


def test_a_real_servo_axis_gives_its_turn(tmp_path: Path) -> None:
    text = MACHINE.replace('url = "sim://X"', 'device = "X AXIS"').replace(
        "sim = { magnet_angle_deg = 100.0, start_mm = 40 }\n", "")
    with pytest.raises(ConfigError, match="encoder_counts_per_rev"):
        _config(tmp_path, text)
    config = _config(tmp_path, text.replace('encoder = "absolute"\n',
                                            'encoder = "absolute"\nencoder_counts_per_rev = 4096\n',
                                            1))
    assert config.axis("X").absolute_encoder == AbsoluteEncoder(turn_counts=4096)


# --- on the devices -----------------------------------------------------------------------------


def test_before_homing_the_device_knows_the_angle_within_a_turn(tmp_path: Path) -> None:
    config = _config(tmp_path)
    with connect_session(config) as session:
        for axis, turn, magnet in (("X", X_TURN, 533), ("Z", Z_TURN, 2222)):
            client = session.machine.axis(axis).client
            setting = client.encoder()
            assert (setting.kind, setting.angle, setting.zero) == (1, magnet, 0)
            state = _device(session, axis).state
            shaft = int(state.shaft_micro_counts) // MICRO
            assert client.status().actual_counts == (shaft + magnet) % turn
        lines = invoke_status(session)
        assert any(line.startswith("X: not homed; its absolute encoder reads") for line in lines)
        session.shutdown()


def invoke_status(session: MachineSession) -> list[str]:
    from usbmotion.cli.status import describe_status  # noqa: PLC0415

    return describe_status(session.machine)


def _check_the_rest_after_homing(session: MachineSession, config: MachineConfig) -> None:
    """Each axis at rest within its travel, at least the pull-off from the switch's edge
    and no nearer the switch than an incremental axis rests (Z's edge is 2.555 mm beyond
    its boundary, toward the travel's end at the switch)."""
    for axis in "XZ":
        homing = config.axis(axis).homing
        zero = session.zeroes[axis]
        scale = session.machine.axis(axis).scale
        here = scale.to_mm(session.machine.axis(axis).client.status().actual_counts)
        lower, upper = config.axis(axis).travel_mm
        assert lower - 0.01 <= here <= upper + 0.01, (axis, here)
        edge = homing.position_mm + scale.to_mm(zero.edge_from_turn_counts)
        away = -homing.direction
        assert away * (here - edge) >= homing.pull_off_mm - 0.01, (axis, here, edge)
        assert away * (here - homing.position_mm) >= homing.pull_off_mm - 0.01, (axis, here)


def test_homing_names_the_turn_and_repeats_to_the_count_where_the_switch_does_not(
        tmp_path: Path) -> None:
    """Between two homings the switch moves by half the margin homing reported (a switch
    that does not repeat): an incremental axis's zero moves with it, an absolute axis's
    stays on its turn boundary, to the count; moved beyond the margin, the next turn is
    named, exactly one turn away."""
    incremental_text = (MACHINE.replace('encoder = "absolute"\n', "")
                        .replace("magnet_angle_deg = 100.0, ", "")
                        .replace("magnet_angle_deg = 250.0\n", ""))
    moves: dict[str, int] = {}
    within: dict[str, int] = {}
    results: dict[str, list[int]] = {}
    for label, text in (("absolute", MACHINE), ("incremental", incremental_text),
                        ("beyond", MACHINE)):
        config = _config(tmp_path, text)
        with connect_session(config) as session:
            session.home()
            first = {axis: _counter_minus_shaft(session, axis) for axis in "XZ"}
            _check_the_rest_after_homing(session, config)
            for axis, turn in (("X", X_TURN), ("Z", Z_TURN)):
                zero = session.zeroes[axis]
                if label == "incremental":
                    assert zero.turn_counts == 0
                    continue
                assert zero.turn_counts == turn
                from_turn = zero.edge_from_turn_counts
                assert -turn // 2 <= from_turn < turn // 2
                # the zero is on a boundary: the encoder reads angle 0 at the switch's
                # machine position
                client = session.machine.axis(axis).client
                switch = session.machine.axis(axis).scale.to_counts(
                    config.axis(axis).homing.position_mm)
                assert (switch - client.encoder().zero) % turn == 0
                margin = turn // 2 - abs(from_turn)
                if label == "absolute":
                    moves[axis] = margin // 2 if from_turn < 0 else -(margin // 2)
                    within[axis] = moves[axis]
                else:   # beyond the margin, toward the middle between boundaries
                    moves[axis] = -(margin + 5) if from_turn < 0 else margin + 5
            for axis in "XZ":
                client = session.machine.axis(axis).client
                lower, upper = client.sim_travel()
                client.set_sim_travel(lower + moves[axis], upper + moves[axis])
            session.home()
            second = {axis: _counter_minus_shaft(session, axis) for axis in "XZ"}
            results[label] = [second[axis] - first[axis] for axis in "XZ"]
            session.shutdown()
    assert results["absolute"] == [0, 0]
    # an incremental zero moves with the switch (Z to a count: its encoder's 4000 counts a
    # turn are read in 3200 microsteps)
    x_shift, z_shift = results["incremental"]
    assert x_shift == -within["X"] and abs(z_shift + within["Z"]) <= 1
    assert [abs(shift) for shift in results["beyond"]] == [X_TURN, Z_TURN]


def test_connecting_again_keeps_a_homed_axis_homed(tmp_path: Path) -> None:
    """The encoder is sent only when it differs: connecting again to homed devices does not
    take the angle afresh (which would lose the zero)."""
    config = _config(tmp_path)
    with connect_session(config) as session:
        session.home()
        before = {axis: session.machine.axis(axis).client.status().actual_counts
                  for axis in "XZ"}
        session.machine.configure()
        after = {axis: session.machine.axis(axis).client.status().actual_counts
                 for axis in "XZ"}
        assert all(abs(after[axis] - before[axis]) <= 2 for axis in "XZ")
        session.shutdown()


def test_home_prints_the_turn_it_named(tmp_path: Path) -> None:
    path = tmp_path / "machine.toml"
    path.write_text(MACHINE, encoding="utf-8")
    code, out, err = invoke("home", "--machine", str(path), "-q")
    assert code == 0, err
    assert "X: absolute encoder: -1.000 mm is the turn boundary nearest the switch" in out
    assert "a turn is 8.000 mm; a switch that repeats within" in out
