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
from usbmotion.session import home_position_mm
from usbmotion.sim.urls import URL_CHECKS

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
        load_config(path, url_checks=URL_CHECKS)
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
        if axis.name == "Z":  # CNC: Z homes up, machine Z runs negative below its switch
            assert axis.homing.direction == 1
            assert axis.homing.position_mm == axis.travel_mm[1] + 1.0, "1 mm above the travel"
        else:
            assert axis.homing.direction == -1
            assert axis.homing.position_mm == axis.travel_mm[0] - 1.0, "1 mm below the travel"
        assert home_position_mm(axis) == 0.0, "homing leaves every axis at machine 0"
        assert axis.homing.pull_off_mm == 1.0
        assert axis.homing.search_mm == 1.5 * (axis.travel_mm[1] - axis.travel_mm[0])
        assert axis.switch_margin_mm == 1.0
        assert axis.sim is not None
        lower, upper = axis.sim_travel_counts or (0, 0)
        assert lower < 0 < upper, "the carriage powers up between its switches"
        assert upper - lower == round((axis.travel_mm[1] - axis.travel_mm[0] + 2.0) * 240)
    assert config.axis("X").travel_mm == (0.0, 200.0)
    assert config.axis("Z").travel_mm == (-100.0, 0.0)


@pytest.mark.parametrize("path", [*sorted(EXAMPLES.glob("*.toml")),
                                  EXAMPLES.parent / "benchmarks" / "machine-10khz.toml"],
                         ids=lambda path: path.name)
def test_every_example_machine_homes_z_up_and_x_y_to_their_lower_ends(path: Path) -> None:
    """The CNC convention: Z's switch is at the top and machine Z runs negative below it
    (G53 G0 Z0 is the safe retract); X and Y run positive from their switches."""
    config = load_config(path, url_checks=URL_CHECKS)
    if config.joints:
        pytest.skip("a robot: its joints home to an end of their range, 0 in the middle")
    assert config.homing_order[0] == ("Z",) or "Z" not in config.axis_names
    for axis in config.axes:
        if axis.rotary:
            continue  # degrees: a rotary table homes where the file says
        low, high = axis.travel_mm
        up = axis.name == "Z"
        assert axis.homing.direction == (1 if up else -1), axis.name
        assert home_position_mm(axis) == (high if up else low) == 0.0, axis.name
        assert axis.homing.position_mm == (high + 1.0 if up else low - 1.0), axis.name
        if axis.sim is not None:
            assert low <= axis.sim.start_mm <= high
            lower, upper = axis.sim_travel_counts or (0, 0)
            assert lower < 0 < upper, "the carriage powers up between its switches"


def test_real_machine_example_loads_without_simulated_motors() -> None:
    config = load_config(EXAMPLES / "real-machine.toml")
    assert not config.is_simulated
    assert all(axis.sim is None for axis in config.axes)
    assert all(axis.device for axis in config.axes)
    x = config.axis("X")
    assert x.reach is not None
    assert (x.reach.velocity_mm_s, x.reach.accel_mm_s2) == (43.95, 2063.0)
    assert x.max_velocity_mm_s / 43.95 + x.max_accel_mm_s2 / 2063.0 <= 0.9
    assert config.axis("Y").reach is None


def test_the_packaged_default_machine_is_the_example() -> None:
    from usbmotion.cli.run import default_machine  # noqa: PLC0415

    assert default_machine().read_text() == (EXAMPLES / "machine.toml").read_text()


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
    assert x.homing.position_mm == -1.0, "pull_off_mm below the travel, by default"
    assert x.sim_travel_counts == (-24240, 24240)
    assert x.sim.counts_per_revolution == SIM_MOTOR_DEFAULTS["counts_per_revolution"]
    assert z.sim is None and z.sim_travel_counts is None
    assert z.homing.direction == 1
    assert z.homing.position_mm == 91.0
    assert z.switch_margin_mm == 1.0
    assert z.homing.slow_speed_mm_s == pytest.approx(0.5)
    assert z.following_error_limit_counts == 0
    assert config.homing_order == (("Z",), ("X",))


