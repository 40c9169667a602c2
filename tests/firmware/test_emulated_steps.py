"""The step/direction drives (call 44) on the emulated chip's pins: STEP, DIR and EN.

A move in each step drive (open loop, and closed loop on the on-chip simulated stepper),
with the TMC2209's timing (call 46 100 20) and the power-up one (2000 1000), at 10 kHz and
at 1 kHz, on the simulated motor (call 39 0; with the motor on the pins the stepper is
outside the chip, its tick completed one behind, test_emulated_absolute.py): every tick's
rising edges of STEP are the steps the Python device issued on that tick (its diagnostics
line), in number and direction; every pulse is high for the pulse and low
at least as long; a rise comes at least the set-up after DIR changed; a tick's pulses end
before the next tick starts; every rise lands on its ideal time (the step generator's
schedule in whole periods, ``tests/firmware/steps.py``: ideal_rises). The driver's enable
(active low) is low only while the servo runs enabled. A stepper outside the chip (the
harness's StepperWorld) takes every step and follows.

The test of the test: the same check catches one pulse missing from every tick, and, on the
chip itself, a set-up and a pulse made a period too short (the step generator's words changed
in core1's memory while the drive runs).
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Sequence
from dataclasses import dataclass

import pytest

from .emulated import require_emulator
from .pins import PinsChip
from .sessions import Feed, Run, Step, lines, python_replay
from .steps import (
    CYCLE_NS,
    DIR_PIN,
    ENABLE_PIN,
    STEP_PIN,
    PulseReport,
    StepTiming,
    capture,
    check_pulses,
    frames_of,
    issued_by_tick,
)


@dataclass(frozen=True, slots=True)
class Case:
    drive: int
    pulse_ns: int
    setup_ns: int
    interval_dms: int
    motor: int
    ticks: int


def _wave(ticks: int, peak: int) -> list[int]:
    """Positions of a move out and back: the velocity a sine of ``peak`` steps a tick (above
    the most a tick issues, so the drive saturates), the second half reversed."""
    position = 0.0
    out: list[int] = []
    for k in range(1, ticks + 1):
        position += peak * math.sin(2 * math.pi * k / ticks)
        out.append(round(position))
    return out


def session(case: Case) -> list[Step]:
    """The move: the timing and the drive set, a diagnostics line every tick, the positions
    queued (one a tick), the servo enabled for the move and a few ticks more, disabled."""
    timing = StepTiming.of(case.pulse_ns, case.setup_ns, case.interval_dms * 100)
    # open loop: beyond what a tick can issue; closed loop: within what the simulated stepper
    # follows (its corner speed, 760 rpm: 40,533 microsteps/s)
    peak = timing.max_per_tick * 5 // 4 if case.drive == 1 else 3 * case.interval_dms
    positions = _wave(case.ticks, peak)
    steps: list[Step] = [lines(f"5 {case.interval_dms}", f"46 {case.pulse_ns} {case.setup_ns}",
                               f"44 {case.drive}", "21 1")]
    for start in range(0, len(positions), 500):
        batch = positions[start : start + 500]
        steps.append(lines(f"1 {len(batch)} {' '.join(map(str, batch))}"))
        if start == 0:
            steps.append(lines("3 1"))
        steps.append(Run(len(batch)))
    steps += [Run(40), lines("3 0"), Run(3), lines("48 -1")]
    return steps


def play(chip: PinsChip, steps: Sequence[Step]) -> list[tuple[int, str]]:
    printed: list[tuple[int, str]] = []
    for step in steps:
        if isinstance(step, Feed):
            reply = chip.request(cmd="feed", data=step.data.decode("latin-1"))
        else:
            assert isinstance(step, Run)
            reply = chip.request(cmd="run", ticks=step.ticks)
        printed += PinsChip.lines(reply)
    return printed


def _python(steps: Sequence[Step]) -> list[tuple[int, str]]:
    return [(tick, line.decode("ascii")) for tick, line in python_replay(steps)]


@pytest.fixture(scope="module")
def chips() -> Iterator[dict[int, PinsChip]]:
    """A chip on each motor (call 39 0 and 1), blank flash but for that."""
    require_emulator()
    with PinsChip(pins=False) as simulated, PinsChip(pins=True) as pins:
        yield {0: simulated, 1: pins}


def run_case(chips: dict[int, PinsChip], case: Case) -> tuple[PulseReport, list[str]]:
    """The move on a fresh chip (of ``case.motor``) and on the Python device: the check's
    report and the chip's lines."""
    chip = chips[case.motor]
    chip.request(cmd="power_cycle", erase_flash=case.motor == 0)
    chip.request(cmd="capture", pins=[STEP_PIN, DIR_PIN])
    steps = session(case)
    printed = play(chip, steps)
    edges, flags = capture(chip.request(cmd="capture"))
    python = _python(steps)
    diagnostics = [entry for entry in printed if entry[1].startswith("D ")]
    assert diagnostics == [entry for entry in python if entry[1].startswith("D ")], (
        "the chip's diagnostics lines differ from the Python device's")
    issued = issued_by_tick(python)
    timing = StepTiming.of(case.pulse_ns, case.setup_ns, case.interval_dms * 100)
    report = check_pulses(edges, flags, issued, timing)
    (last,) = [line for _, line in printed if line.startswith("STEPS ")]
    assert report.net_steps == int(last.split()[1]), (last, report)
    assert report.steps == sum(abs(steps) for steps in issued.values())
    return report, [line for _, line in printed]


