"""Every reply the device prints, to the letter: seed 000's strings, queries, debug lines."""

from __future__ import annotations

import struct
import zlib

import pytest

from usbmotion.device import Device
from usbmotion.protocol import CALLS, ReplyKind, parse_reply

from .helpers import send

# (setup lines, the line, what the device prints), straight from seed 000.
SEED_000 = [
    ([], "0 3910", []),
    (["8 0 1"], "0 3910", ["S0 3910"]),
    (["8 1 1"], "1 1 3928", ["S0 1 3928"]),
    (["8 1 1"], "1 3 4929 2904 103049", ["S0 3 4929 2904 103049"]),
    ([], "1 3 4929 2904 103049", []),
    (["8 3 1"], "3 1", ["SERVO ENABLE MODIFIED TO 1"]),
    (["8 3 1", "3 1"], "3 0", ["SERVO ENABLE MODIFIED TO 0"]),
    ([], "3 1", []),
    (["3 1"], "3 -1", ["SERVO_ENABLE 1"]),
    ([], "3 -1", ["SERVO_ENABLE 0"]),
    (["8 5 1"], "5 10", ["SERVO LOOP INTERVAL MODIFIED TO 1000 MICROSECONDS"]),
    (["8 5 1"], "5 1", ["SERVO LOOP INTERVAL MODIFIED TO 100 MICROSECONDS"]),
    ([], "5 -1", ["SERVO_UPDATE_INTERVAL_US 1000"]),
    (["5 1"], "5 -1", ["SERVO_UPDATE_INTERVAL_US 100"]),
    (["8 6 1"], "6 1000", ["MOTION UPDATE INTERVAL SCALAR MODIFIED TO 1000"]),
    (["6 1000"], "6 -1", ["MOTION_UPDATE_INTERVAL_SCALAR 1000"]),
    ([], "6 -1", ["MOTION_UPDATE_INTERVAL_SCALAR 1"]),
    (["8 7 1"], "7 2", ["Control Mode MODIFIED TO 2"]),
    (["7 2"], "7 -1", ["CONTROL_MODE 2"]),
    ([], "7 -1", ["CONTROL_MODE 1"]),
    (["8 0 1"], "8 0 -1", ["DEBUG_FLAG 0 1"]),
    ([], "8 0 -1", ["DEBUG_FLAG 0 0"]),
    (["8 0 2"], "0 5", []),
]


@pytest.mark.parametrize(("setup", "line", "expected"), SEED_000)
def test_seed_000_strings_to_the_letter(
    setup: list[str], line: str, expected: list[str]
) -> None:
    device = Device()
    send(device, *setup)
    assert send(device, line) == expected


POWER_UP_QUERIES = {
    "2 -1": "MOTION_QUEUE 0 1000",
    "39 -1": "MOTOR 0 0",
    "3 -1": "SERVO_ENABLE 0",
    "5 -1": "SERVO_UPDATE_INTERVAL_US 1000",
    "6 -1": "MOTION_UPDATE_INTERVAL_SCALAR 1",
    "7 -1": "CONTROL_MODE 1",
    "8 5 -1": "DEBUG_FLAG 5 0",
    "9 -1 0": "PROPORTIONAL_GAIN 1 0",
    "10 -1 0": "INTEGRAL_GAIN 1 0",
    "11 -1 0": "DERIVATIVE_GAIN 7 -3",
    "12 -1": "SIM_UPDATE_INTERVAL_DMS 10",
    "13 -1 0": "SIM_SOURCE_VOLTAGE 12 0",
    "14 -1 0": "SIM_TORQUE_CONSTANT 3346 -1",
    "15 -1 0": "SIM_WINDING_RESISTANCE 2182 -3",
    "16 -1": "SIM_COUNTS_PER_REVOLUTION 1920",
    "17 -1 0": "SIM_INERTIA 11 -4",
    "18 -1": "DEVICE_NAME GENERIC USB MOTION DEVICE",
    "19 -1": "DEFAULT_CONTROL_MODE 1",
    "20 -1": "STATUS 0 0 0 0 0 0 1 0 0",
    "21 -1": "DIAGNOSTICS_INTERVAL 0",
    "22 -1": "CLOCK 0",
    "24 -1": "LIMITS 0 0",
    "27 -1": "CURVE_BUFFER 8",
    "28 -1": "WATCHDOG_MS 0",
    "29 -1": "FOLLOWING_ERROR_LIMIT 0",
    "30 -1": "FAULT 0 0",
    "31 -1": "START_TICK -1",
    "32 -1 0": "SIM_VISCOUS_FRICTION 500 0",
    "33 -1 0": "SIM_LOAD_TORQUE 50 0",
    "34 -1 -1": "SIM_TRAVEL -2147483648 2147483647",
    "35 -1": "MOTION_STATS 0 0 0 0 -1",
    "36 1": "SWITCH_EDGE 1 0 0 0 0",
    "40 -1 0": "SIM_PROBE 0 0",
    "41 -1": "PROBE 0 0 0 0 0",
    "43 0": "OUTPUTS 0 0 0 0 0 -1",
    "44 -1": "DRIVE 0",
    "45 -1 0": "STEPPER 200 16",
    "46 -1 0": "STEP_TIMING 2000 1000",
    "47 -1 0 0": "SIM_STEPPER 590 20 760",
    "48 -1": "STEPS 0 0 249",
    "49 -1 0": "ENCODER 0 0 0",
}


