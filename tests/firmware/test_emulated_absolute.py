"""Absolute encoders on the pins (call 49 kind 1): an AS5161-style PWM on channel A, read by
the PIO (firmware/src/rp2040/pwm_angle.pio) and made an angle by core1 (src/device/absenc.c);
and the step drives with the stepper outside the chip, closed through the pins' encoder.

- A DC axis knows its angle at power-up, before it moves, within the encoder's resolution
  (a count, or a 4096th of a turn where that is coarser), counts on across turns both ways
  (the turns counted by the angle's overflow) and follows a move.
- The encoder's PWM clock 10 % fast or slow changes no reading (high time over period).
- A silent encoder latches fault 5 within its timeout (ABSENC_TIMEOUT_US) and the axis stops;
  enabling again while it is silent latches it again; once the PWM is back it runs.
- A closed-loop stepper on the pins (the harness's StepperWorld), with a quadrature encoder
  and with an absolute one, follows a move, and a load beyond its torque is a following error
  (fault 2) at call 29's limit.
"""

from __future__ import annotations

import math
from collections.abc import Iterator

import pytest

from .emulated import require_emulator
from .pins import PinsChip

CPR = 1920
"""The default DC motor's encoder (call 16 at power-up)."""
CODES = 4096
TIMEOUT_MS = 5
"""ABSENC_TIMEOUT_US (firmware/src/device/absenc.h), in 1 ms ticks."""
DC_GAINS = "9 7 -3\n10 1 0\n11 0 0\n"
ABSOLUTE_GAINS = "9 4 -3\n10 1 0\n11 5 -3\n"
"""Gentler than the quadrature's (DC_GAINS): the angle comes once a frame (1.09 ms) and is a
frame old when it comes, so the loop sees the shaft up to two ticks late; DC_GAINS rings."""


@pytest.fixture(scope="module")
def chip() -> Iterator[PinsChip]:
    require_emulator()
    with PinsChip(pins=True) as pins_chip:
        yield pins_chip


def absolute_dc(chip: PinsChip, start_count: float, **absolute: float) -> None:
    """A DC motor with an absolute encoder at ``start_count`` on a freshly powered chip."""
    chip.request(cmd="motor", options={"startCount": start_count, "absolute": absolute})
    chip.request(cmd="power_cycle")


def true_angle(theta_counts: float, magnet_turns: float, turn: int) -> float:
    """Where the shaft is within a turn, counts."""
    turns = theta_counts / CPR + magnet_turns
    return (turns - math.floor(turns)) * turn


def position(chip: PinsChip) -> int:
    return chip.status()[1]


@pytest.mark.parametrize("start_count, magnet_turns", [
    (0.0, 0.0), (1234.3, 0.0), (-517.9, 0.25), (19_200.5, 0.8), (1919.99, 0.0),
])
def test_the_angle_is_known_at_power_up_before_the_axis_moves(
        chip: PinsChip, start_count: float, magnet_turns: float) -> None:
    absolute_dc(chip, start_count, magnetTurns=magnet_turns)
    assert chip.feed("49 1 0\n") == []
    chip.run(3)
    world = chip.request(cmd="world")["world"]
    assert world["theta"] == start_count and world["omega"] == 0, "it has not moved"
    got = position(chip)
    want = true_angle(start_count, magnet_turns, CPR)
    resolution = max(1.0, CPR / CODES)
    assert 0 <= want - got < resolution + 1e-9, (got, want)


@pytest.mark.parametrize("clock_scale", [0.9, 1.1])
def test_the_encoders_clock_off_by_ten_percent_changes_nothing(chip: PinsChip,
                                                               clock_scale: float) -> None:
    readings = []
    for scale in (1.0, clock_scale):
        absolute_dc(chip, 777.7, magnetTurns=0.1, clockScale=scale)
        chip.feed("49 1 0\n")
        chip.run(4)
        readings.append(position(chip))
    assert readings[0] == readings[1] == math.floor(
        math.floor(true_angle(777.7, 0.1, CPR) * CODES / CPR) * CPR / CODES)


def cosine(start: int, distance: int, ticks: int) -> list[int]:
    return [start + round(distance * (1 - math.cos(math.pi * k / ticks)) / 2)
            for k in range(1, ticks + 1)]


def follow(chip: PinsChip, positions: list[int], settle: int) -> list[str]:
    """Queue ``positions`` (one a tick) in batches and run them, then ``settle`` ticks."""
    lines: list[str] = []
    for start in range(0, len(positions), 500):
        batch = positions[start : start + 500]
        lines += chip.feed(f"1 {len(batch)} {' '.join(map(str, batch))}\n")
        if start == 0:
            lines += chip.feed("3 1\n")
        lines += chip.run(len(batch))
    return lines + chip.run(settle)


def errors(lines: list[str]) -> list[int]:
    return [int(line.split()[2]) - int(line.split()[3]) for line in lines if line.startswith("D ")]