CASES = {
    "open loop, TMC2209 timing, 10 kHz": Case(1, 100, 20, 1, 0, 400),
    "open loop, power-up timing, 10 kHz": Case(1, 2000, 1000, 1, 0, 300),
    "open loop, power-up timing, 1 kHz": Case(1, 2000, 1000, 10, 0, 120),
    "closed loop, TMC2209 timing, 10 kHz": Case(2, 100, 20, 1, 0, 400),
    "closed loop, power-up timing, 1 kHz": Case(2, 2000, 1000, 10, 0, 150),
}


@pytest.mark.parametrize("name", list(CASES))
def test_every_ticks_steps_come_out_on_the_pins_in_time(chips: dict[int, PinsChip],
                                                        name: str) -> None:
    case = CASES[name]
    report, _ = run_case(chips, case)
    timing = StepTiming.of(case.pulse_ns, case.setup_ns, case.interval_dms * 100)
    assert report.direction_changes >= 1
    assert report.min_high_ns == timing.pulse * CYCLE_NS
    if case.drive == 1:
        assert report.busiest == timing.max_per_tick, "the move saturates the drive"
    assert report.max_jitter_ns == 0


def test_the_drivers_enable_is_low_only_while_the_servo_runs(chips: dict[int, PinsChip]) -> None:
    chip = chips[0]
    chip.request(cmd="power_cycle", erase_flash=True)

    def enable_level() -> int:
        (level,) = chip.request(cmd="levels", pins=[ENABLE_PIN])["levels"]
        return int(level)

    assert enable_level() == 1, "EN high (the driver off) from power-up"
    chip.feed("44 1\n")
    chip.run(2)
    assert enable_level() == 1
    chip.feed("3 1\n")
    chip.run(2)
    assert enable_level() == 0, "EN low while the servo runs enabled"
    chip.feed("3 0\n")
    chip.run(2)
    assert enable_level() == 1