def test_every_query_of_the_table_is_covered() -> None:
    queried = {int(line.split()[0]) for line in POWER_UP_QUERIES}
    assert queried == {spec.number for spec in CALLS if spec.query is not None}


@pytest.mark.parametrize(("line", "reply"), sorted(POWER_UP_QUERIES.items()))
def test_every_query_answers_its_template_at_power_up(line: str, reply: str) -> None:
    device = Device()
    assert send(device, line) == [reply]
    parsed = parse_reply(reply)
    assert parsed.kind is ReplyKind.QUERY
    assert parsed.call == int(line.split(maxsplit=1)[0])


# (set line, query line, query reply after the set)
SET_THEN_QUERY = [
    ("3 1", "3 -1", "SERVO_ENABLE 1"),
    ("5 25", "5 -1", "SERVO_UPDATE_INTERVAL_US 2500"),
    ("6 7", "6 -1", "MOTION_UPDATE_INTERVAL_SCALAR 7"),
    ("7 3", "7 -1", "CONTROL_MODE 3"),
    ("8 33 200", "8 33 -1", "DEBUG_FLAG 33 200"),
    ("9 15 -1", "9 -1 0", "PROPORTIONAL_GAIN 15 -1"),
    ("10 0 0", "10 -1 0", "INTEGRAL_GAIN 0 0"),
    ("11 999 -12", "11 -1 0", "DERIVATIVE_GAIN 999 -12"),
    ("12 3", "12 -1", "SIM_UPDATE_INTERVAL_DMS 3"),
    ("13 24 0", "13 -1 0", "SIM_SOURCE_VOLTAGE 24 0"),
    ("14 9999 6", "14 -1 0", "SIM_TORQUE_CONSTANT 9999 6"),
    ("15 1 -12", "15 -1 0", "SIM_WINDING_RESISTANCE 1 -12"),
    ("16 4000", "16 -1", "SIM_COUNTS_PER_REVOLUTION 4000"),
    ("17 5 -5", "17 -1 0", "SIM_INERTIA 5 -5"),
    ("18 3 65 66 67", "18 -1", "DEVICE_NAME ABC"),
    ("19 2", "19 -1", "DEFAULT_CONTROL_MODE 2"),
    ("39 0", "39 -1", "MOTOR 0 0"),
    ("21 50", "21 -1", "DIAGNOSTICS_INTERVAL 50"),
    ("23 -5", "20 -1", "STATUS 0 -5 -5 0 0 0 1 0 0"),
    ("28 250", "28 -1", "WATCHDOG_MS 250"),
    ("29 100", "29 -1", "FOLLOWING_ERROR_LIMIT 100"),
    ("31 2000", "31 -1", "START_TICK 2000"),
    ("32 1 -12", "32 -1 0", "SIM_VISCOUS_FRICTION 1 -12"),
    ("33 0 0", "33 -1 0", "SIM_LOAD_TORQUE 0 0"),
    ("34 -100 100", "34 -1 -1", "SIM_TRAVEL -100 100"),
    ("40 2 -7", "40 -1 0", "SIM_PROBE 2 -7"),
    ("40 1 0", "41 -1", "PROBE 1 0 0 0 0"),  # touching at once, and no edge
    ("42 3 250 9", "43 0", "OUTPUTS 0 0 0 0 1 -1"),
    ("42 1 1000 0", "43 1", "OUTPUTS 0 0 0 0 0 -1"),  # cleared before it applied
    ("0 42", "2 -1", "MOTION_QUEUE 1 999"),
    ("37 -12", "20 -1", "STATUS 0 -12 -12 0 0 0 1 0 0"),
    ("44 1", "44 -1", "DRIVE 1"),
    ("45 400 8", "45 -1 0", "STEPPER 400 8"),
    ("46 100 20", "48 -1", "STEPS 0 0 4807"),
    ("47 450 15 900", "47 -1 0 0", "SIM_STEPPER 450 15 900"),
    ("49 1 2000", "20 -1", "STATUS 0 80 80 0 0 0 1 0 0"),  # 2000 counts of a 1920 turn
    ("49 0 7", "49 -1 0", "ENCODER 0 7 0"),
]


