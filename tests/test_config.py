"""The machine configuration file: the examples load, every bad form is a located ConfigError."""

from __future__ import annotations

from pathlib import Path

import pytest

from usbmotion.errors import ConfigError
from usbmotion.host.config import (
    SIM_MOTOR_DEFAULTS,
    MachineConfig,
    load_config,
    parse_config,
)

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"

GOOD = """\
name = "bench"
servo_interval_dms = 10
watchdog_ms = 0

[axes.X]
url = "sim://X"
counts_per_mm = 240
max_velocity_mm_s = 25
max_accel_mm_s2 = 500
travel_mm = [0, 200]
gains = { kp = 0.2, ki = 2, kd = 0.002 }

[axes.Z]
device = "Z AXIS"
counts_per_mm = 100.5
max_velocity_mm_s = 10
max_accel_mm_s2 = 200
travel_mm = [-10, 90]
following_error_limit_mm = 0

[axes.Z.gains]
kp = 0.1
ki = 0
kd = 0

[axes.Z.homing]
direction = 1
speed_mm_s = 5
"""


def write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "machine.toml"
    path.write_text(text, encoding="utf-8")
    return path


def line_of(text: str, fragment: str) -> int:
    """The 1-based line of the first line holding ``fragment``."""
    for number, line in enumerate(text.splitlines(), start=1):
        if fragment in line:
            return number
    raise AssertionError(f"{fragment!r} not in the text")


def fails(tmp_path: Path, text: str) -> ConfigError:
    path = write(tmp_path, text)
    with pytest.raises(ConfigError) as caught:
        load_config(path)
    error = caught.value
    assert str(path) in str(error)
    assert error.path == str(path)
    return error


def assert_located(
    error: ConfigError, *, key: str, line: int | None, words: tuple[str, ...]
) -> None:
    message = str(error)
    assert error.key == key
    assert key in message
    assert error.line == line
    if line is not None:
        assert f"{error.path}:{line}:" in message
    for word in words:
        assert word in message, (word, message)


# --- good files ---------------------------------------------------------------------------


def test_example_machine_loads_as_the_simulated_xyz_machine() -> None:
    config = load_config(EXAMPLES / "machine.toml")
    assert config.axis_names == ("X", "Y", "Z")
    assert config.is_simulated
    assert config.homing_order == (("Z",), ("X", "Y"))
    assert config.servo_period_s == pytest.approx(0.001)
    for axis in config.axes:
        assert axis.counts_per_mm == 240.0
        assert axis.homing.direction == -1
        assert axis.homing.position_mm == axis.travel_mm[0]
        assert axis.switch_margin_mm == 0.0
        assert axis.sim is not None
        lower, upper = axis.sim_travel_counts or (0, 0)
        assert lower < 0 < upper
        assert upper - lower == round((axis.travel_mm[1] - axis.travel_mm[0]) * 240)
    assert config.axis("X").travel_mm == (0.0, 200.0)
    assert config.axis("Z").travel_mm == (0.0, 100.0)


def test_real_machine_example_loads_without_simulated_motors() -> None:
    config = load_config(EXAMPLES / "real-machine.toml")
    assert not config.is_simulated
    assert all(axis.sim is None for axis in config.axes)
    assert all(axis.device for axis in config.axes)


def test_values_defaults_and_derived_figures(tmp_path: Path) -> None:
    config = load_config(write(tmp_path, GOOD))
    assert isinstance(config, MachineConfig)
    assert config.name == "bench"
    assert config.motion_scalar == 1
    assert config.junction_deviation_mm == 0.01
    assert config.watchdog_ms == 0
    assert config.ports == ()
    x, z = config.axes
    assert x.url == "sim://X" and x.device is None and x.is_simulated
    assert z.device == "Z AXIS" and z.url is None and not z.is_simulated
    assert x.gains.kp == 0.2 and x.gains.ki == 2.0
    assert x.following_error_limit_counts == 480
    assert x.max_jerk_mm_s3 == 20 * 500
    assert x.scale.to_counts(1.0) == 240
    assert x.sim is not None and x.sim.start_mm == 100.0
    assert x.homing.position_mm == 0.0
    assert x.sim_travel_counts == (-24000, 24000)
    assert x.sim.counts_per_revolution == SIM_MOTOR_DEFAULTS["counts_per_revolution"]
    assert z.sim is None and z.sim_travel_counts is None
    assert z.homing.direction == 1
    assert z.homing.position_mm == 90.0
    assert z.switch_margin_mm == 0.0
    assert z.homing.slow_speed_mm_s == pytest.approx(0.5)
    assert z.following_error_limit_counts == 0
    assert config.homing_order == (("Z",), ("X",))