def test_a_home_switch_beyond_the_travel_moves_both_simulated_switches(tmp_path: Path) -> None:
    text = GOOD.replace("gains = { kp = 0.2, ki = 2, kd = 0.002 }",
                        "gains = { kp = 0.2, ki = 2, kd = 0.002 }\n"
                        "homing = { position_mm = -1.5, pull_off_mm = 2.0 }")
    x = load_config(write(tmp_path, text)).axis("X")
    assert x.homing.position_mm == -1.5
    assert x.switch_margin_mm == 1.5
    assert x.sim_travel_counts == (-24360, 24360)


@pytest.mark.parametrize(("homing", "words"), [
    ("homing = { position_mm = 0.0 }",
     ("axes.X.homing.position_mm: 0.0 puts the switch at the end of the working travel",
      "a move to 0 (G0 to the end, a CAM retract) closes it", "allowed: below 0, e.g. -1")),
    ("homing = { position_mm = -1.5 }",
     ("homing leaves the axis at -0.5 mm (the switch's position_mm -1.5 pulled off by"
      " pull_off_mm 1), outside travel_mm [0, 200]", "or a longer pull_off_mm")),
    ("homing = { pull_off_mm = 0 }", ("axes.X.homing.pull_off_mm", "0 is out of range")),
    ("homing = { search_mm = 5000 }", ("axes.X.homing.search_mm", "at most 10 x the travel")),
])
def test_a_switch_inside_the_travel_or_a_home_outside_it_is_refused(
        tmp_path: Path, homing: str, words: tuple[str, ...]) -> None:
    text = GOOD.replace("gains = { kp = 0.2, ki = 2, kd = 0.002 }",
                        f"gains = {{ kp = 0.2, ki = 2, kd = 0.002 }}\n{homing}")
    with pytest.raises(ConfigError) as caught:
        load_config(write(tmp_path, text))
    message = str(caught.value)
    for word in words:
        assert word in message, message
    assert f":{line_of(text, homing)}:" in message, "the line of the homing table"


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
         ("80 is out of range", "above travel_mm's highest end")),
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


# --- a misspelt key is named as unknown, with the closest known key -----------------------

AXIS_KEYS = ("counts_per_mm, device, encoder, encoder_counts_per_rev, following_error_limit_mm,"
             " gains, homing, kind,"
             " max_accel_mm_s2, max_jerk_mm_s3, max_velocity_mm_s, model, reach, sim,"
             " travel_mm, url, velocity_gains")
SIM_KEYS = ("counts_per_revolution, inertia_kg_m2, load_torque_mnm, magnet_angle_deg,"
            " probe_above_mm,"
            " probe_below_mm, source_voltage_v, start_mm, torque_constant_mnm_per_a,"
            " update_interval_dms, viscous_friction_unm_per_rad_s, winding_resistance_ohm")