@pytest.mark.parametrize(("set_line", "query", "reply"), SET_THEN_QUERY)
def test_a_set_value_is_queried_back(set_line: str, query: str, reply: str) -> None:
    device = Device()
    assert send(device, set_line) == []
    assert send(device, query) == [reply]


# (setup, the line with its debug flag 1 set, the debug line)
DEBUG_LINES = [
    ([], "0 -7", "S0 -7"),
    ([], "1 2 -1 2147483647", "S0 2 -1 2147483647"),
    ([], "3 1", "SERVO ENABLE MODIFIED TO 1"),
    ([], "4 0", "MOTION QUEUE CLEARED"),
    ([], "5 2", "SERVO LOOP INTERVAL MODIFIED TO 200 MICROSECONDS"),
    ([], "6 4", "MOTION UPDATE INTERVAL SCALAR MODIFIED TO 4"),
    ([], "7 1", "Control Mode MODIFIED TO 1"),
    ([], "9 2 -1", "PROPORTIONAL GAIN MODIFIED TO 2 -1"),
    ([], "10 5 0", "INTEGRAL GAIN MODIFIED TO 5 0"),
    ([], "11 8 -3", "DERIVATIVE GAIN MODIFIED TO 8 -3"),
    ([], "12 5", "SIM UPDATE INTERVAL MODIFIED TO 5 DMS"),
    ([], "13 12 0", "SIM SOURCE VOLTAGE MODIFIED TO 12 0"),
    ([], "14 3346 -1", "SIM TORQUE CONSTANT MODIFIED TO 3346 -1"),
    ([], "15 2182 -3", "SIM WINDING RESISTANCE MODIFIED TO 2182 -3"),
    ([], "16 1920", "SIM COUNTS PER REVOLUTION MODIFIED TO 1920"),
    ([], "17 11 -4", "SIM INERTIA MODIFIED TO 11 -4"),
    ([], "18 2 88 49", "DEVICE NAME MODIFIED TO X1"),
    (["18 2 88 49"], "18 0", "DEVICE NAME MODIFIED TO GENERIC USB MOTION DEVICE"),
    ([], "19 3", "DEFAULT CONTROL MODE MODIFIED TO 3"),
    ([], "21 10", "DIAGNOSTICS INTERVAL MODIFIED TO 10"),
    ([], "22 0", "CLOCK ZEROED"),
    ([], "23 1234", "POSITION SET TO 1234"),
    (["7 3"], "25 100 500 1024 -1024", "KEYFRAME 100 500 1024 -1024"),
    ([], "26 0", "KEYFRAMES CLEARED"),
    ([], "28 100", "WATCHDOG MODIFIED TO 100 MS"),
    ([], "29 50", "FOLLOWING ERROR LIMIT MODIFIED TO 50"),
    ([], "30 0", "FAULT CLEARED"),
    ([], "31 77", "START TICK MODIFIED TO 77"),
    ([], "32 500 0", "SIM VISCOUS FRICTION MODIFIED TO 500 0"),
    ([], "33 25 0", "SIM LOAD TORQUE MODIFIED TO 25 0"),
    ([], "34 -10 10", "SIM TRAVEL MODIFIED TO -10 10"),
    ([], "35 0", "MOTION STATS RESET"),
    ([], "37 -3", "POSITION SHIFTED BY -3"),
    ([], "38 0 2 5 -5", "REPLACED 0 0 2 CRC 2082170553"),
    ([], "50 0 2 5 -5", "STOPPED 0 0 2 0 CRC 2082170553"),
    ([], "39 1", "MOTOR MODIFIED TO 1"),
    ([], "40 2 -250", "SIM PROBE MODIFIED TO 2 -250"),
    (["43 1"], "42 0 1000 7", "OUTPUT 0 TO 1000 AT 7 FREE 15"),
    ([], "44 2", "DRIVE MODIFIED TO 2"),
    ([], "45 400 8", "STEPPER MODIFIED TO 400 8"),
    ([], "46 100 20", "STEP TIMING MODIFIED TO 100 20"),
    ([], "47 450 15 900", "SIM STEPPER MODIFIED TO 450 15 900"),
    ([], "49 1 100", "ENCODER MODIFIED TO 1 100"),
]