def test_the_check_catches_a_dropped_pulse(chips: dict[int, PinsChip]) -> None:
    case = Case(1, 100, 20, 1, 0, 60)
    chip = chips[0]
    chip.request(cmd="power_cycle", erase_flash=True)
    chip.request(cmd="capture", pins=[STEP_PIN, DIR_PIN])
    steps = session(case)
    play(chip, steps)
    edges, flags = capture(chip.request(cmd="capture"))
    issued = issued_by_tick(_python(steps))
    timing = StepTiming.of(case.pulse_ns, case.setup_ns, case.interval_dms * 100)
    check_pulses(edges, flags, issued, timing)
    # the last pulse of every tick taken away
    dropped: set[int] = set()
    for frame in frames_of(edges, flags):
        if frame.rises:
            dropped.add(frame.rises[-1])
    last_rise = 0
    kept = []
    for edge in sorted(edges, key=lambda e: e[2]):
        if edge[0] == STEP_PIN and edge[1] == 1:
            last_rise = edge[2]
        if edge[0] == STEP_PIN and last_rise in dropped:
            continue
        kept.append(edge)
    with pytest.raises(AssertionError, match="rising edges of STEP for the"):
        check_pulses(kept, flags, issued, timing)


@pytest.mark.parametrize(("change", "rule"), [(1 << 16, "after DIR changed, under the set-up"),
                                               (1, "a STEP pulse high for")])
def test_the_check_catches_a_short_set_up_or_pulse_on_the_chip(chips: dict[int, PinsChip],
                                                              change: int, rule: str) -> None:
    """core1's frame word of the pulse and the set-up ((pulse - 2) | (setup - 2) << 16)
    changed on the running chip, the set-up or the pulse a period shorter: the PIO then puts
    that on the pins, and the check says so."""
    case = Case(1, 100, 80, 1, 0, 60)
    chip = chips[0]
    chip.request(cmd="power_cycle", erase_flash=True)
    chip.request(cmd="capture", pins=[STEP_PIN, DIR_PIN])
    steps = session(case)
    play(chip, steps[:1])   # the timing and the drive: the words are computed on the next tick
    chip.run(1)
    offset = 16  # step_frames_t: tick, room, most, head, timing_words[0]
    word = bytes.fromhex(chip.request(cmd="read", symbol="frames")["hex"])[offset : offset + 4]
    value = int.from_bytes(word, "little")
    assert value == (13 - 2) | (10 - 2) << 16, hex(value)
    chip.request(cmd="write", symbol="frames", offset=offset,
                 hex=(value - change).to_bytes(4, "little").hex())
    play(chip, steps[1:])
    edges, flags = capture(chip.request(cmd="capture"))
    issued = {tick + 1: steps for tick, steps in issued_by_tick(_python(steps)).items()}
    timing = StepTiming.of(case.pulse_ns, case.setup_ns, case.interval_dms * 100)
    with pytest.raises(AssertionError, match=rule):
        check_pulses(edges, flags, issued, timing)


def test_a_stepper_outside_the_chip_follows_the_step_pins(chips: dict[int, PinsChip]) -> None:
    """The harness's stepper world (lib/pins.js StepperWorld: a NEMA 17 on a step/direction
    driver, its rotor integrated from the STEP and DIR edges while EN is low, its encoder on
    the decoder's pins) after an open-loop move out and back: its driver took every step the
    chip issued, and the rotor stands within a full step of them, its encoder's count the
    rotor's."""
    chip = chips[0]
    chip.request(cmd="power_cycle", erase_flash=True)
    start = chip.request(cmd="stepper", options={"countsPerRevolution": 4000})["world"]
    assert start["powered"] is False, "EN high from power-up: the driver off"
    chip.feed("5 1\n46 100 20\n17 1 -5\n44 1\n")
    positions = _wave(600, 12)   # up to 12 microsteps a tick: 120,000 microsteps/s
    chip.feed(f"1 {len(positions)} {' '.join(map(str, positions))}\n")
    chip.feed("3 1\n")
    chip.run(len(positions) // 2)
    halfway = chip.request(cmd="world")["world"]
    assert halfway["powered"] is True
    chip.run(len(positions) // 2 + 200)
    (line,) = chip.feed("48 -1\n")
    issued = int(line.split()[1])
    world = chip.request(cmd="world")["world"]
    assert world["field"] == issued and world["steps"] >= 2 * halfway["field"] > 0, (world, line)
    assert abs(world["theta"] - issued) < 16, world
    assert world["count"] == math.floor(world["theta"] * 4000 / 3200), world