@pytest.mark.parametrize(
    ("old", "new", "key", "problem"),
    [
        ("servo_interval_dms = 10", "servo_interval_ms = 10", "servo_interval_ms",
         "unknown key 'servo_interval_ms'; did you mean 'servo_interval_dms'? allowed keys here:"
         " arc_tolerance_mm, axes, dialect, homing_order, joints, junction_deviation_mm,"
         " motion_scalar, name, outputs, parameter_file, ports, reply_timeout_s,"
         " servo_interval_dms,"
         " spindle, tool_setter, tool_table, watchdog_ms"),
        ("max_accel_mm_s2 = 500", "max_acel_mm_s2 = 500", "axes.X.max_acel_mm_s2",
         "unknown key 'max_acel_mm_s2'; did you mean 'max_accel_mm_s2'? allowed keys here: "
         + AXIS_KEYS),
        ("counts_per_mm = 100.5", "Counts_Per_MM = 100.5", "axes.Z.Counts_Per_MM",
         "unknown key 'Counts_Per_MM'; did you mean 'counts_per_mm'? allowed keys here: "
         + AXIS_KEYS),
        ("kd = 0.002 }", "kdd = 0.002 }", "axes.X.gains.kdd",
         "unknown key 'kdd'; did you mean 'kd'? allowed keys here: kd, ki, kp"),
        ("[axes.Z.gains]", "[axes.Z.velocity_gains]\nkp = 0.001\nkii = 0.5\n[axes.Z.gains]",
         "axes.Z.velocity_gains.kii",
         "unknown key 'kii'; did you mean 'ki'? allowed keys here: kd, ki, kp"),
        ("speed_mm_s = 5", "sped_mm_s = 5", "axes.Z.homing.sped_mm_s",
         "unknown key 'sped_mm_s'; did you mean 'speed_mm_s'? allowed keys here: backoff_mm,"
         " declare, direction, position_mm, pull_off_mm, search_mm, slow_speed_mm_s, speed_mm_s"),
        ("travel_mm = [0, 200]", "travel_mm = [0, 200]\nsim = { inertia_kg_m = 1e-3 }",
         "axes.X.sim.inertia_kg_m",
         "unknown key 'inertia_kg_m'; did you mean 'inertia_kg_m2'? allowed keys here: "
         + SIM_KEYS),
        ("travel_mm = [0, 200]", "travel_mm = [0, 200]\nreach = { velocity_mm_s = 40,"
         " acel_mm_s2 = 900 }", "axes.X.reach.acel_mm_s2",
         "unknown key 'acel_mm_s2'; did you mean 'accel_mm_s2'? allowed keys here: accel_mm_s2,"
         " velocity_mm_s"),
        ("servo_interval_dms = 10", "servo_interval_dms = 10\ncolour = 'red'", "colour",
         "unknown key 'colour'; allowed keys here: arc_tolerance_mm, axes, dialect,"
         " homing_order, joints, junction_deviation_mm, motion_scalar, name, outputs,"
         " parameter_file, ports,"
         " reply_timeout_s, servo_interval_dms, spindle, tool_setter, tool_table, watchdog_ms"),
    ],
)
def test_a_misspelt_key_is_named_as_unknown_with_the_closest_key(
    tmp_path: Path, old: str, new: str, key: str, problem: str
) -> None:
    assert old in GOOD
    text = GOOD.replace(old, new, 1)
    error = fails(tmp_path, text)
    line = line_of(text, key.rsplit(".", 1)[-1] + " =")
    assert str(error) == f"{error.path}:{line}: {key}: {problem}"
    assert error.key == key
    assert error.line == line


def test_an_unknown_key_is_named_before_the_other_problems_of_its_table(tmp_path: Path) -> None:
    """A bad value read before the misspelt key, a missing required key: the typo comes first."""
    text = (GOOD.replace("counts_per_mm = 240", "counts_per_mm = -240")
            .replace("max_accel_mm_s2 = 500", "max_acel_mm_s2 = 500"))
    error = fails(tmp_path, text)
    assert error.key == "axes.X.max_acel_mm_s2"
    assert error.line == line_of(text, "max_acel_mm_s2")
    text = GOOD.replace("watchdog_ms = 0", "watchdog_ms = 0\nwatchdog = 5").replace(
        "max_accel_mm_s2 = 500", "max_accel_mm_s2 = -500")
    error = fails(tmp_path, text)
    assert error.key == "watchdog"
    assert "did you mean 'watchdog_ms'?" in str(error)


def test_a_lower_case_axis_letter_is_suggested_in_upper_case(tmp_path: Path) -> None:
    text = GOOD.replace("[axes.Z]", "[axes.z]").replace("[axes.Z.", "[axes.z.")
    error = fails(tmp_path, text)
    assert str(error) == (f"{error.path}:{line_of(text, '[axes.z]')}: axes.z: 'z' is not an"
                          " axis name (did you mean 'Z'?); allowed: X, Y, Z, A, B, C, U, V, W")


# --- limits the motor cannot reach ----------------------------------------------------------

DEFAULT_MOTOR = "the simulated motor (axes.X.sim's defaults)"
MARGIN = "(90% of it, so the PID keeps 10% of the supply to correct errors)"