def test_a_home_switch_beyond_the_travel_moves_both_simulated_switches(tmp_path: Path) -> None:
    text = GOOD.replace("gains = { kp = 0.2, ki = 2, kd = 0.002 }",
                        "gains = { kp = 0.2, ki = 2, kd = 0.002 }\n"
                        "homing = { position_mm = -1.5 }")
    x = load_config(write(tmp_path, text)).axis("X")
    assert x.homing.position_mm == -1.5
    assert x.switch_margin_mm == 1.5
    assert x.sim_travel_counts == (-24360, 24360)


def test_sim_defaults_are_the_device_motor_defaults() -> None:
    from usbmotion.device.motor import MotorParams  # noqa: PLC0415

    motor = MotorParams()

    def value(pair: tuple[int, int]) -> float:
        return pair[0] * 10.0 ** pair[1]

    d = SIM_MOTOR_DEFAULTS
    assert d["source_voltage_v"] == pytest.approx(value(motor.source_voltage_v))
    assert d["torque_constant_mnm_per_a"] == pytest.approx(value(motor.torque_constant_mnm_per_a))
    assert d["winding_resistance_ohm"] == pytest.approx(value(motor.winding_resistance_ohm))
    assert d["counts_per_revolution"] == motor.counts_per_revolution
    assert d["inertia_kg_m2"] == pytest.approx(value(motor.inertia_kg_m2))
    assert d["viscous_friction_unm_per_rad_s"] == pytest.approx(
        value(motor.viscous_friction_unm_per_rad_s)
    )
    assert d["load_torque_mnm"] == pytest.approx(value(motor.load_torque_mnm))
    assert d["update_interval_dms"] == motor.sim_update_interval_dms


def test_parse_config_names_a_string_source() -> None:
    with pytest.raises(ConfigError, match=r"^<string>:1: speed: unknown key 'speed'"):
        parse_config("speed = 1\n" + GOOD)
    config = parse_config(GOOD, path="inline.toml")
    assert config.path == Path("inline.toml")
    assert config.name == "bench"


# --- bad files: each names the file, the key, the line and what is allowed ---------------


def test_unknown_top_level_key(tmp_path: Path) -> None:
    text = GOOD.replace('servo_interval_dms = 10', 'servo_interval_dms = 10\ncolour = "red"')
    error = fails(tmp_path, text)
    assert_located(error, key="colour", line=line_of(text, "colour"),
                   words=("unknown key 'colour'", "allowed keys here", "servo_interval_dms",
                          "homing_order"))


def test_unknown_key_in_an_axis(tmp_path: Path) -> None:
    text = GOOD.replace("max_accel_mm_s2 = 200", "max_accel_mm_s2 = 200\nfeed = 3")
    error = fails(tmp_path, text)
    assert_located(error, key="axes.Z.feed", line=line_of(text, "feed = 3"),
                   words=("unknown key 'feed'", "counts_per_mm", "travel_mm"))


def test_unknown_key_in_an_inline_sub_table(tmp_path: Path) -> None:
    text = GOOD.replace("kd = 0.002 }", "kd = 0.002, kf = 1 }")
    error = fails(tmp_path, text)
    assert_located(error, key="axes.X.gains.kf", line=line_of(text, "kf = 1"),
                   words=("unknown key 'kf'", "kd, ki, kp"))