def test_the_counter_counts_on_across_turns_both_ways_and_follows_a_move(chip: PinsChip) -> None:
    start, magnet = 300.4, 0.6
    absolute_dc(chip, start, magnetTurns=magnet)
    chip.feed("49 1 0\n")
    chip.run(3)
    here = position(chip)
    base = true_angle(start, magnet, CPR) - start   # counter = shaft + base
    chip.feed(ABSOLUTE_GAINS + "7 1\n29 1000\n21 1\n")
    up = cosine(here, 2 * CPR + 500, 2100)          # 2.26 turns up
    down = cosine(up[-1], -3 * CPR - 300, 2450)     # 3.16 turns down
    peaks = []
    for move in (up, down):
        lines = follow(chip, move, 150)
        assert not any(line.startswith("ALARM") for line in lines), lines[-5:]
        peaks.append(max(abs(e) for e in errors(lines)))
        got = position(chip)
        theta = chip.request(cmd="world")["world"]["theta"]
        assert abs(got - move[-1]) <= 4, (got, move[-1])
        assert 0 <= theta + base - got < 2, (theta + base, got)
    assert max(peaks) <= 25, peaks
    chip.feed("3 0\n21 0\n")
    # the query says where the turns begin, through a shift of the counter too (as homing
    # shifts it): the counter less `zero` is the shaft's angle within the turn
    for shift in (0, 1000, -7777):
        chip.feed(f"37 {shift}\n")
        zero = int(chip.feed("49 -1 0\n")[0].split()[3])
        got = position(chip)
        theta = chip.request(cmd="world")["world"]["theta"]
        angle = true_angle(theta, magnet, CPR)
        assert 0 <= angle - (got - zero) % CPR < 2, (angle, got, zero)


def test_a_silent_encoder_latches_fault_5_and_the_axis_stops(chip: PinsChip) -> None:
    absolute_dc(chip, 100.0)
    chip.feed("49 1 0\n")
    chip.run(3)
    here = position(chip)
    chip.feed(DC_GAINS + f"23 {here}\n0 1 {here}\n3 1\n")
    chip.run(20)
    chip.request(cmd="encoder_pwm", on=False)
    clock = chip.status()[0]
    lines = chip.run(TIMEOUT_MS + 3)
    alarms = [line for line in lines if line.startswith("ALARM")]
    assert len(alarms) == 1 and alarms[0].split()[1] == "5", lines
    assert clock < int(alarms[0].split()[2]) <= clock + TIMEOUT_MS + 2, (clock, alarms)
    status = chip.status()
    assert (status[5], status[8]) == (0, 5), "disabled, fault 5 latched"
    world = chip.request(cmd="world")["world"]
    assert world["voltage"] == 0 and world["enabled"] is False
    # enabled again while silent: the fault again, within the timeout
    chip.feed("30 0\n3 1\n")
    lines = chip.run(TIMEOUT_MS + 2)
    assert [line.split()[1] for line in lines if line.startswith("ALARM")] == ["5"], lines
    # the PWM back: the axis runs and holds where it stands
    chip.request(cmd="encoder_pwm", on=True)
    chip.run(3)
    chip.feed(f"30 0\n0 1 {position(chip)}\n3 1\n")
    lines = chip.run(50)
    assert not any(line.startswith("ALARM") for line in lines), lines
    assert chip.status()[5] == 1
    chip.feed("3 0\n")


STEPPER_SETUP = "5 1\n12 1\n46 100 20\n16 4000\n9 1 -1\n10 1 0\n11 2 -3\n44 2\n"
"""10 kHz, the TMC2209's timing, the world's 4000-count encoder, the closed loop's gains
(PROTOCOL.md, "Steppers")."""


def stepper_chip(chip: PinsChip, **options: object) -> None:
    chip.request(cmd="stepper", options={"countsPerRevolution": 4000, **options})
    chip.request(cmd="power_cycle")


@pytest.mark.parametrize("encoder", ["quadrature", "absolute"])
def test_a_closed_loop_stepper_on_the_pins_follows_a_move(chip: PinsChip, encoder: str) -> None:
    options = {"absolute": {"magnetTurns": 0.3}} if encoder == "absolute" else {}
    stepper_chip(chip, **options)
    chip.feed(STEPPER_SETUP + ("49 1 0\n" if encoder == "absolute" else ""))
    chip.run(30)
    here = position(chip)
    chip.feed(f"21 1\n29 400\n23 {here}\n")
    lines = follow(chip, cosine(here, 6400, 2000), 300)   # two turns in 0.2 s
    assert not any(line.startswith("ALARM") for line in lines), lines[-5:]
    peak = max(abs(e) for e in errors(lines))
    # the absolute angle comes once a frame, 11 ticks at 10 kHz, a frame late
    assert peak <= (60 if encoder == "quadrature" else 150), peak
    world = chip.request(cmd="world")["world"]
    # the absolute angle's staleness leaves the loop hunting about its end (measured: 51)
    assert abs(position(chip) - (here + 6400)) <= (16 if encoder == "quadrature" else 64)
    issued = int(chip.feed("48 -1\n")[0].split()[1])
    assert abs(world["field"] - issued) <= 4, "the driver took the steps (the last on their way)"
    chip.feed("3 0\n21 0\n")


@pytest.mark.parametrize("encoder", ["quadrature", "absolute"])
def test_a_load_beyond_the_steppers_torque_is_a_following_error(chip: PinsChip,
                                                                encoder: str) -> None:
    options = {"absolute": {}} if encoder == "absolute" else {}
    stepper_chip(chip, loadNm=1.0, **options)   # beyond its 0.59 N m
    chip.feed(STEPPER_SETUP + ("49 1 0\n" if encoder == "absolute" else ""))
    chip.run(30)
    here = position(chip)
    chip.feed(f"21 1\n29 400\n23 {here}\n")
    lines = follow(chip, cosine(here, 6400, 2000), 0)
    alarm = [line for line in lines if line.startswith("ALARM")]
    assert alarm and alarm[0].split()[1] == "2", lines[-5:]
    tick = int(alarm[0].split()[2])
    by_tick = {int(line.split()[1]): int(line.split()[2]) - int(line.split()[3])
               for line in lines if line.startswith("D ")}
    assert abs(by_tick[tick]) > 400 >= abs(by_tick[tick - 1]), (by_tick[tick - 1], by_tick[tick])
    world = chip.request(cmd="world")["world"]
    assert abs(world["theta"]) < 3200 / 200, "the load held the shaft"
    chip.feed("30 0\n")