def analytic_reach(*, load_torque_mnm: float = 50.0, inertia_kg_m2: float = 1.1e-3,
                   counts_per_mm: float = 240.0) -> tuple[float, float]:
    """No-load speed (mm/s) and acceleration from standstill (mm/s^2) of the default motor
    at 12 V, straight from the model's equation (PROTOCOL.md, "The simulated motor")."""
    import math  # noqa: PLC0415

    kt, resistance, volts, viscous = 0.3346, 2.182, 12.0, 500e-6
    drive = kt * volts / resistance - load_torque_mnm * 1e-3
    mm_per_rad = 1920 / (2 * math.pi) / counts_per_mm
    return (drive / (kt * kt / resistance + viscous) * mm_per_rad,
            drive / inertia_kg_m2 * mm_per_rad)


def test_the_default_machine_reach_is_the_motor_model_at_full_voltage() -> None:
    from usbmotion.host.config import REACH_MARGIN, simulated_reach  # noqa: PLC0415

    config = load_config(EXAMPLES / "machine.toml")
    x, z = config.axis("X"), config.axis("Z")
    assert x.sim is not None and z.sim is not None
    reach_x = simulated_reach(x.sim, x.counts_per_mm)
    reach_z = simulated_reach(z.sim, z.counts_per_mm)
    assert (reach_x.velocity_mm_s, reach_x.accel_mm_s2) == pytest.approx(analytic_reach())
    assert (reach_z.velocity_mm_s, reach_z.accel_mm_s2) == pytest.approx(
        analytic_reach(load_torque_mnm=80.0, inertia_kg_m2=1.5e-3))
    assert reach_x.velocity_mm_s == pytest.approx(43.99, abs=0.01)
    assert reach_x.accel_mm_s2 == pytest.approx(2072, abs=1)
    assert reach_x.accel_at_mm_s2(20.0) == pytest.approx(1130, abs=1)
    assert reach_z.velocity_mm_s == pytest.approx(43.26, abs=0.01)
    assert reach_z.accel_at_mm_s2(15.0) == pytest.approx(976, abs=1)
    assert REACH_MARGIN == 0.1
    for axis, reach in ((x, reach_x), (z, reach_z)):
        assert axis.max_velocity_mm_s <= reach.usable_velocity_mm_s
        assert axis.max_accel_mm_s2 <= reach.usable_accel_mm_s2(axis.max_velocity_mm_s)
        assert axis.reach is None