def test_unknown_axis_letter(tmp_path: Path) -> None:
    text = GOOD.replace("[axes.Z]", "[axes.z]").replace("[axes.Z.", "[axes.z.")
    error = fails(tmp_path, text)
    assert_located(error, key="axes.z", line=line_of(text, "[axes.z]"),
                   words=("'z' is not an axis name", "X, Y, Z, A, B, C, U, V, W"))


def test_bad_value_type(tmp_path: Path) -> None:
    text = GOOD.replace("max_velocity_mm_s = 25", 'max_velocity_mm_s = "fast"')
    error = fails(tmp_path, text)
    assert_located(error, key="axes.X.max_velocity_mm_s", line=line_of(text, '"fast"'),
                   words=("'fast' is not a number", "allowed: a number > 0", "mm/s"))


def test_boolean_is_not_a_number(tmp_path: Path) -> None:
    text = GOOD.replace("servo_interval_dms = 10", "servo_interval_dms = true")
    error = fails(tmp_path, text)
    assert_located(error, key="servo_interval_dms", line=2,
                   words=("True (bool) is not an integer", "an integer 1..10000"))


def test_out_of_range_value(tmp_path: Path) -> None:
    text = GOOD.replace("max_accel_mm_s2 = 500", "max_accel_mm_s2 = -5")
    error = fails(tmp_path, text)
    assert_located(error, key="axes.X.max_accel_mm_s2", line=line_of(text, "= -5"),
                   words=("-5 is out of range", "allowed: a number > 0"))


def test_out_of_range_in_a_sub_table(tmp_path: Path) -> None:
    text = GOOD.replace("direction = 1", "direction = 2")
    error = fails(tmp_path, text)
    assert_located(error, key="axes.Z.homing.direction", line=line_of(text, "direction = 2"),
                   words=("2 (int) is not a homing direction", "-1", "lower limit switch"))


def test_travel_must_be_an_increasing_pair(tmp_path: Path) -> None:
    text = GOOD.replace("travel_mm = [0, 200]", "travel_mm = [200, 0]")
    error = fails(tmp_path, text)
    assert_located(error, key="axes.X.travel_mm", line=line_of(text, "[200, 0]"),
                   words=("lowest < highest",))


def test_missing_required_key(tmp_path: Path) -> None:
    text = GOOD.replace("counts_per_mm = 100.5\n", "")
    error = fails(tmp_path, text)
    assert_located(error, key="axes.Z.counts_per_mm", line=line_of(text, "[axes.Z]"),
                   words=("missing required key 'counts_per_mm'", "encoder counts per mm"))


def test_missing_device_and_url(tmp_path: Path) -> None:
    text = GOOD.replace('device = "Z AXIS"\n', "")
    error = fails(tmp_path, text)
    assert_located(error, key="axes.Z.device", line=line_of(text, "[axes.Z]"),
                   words=("'device' or 'url'", "sim://X", "/dev/ttyACM0"))


def test_missing_gains_table(tmp_path: Path) -> None:
    text = GOOD.replace("gains = { kp = 0.2, ki = 2, kd = 0.002 }\n", "")
    error = fails(tmp_path, text)
    assert_located(error, key="axes.X.gains", line=line_of(text, "[axes.X]"),
                   words=("missing required key 'gains'", "kp, ki, kd"))


def test_no_axes(tmp_path: Path) -> None:
    error = fails(tmp_path, "servo_interval_dms = 10\n")
    assert_located(error, key="axes", line=None, words=("missing required key 'axes'",
                                                        "[axes.X]"))


def test_toml_syntax_error_gives_tomllib_line(tmp_path: Path) -> None:
    text = GOOD.replace("max_accel_mm_s2 = 200", "max_accel_mm_s2 = = 200")
    error = fails(tmp_path, text)
    line = line_of(text, "= = 200")
    assert error.line == line
    assert f"{error.path}:{line}: TOML syntax error" in str(error)
    assert f"line {line}, column" in str(error)