def test_every_debug_template_is_covered() -> None:
    covered = {int(line.split()[0]) for _, line, _ in DEBUG_LINES}
    assert covered == {spec.number for spec in CALLS if spec.debug}


@pytest.mark.parametrize(("setup", "line", "expected"), DEBUG_LINES)
def test_every_debug_line_with_flag_1(setup: list[str], line: str, expected: str) -> None:
    device = Device()
    send(device, *setup)
    number = int(line.split(maxsplit=1)[0])
    assert send(device, line) == [], "quiet while the flag is 0"
    send(device, *setup)
    send(device, f"8 {number} 1")
    assert send(device, line) == [expected]
    parsed = parse_reply(expected)
    assert (parsed.kind, parsed.call) == (ReplyKind.DEBUG, number)
    send(device, f"8 {number} 9")
    send(device, *setup)
    assert send(device, line) == [], "an undefined flag value acts as 0"


def test_a_query_prints_no_debug_line() -> None:
    device = Device()
    send(device, "8 3 1", "8 5 1")
    assert send(device, "3 -1", "5 -1") == ["SERVO_ENABLE 0", "SERVO_UPDATE_INTERVAL_US 1000"]


def test_replies_come_in_the_order_of_the_lines() -> None:
    device = Device()
    lines = send(device, "8 0 1", "0 1", "2 -1", "0 2", "2 -1", "22 -1")
    assert lines == ["S0 1", "MOTION_QUEUE 1 999", "S0 2", "MOTION_QUEUE 2 998", "CLOCK 0"]


def test_lines_may_arrive_in_any_split() -> None:
    whole = b"8 0 1\n0 3910\r\n\n  \n1 2 5 6\n2 -1\n"
    reference = Device()
    reference.feed(whole)
    expected = reference.take_output()
    for size in (1, 2, 3, 7, len(whole)):
        device = Device()
        for start in range(0, len(whole), size):
            device.feed(whole[start : start + size])
        assert device.take_output() == expected
    assert expected == b"S0 3910\nMOTION_QUEUE 3 997\n"


def test_status_reports_the_servo() -> None:
    device = Device()
    send(device, "3 1", "0 500")
    device.run(300)
    status = send(device, "20 -1")[0].split()
    assert status[0] == "STATUS"
    clock, actual, desired, velocity, queued, enable, mode, limits, fault = map(int, status[1:])
    assert (clock, desired, queued, enable, mode, limits, fault) == (300, 500, 0, 1, 1, 0, 0)
    assert abs(actual - 500) <= 2
    assert velocity == 0


def test_a_batch_is_acknowledged_by_its_crc_with_flag_2() -> None:
    device = Device()
    expected = zlib.crc32(struct.pack("<3i", -1, 2147483647, -2147483648))
    assert send(device, "8 1 2", "1 3 -1 2147483647 -2147483648") == [f"ADDED 3 CRC {expected}"]
    assert send(device, "8 1 0", "1 1 5") == [], "flag 0: no line"
    assert send(device, "8 1 7", "1 1 5") == [], "an undefined flag acts as 0"


def test_the_crc_covers_a_batch_that_wraps_around_the_queue_ring() -> None:
    device = Device()
    send(device, "3 1", "1 700 " + " ".join(["5"] * 700))
    device.run(600)
    values = list(range(-250, 250))
    expected = zlib.crc32(struct.pack(f"<{len(values)}i", *values))
    lines = send(device, "8 1 2", f"1 {len(values)} " + " ".join(map(str, values)), "2 -1")
    assert lines == [f"ADDED 500 CRC {expected}", "MOTION_QUEUE 600 400"]