@pytest.mark.parametrize(
    ("old", "new", "key", "problem"),
    [
        ("max_velocity_mm_s = 25", "max_velocity_mm_s = 50", "axes.X.max_velocity_mm_s",
         f"50.0 mm/s is faster than the motor can go: its no-load speed at the full 12 V of"
         f" {DEFAULT_MOTOR} is 43.99 mm/s ((Kt V/R - T_load) / (Kt^2/R + b)); allowed:"
         f" <= 39.59 mm/s {MARGIN}"),
        ("max_velocity_mm_s = 25", "max_velocity_mm_s = 42", "axes.X.max_velocity_mm_s",
         f"42.0 mm/s leaves the PID less than 10% of the supply to correct errors: its no-load"
         f" speed at the full 12 V of {DEFAULT_MOTOR} is 43.99 mm/s ((Kt V/R - T_load) /"
         f" (Kt^2/R + b)); allowed: <= 39.59 mm/s {MARGIN}"),
        ("max_accel_mm_s2 = 500", "max_accel_mm_s2 = 1000", "axes.X.max_accel_mm_s2",
         f"1000.0 mm/s^2 is more than the motor can give at max_velocity_mm_s 25 mm/s: the"
         f" motor gives 894.6 mm/s^2 at the full 12 V of {DEFAULT_MOTOR} ((Kt (V - Kt w)/R -"
         " b w - T_load) / J at w = max_velocity_mm_s; 2072 mm/s^2 from standstill, 0 at the"
         " top speed 43.99 mm/s); allowed: <= 687.3 mm/s^2 (keeping 10% of the supply for the"
         " PID: 2072 x (0.9 - 25 / 43.99)), or a lower max_velocity_mm_s"),
        ("max_accel_mm_s2 = 500", "max_accel_mm_s2 = 800", "axes.X.max_accel_mm_s2",
         f"800.0 mm/s^2 leaves the PID less than 10% of the supply to correct errors at"
         f" max_velocity_mm_s 25 mm/s: the motor gives 894.6 mm/s^2 at the full 12 V of"
         f" {DEFAULT_MOTOR} ((Kt (V - Kt w)/R - b w - T_load) / J at w = max_velocity_mm_s;"
         " 2072 mm/s^2 from standstill, 0 at the top speed 43.99 mm/s); allowed: <= 687.3"
         " mm/s^2 (keeping 10% of the supply for the PID: 2072 x (0.9 - 25 / 43.99)), or a"
         " lower max_velocity_mm_s"),
        ("travel_mm = [0, 200]", "travel_mm = [0, 200]\n"
         "sim = { source_voltage_v = 6.0, inertia_kg_m2 = 2.2e-3 }", "axes.X.max_velocity_mm_s",
         "25.0 mm/s is faster than the motor can go: its no-load speed at the full 6 V of"
         " axes.X.sim is 21.38 mm/s ((Kt V/R - T_load) / (Kt^2/R + b)); allowed:"
         f" <= 19.24 mm/s {MARGIN}"),
        ("travel_mm = [0, 200]", "travel_mm = [0, 200]\nsim = { load_torque_mnm = 2000 }",
         "axes.X.max_velocity_mm_s",
         "25.0 mm/s cannot be reached: its no-load speed at the full 12 V of axes.X.sim is 0"
         " ((Kt V/R - T_load) / (Kt^2/R + b): the load torque is at least the stall torque"
         " Kt V/R); allowed: a motor that turns (a smaller load_torque_mnm or a larger"
         " source_voltage_v)"),
    ],
)
def test_a_limit_the_simulated_motor_cannot_reach_is_refused(
    tmp_path: Path, old: str, new: str, key: str, problem: str
) -> None:
    assert old in GOOD
    text = GOOD.replace(old, new, 1)
    error = fails(tmp_path, text)
    line = line_of(text, key.rsplit(".", 1)[-1] + " =")
    assert str(error) == f"{error.path}:{line}: {key}: {problem}"
    assert (error.key, error.line) == (key, line)


def test_the_reach_limits_load_up_to_the_margin_and_not_beyond(tmp_path: Path) -> None:
    """39.59 mm/s (with the acceleration left there) loads; a hundredth more does not."""
    from usbmotion.host.config import simulated_reach  # noqa: PLC0415

    fast = GOOD.replace("max_velocity_mm_s = 25", "max_velocity_mm_s = 39.59").replace(
        "max_accel_mm_s2 = 500", "max_accel_mm_s2 = 0.2")
    x = load_config(write(tmp_path, fast)).axis("X")
    assert x.sim is not None
    reach = simulated_reach(x.sim, x.counts_per_mm)
    assert 0.2 <= reach.usable_accel_mm_s2(39.59) < 0.21
    fails(tmp_path, fast.replace("max_velocity_mm_s = 39.59", "max_velocity_mm_s = 39.6"))
    fails(tmp_path, fast.replace("max_accel_mm_s2 = 0.2", "max_accel_mm_s2 = 0.21"))
    hard = GOOD.replace("max_accel_mm_s2 = 500", "max_accel_mm_s2 = 687.3")
    assert load_config(write(tmp_path, hard)).axis("X").max_accel_mm_s2 == 687.3
    fails(tmp_path, hard.replace("max_accel_mm_s2 = 687.3", "max_accel_mm_s2 = 687.5"))


MEASURED = "reach = { velocity_mm_s = 30.0, accel_mm_s2 = 1200.0 }"


def test_a_measured_reach_is_read_and_the_limits_are_checked_against_it(tmp_path: Path) -> None:
    text = GOOD.replace("following_error_limit_mm = 0", "following_error_limit_mm = 0\n"
                        + MEASURED)
    z = load_config(write(tmp_path, text)).axis("Z")
    assert z.sim is None and z.reach is not None
    assert (z.reach.velocity_mm_s, z.reach.accel_mm_s2) == (30.0, 1200.0)
    assert z.reach.accel_at_mm_s2(10.0) == pytest.approx(800.0)
    assert z.reach.usable_accel_mm_s2(10.0) == pytest.approx(680.0)
    assert load_config(write(tmp_path, GOOD)).axis("Z").reach is None