def test_unreadable_file_is_a_config_error(tmp_path: Path) -> None:
    missing = tmp_path / "nowhere.toml"
    with pytest.raises(ConfigError, match="cannot read") as caught:
        load_config(missing)
    assert caught.value.path == str(missing)


@pytest.mark.parametrize(
    ("old", "new", "key", "words"),
    [
        ('device = "Z AXIS"', 'device = "' + "Z" * 26 + '"', "axes.Z.device",
         ("not a device name", "1..25 printable ASCII")),
        ('url = "sim://X"', 'url = "sim://X?world=other"', "axes.X.url",
         ("names a world", "sim://NAME")),
        ('url = "sim://X"', 'url = "sim://X?latency_us=soon"', "axes.X.url",
         ("latency_us", "not an integer")),
        ("kp = 0.1", "kp = 1e-15", "axes.Z.gains.kp",
         ("cannot be sent to the device", "call 9")),
        ("kp = 0.1", "kp = -0.1", "axes.Z.gains.kp", ("out of range", ">= 0")),
        ("watchdog_ms = 0", "watchdog_ms = 500", "watchdog_ms",
         ("shorter than a full motion queue", ">= 1250")),
        ("watchdog_ms = 0", "watchdog_ms = 1.5", "watchdog_ms", ("not an integer",)),
        ("watchdog_ms = 0", 'homing_order = ["X"]', "homing_order", ("Z never homed",)),
        ("watchdog_ms = 0", 'homing_order = ["X", ["Z", "Y"]]', "homing_order",
         ("'Y' is not an axis of this machine",)),
        ("watchdog_ms = 0", 'homing_order = ["X", ["Z", "X"]]', "homing_order",
         ("'X' is listed twice",)),
        ("watchdog_ms = 0", "homing_order = [1]", "homing_order",
         ("is not an axis name or a list",)),
        ("watchdog_ms = 0", 'ports = "/dev/ttyACM0"', "ports", ("not a list",)),
        ("speed_mm_s = 5", "speed_mm_s = 50", "axes.Z.homing.speed_mm_s",
         ("out of range", "at most max_velocity_mm_s")),
        ("speed_mm_s = 5", "speed_mm_s = 5\nposition_mm = 80", "axes.Z.homing.position_mm",
         ("80 is out of range", "at or above travel_mm's highest")),
    ],
)
def test_bad_values_are_located(
    tmp_path: Path, old: str, new: str, key: str, words: tuple[str, ...]
) -> None:
    assert old in GOOD
    text = GOOD.replace(old, new, 1)
    error = fails(tmp_path, text)
    assert_located(error, key=key, line=line_of(text, new.splitlines()[-1]),
                   words=(*words, "allowed"))


def test_the_same_device_on_two_axes(tmp_path: Path) -> None:
    text = GOOD.replace('url = "sim://X"', 'device = "Z AXIS"')
    error = fails(tmp_path, text)
    assert_located(error, key="axes.Z", line=line_of(text, "[axes.Z]"),
                   words=("device 'Z AXIS' is also axis X's",))


def test_sim_table_values_are_checked(tmp_path: Path) -> None:
    text = GOOD.replace("gains = { kp = 0.2, ki = 2, kd = 0.002 }",
                        "gains = { kp = 0.2, ki = 2, kd = 0.002 }\n"
                        "sim = { start_mm = 250.0 }")
    error = fails(tmp_path, text)
    assert_located(error, key="axes.X.sim.start_mm", line=line_of(text, "start_mm = 250"),
                   words=("250.0 is out of range", "within travel_mm"))
    text = GOOD.replace("gains = { kp = 0.2, ki = 2, kd = 0.002 }",
                        "gains = { kp = 0.2, ki = 2, kd = 0.002 }\n"
                        "[axes.X.sim]\ninertia_kg_m2 = 0")
    error = fails(tmp_path, text)
    assert_located(error, key="axes.X.sim.inertia_kg_m2", line=line_of(text, "inertia_kg_m2"),
                   words=("out of range", "kg m^2"))