@pytest.mark.parametrize(
    ("old", "new", "key", "problem"),
    [
        ("max_velocity_mm_s = 10", "max_velocity_mm_s = 31", "axes.Z.max_velocity_mm_s",
         "31.0 mm/s is faster than the motor can go: its top speed measured by usbmotion tune"
         " --reach is 30 mm/s (axes.Z.reach.velocity_mm_s); allowed: <= 27 mm/s"
         f" {MARGIN}"),
        ("max_accel_mm_s2 = 200", "max_accel_mm_s2 = 700", "axes.Z.max_accel_mm_s2",
         "700.0 mm/s^2 leaves the PID less than 10% of the supply to correct errors at"
         " max_velocity_mm_s 10 mm/s: the motor gives 800 mm/s^2 by the reach that usbmotion"
         " tune --reach measured (axes.Z.reach, on a DC motor's straight torque-speed line;"
         " 1200 mm/s^2 from standstill, 0 at the top speed 30 mm/s); allowed: <= 680 mm/s^2"
         " (keeping 10% of the supply for the PID: 1200 x (0.9 - 10 / 30)), or a lower"
         " max_velocity_mm_s"),
        ("max_accel_mm_s2 = 200", "max_accel_mm_s2 = 900", "axes.Z.max_accel_mm_s2",
         "900.0 mm/s^2 is more than the motor can give at max_velocity_mm_s 10 mm/s"),
        (MEASURED, "reach = { velocity_mm_s = 30.0 }", "axes.Z.reach.accel_mm_s2",
         "missing required key 'accel_mm_s2'; allowed: a number > 0 and <= 1e+08 (mm/s^2, the"
         " acceleration from standstill it measured)"),
        (MEASURED, "reach = { velocity_mm_s = -30.0, accel_mm_s2 = 1200.0 }",
         "axes.Z.reach.velocity_mm_s",
         "-30.0 is out of range; allowed: a number > 0 and <= 100000 (mm/s, the top speed"
         " usbmotion tune --reach measured)"),
        (MEASURED, "reach = 30.0", "axes.Z.reach",
         "30.0 (float) is not a table; allowed: a table: velocity_mm_s, accel_mm_s2 (as"
         " usbmotion tune --reach prints)"),
    ],
)
def test_a_limit_above_a_measured_reach_is_refused(
    tmp_path: Path, old: str, new: str, key: str, problem: str
) -> None:
    base = GOOD.replace("following_error_limit_mm = 0", "following_error_limit_mm = 0\n"
                        + MEASURED)
    text = base.replace(old, new, 1)
    assert text != base
    error = fails(tmp_path, text)
    z_table = line_of(text, "[axes.Z]")
    name = "reach" if ".reach" in key else key.rsplit(".", 1)[-1]
    line = z_table + line_of("\n".join(text.splitlines()[z_table:]), name + " =")
    assert str(error).startswith(f"{error.path}:{line}: {key}: {problem}"), str(error)
    assert (error.key, error.line) == (key, line)


def test_a_simulated_axis_with_a_measured_reach_is_held_to_both(tmp_path: Path) -> None:
    """The model refuses what the measurement would allow, and the other way round."""
    generous = GOOD.replace("travel_mm = [0, 200]", "travel_mm = [0, 200]\n"
                            "reach = { velocity_mm_s = 100.0, accel_mm_s2 = 9000.0 }")
    error = fails(tmp_path, generous.replace("max_velocity_mm_s = 25", "max_velocity_mm_s = 42"))
    assert "its no-load speed at the full 12 V of" in str(error)
    stingy = GOOD.replace("travel_mm = [0, 200]", "travel_mm = [0, 200]\n"
                          "reach = { velocity_mm_s = 27.0, accel_mm_s2 = 9000.0 }")
    error = fails(tmp_path, stingy)
    assert error.key == "axes.X.max_velocity_mm_s"
    assert "its top speed measured by usbmotion tune --reach is 27 mm/s" in str(error)
