"""The firmware with the motor on its pins (call 39), the motor outside the emulated chip.

- Call 39 is stored in flash and takes effect at the next power-up; the Python device gives
  the same answers (and keeps simulating).
- The PIO quadrature decoder counts every edge exactly over a sweep of rates up to its
  stated maximum (QUADRATURE_MAX_COUNTS_PER_S, firmware/src/rp2040/motor_pins.c), both ways;
  the test of the test: an edge the decoder cannot see, and a rate above the maximum, are
  both caught by the same comparison.
- Closed loop through the pins (PWM to the bridge, the encoder, the switches) on a motor
  with the on-chip simulated motor's model and constants: a step, a move and its return, and
  a homing (velocity mode onto the lower switch, the edge latch, the shift to machine zero)
  follow as on the on-chip motor, their following errors within FOLLOWING_BOUND_COUNTS of
  it at every tick.
- An open-loop step drive (call 44) on a chip whose motor is on its pins counts its steps,
  line for line as the Python device, and call 44 0 gives the axis back to the pins.
"""

from __future__ import annotations

import itertools
import math
import re
from collections.abc import Iterator

import pytest

from usbmotion.device import Device
from usbmotion.sim.firmware import PinsMotor, emulator_dir

from .emulated import require_emulator
from .pins import PinsChip
from .test_native_device import STEPPER, ramp

QUADRATURE_MAX_COUNTS_PER_S = 10_400_000
"""Two edges more than 12 PIO cycles (96 ns at 125 MHz) apart are both counted."""

FOLLOWING_BOUND_COUNTS = 3
"""The pins' quantisation, in counts of following error at any tick (firmware/README.md,
"The motor on the pins"). The count is the same integer on both, read as the tick starts
instead of computed after the motor's step (which changes when it is read, not its value);
the bridge's voltage is the output truncated to one of 6,250 duty steps (up to 1.9 mV less
at 12 V), and the motor outside integrates in binary64 where the on-chip one rounds each
product to four digits. Each moves the shaft by far less than a count, but where the two
shafts straddle a count boundary the counts differ by one, and the PID answers that count
at once (Kp 1 V, and Kd over the 1 ms window 7 V for one tick): the two loops then part by
a count or two for a few ticks until both settle again. Three counts bounds that, at any
tick of a move near the motor's top speed."""


@pytest.fixture(scope="module")
def pins_chip() -> Iterator[PinsChip]:
    require_emulator()
    with PinsChip(pins=True) as chip:
        yield chip


def test_call_39_is_kept_in_flash_and_runs_at_power_up() -> None:
    require_emulator()
    python = Device()
    with PinsChip(pins=False) as chip:
        for line in ("39 -1", "8 39 1", "39 1", "39 -1", "39 2", "39"):
            python.feed(line.encode("ascii") + b"\n")
            assert chip.feed(line + "\n") == python.take_output().decode("ascii").splitlines()
        assert chip.feed("39 -1\n") == ["MOTOR 1 0"]
        chip.request(cmd="power_cycle")
        assert chip.feed("39 -1\n") == ["MOTOR 1 1"]
        chip.feed("39 0\n")
        chip.request(cmd="power_cycle")
        assert chip.feed("39 -1\n") == ["MOTOR 0 0"]


def unclocked(line: str) -> str:
    """A STATUS line without its clock: on the pins a tick completes as the next starts, so
    the clock counts one behind the alarms (firmware/README.md, "The tick")."""
    return " ".join(line.split()[:1] + line.split()[2:]) if line.startswith("STATUS") else line


def test_an_open_loop_step_drive_with_the_motor_on_the_pins_counts_its_steps() -> None:
    """A step drive on a chip whose motor is on its pins issues its steps on STEP/DIR/EN and,
    open loop, counts them, exactly as the Python device (nothing outside the chip: the
    switches read open, as the Python device's travel does within it); back in the DC drive
    the counter starts at 0 where the motor on the pins stands. (A closed loop there reads
    the stepper outside the chip: test_emulated_absolute.py.)"""
    require_emulator()
    python = Device()
    session = [
        [*STEPPER, "44 1", "21 25", "3 1", ramp(0, 3200, 160)], 220,
        ["20 -1", "48 -1", "3 0", "3 1", ramp(3200, -1600, 80)], 120,
        ["20 -1", "48 -1"],
    ]
    with PinsChip(pins=True) as chip:
        for step in session:
            if isinstance(step, int):
                python.run(step)
                got = chip.run(step)
            else:
                text = "".join(line + "\n" for line in step)
                python.feed(text.encode("ascii"))
                got = chip.feed(text)
            want = python.take_output().decode("ascii").splitlines()
            assert [unclocked(line) for line in got] == [unclocked(line) for line in want]
        chip.feed("3 0\n44 0\n")
        assert chip.status()[1] == 0 and chip.feed("48 -1\n") == ["STEPS 0 0 249"]


def sweep_total(chip: PinsChip, counts: int, rate: float, skip: tuple[int, ...] = ()) -> int:
    """The counter's change over a sweep of ``counts`` at ``rate`` counts/s."""
    before = chip.status()[1]
    chip.request(cmd="sweep", counts=counts, counts_per_s=rate, skip=list(skip))
    chip.run(2)
    return chip.status()[1] - before


@pytest.mark.parametrize("rate", [100, 10_000, 200_000, 1_000_000, 4_000_000, 8_000_000,
                                  QUADRATURE_MAX_COUNTS_PER_S])
def test_the_decoder_counts_every_edge_up_to_its_maximum(pins_chip: PinsChip,
                                                         rate: int) -> None:
    counts = min(4001, max(41, rate // 100))
    assert sweep_total(pins_chip, counts, rate) == counts
    assert sweep_total(pins_chip, -counts, rate) == -counts


def test_the_sweep_catches_a_missed_edge(pins_chip: PinsChip) -> None:
    # the same comparison as above, on edges the decoder cannot have counted
    assert sweep_total(pins_chip, 1000, 1_000_000, skip=(500,)) != 1000
    assert sweep_total(pins_chip, 1000, 2 * QUADRATURE_MAX_COUNTS_PER_S) != 1000


SETUP = "21 1\n"


def following_errors(lines: list[str]) -> dict[int, int]:
    """desired - actual of every diagnostics line, by its clock."""
    errors: dict[int, int] = {}
    for line in lines:
        if line.startswith("D "):
            clock, desired, actual = (int(word) for word in line.split()[1:4])
            errors[clock] = desired - actual
    return errors


def motion(chip: PinsChip, positions: list[int], ticks: int) -> dict[int, int]:
    """Queue ``positions`` (one per tick), enable, run ``ticks``: the following errors."""
    lines = chip.feed(SETUP + "23 0\n")
    for start in range(0, len(positions), 500):
        batch = positions[start : start + 500]
        lines += chip.feed(f"1 {len(batch)} {' '.join(map(str, batch))}\n")
        if start == 0:
            lines += chip.feed("3 1\n")
        lines += chip.run(min(500, ticks))
        ticks -= min(500, ticks)
    lines += chip.run(ticks)
    lines += chip.feed("3 0\n21 0\n")
    return following_errors(lines)


def move_profile(distance: int, ticks: int) -> list[int]:
    """A smooth (cosine) move of ``distance`` counts over ``ticks`` ticks, and back."""
    there = [round(distance * (1 - math.cos(math.pi * k / ticks)) / 2) for k in range(ticks)]
    return there + [distance] * 200 + [distance - p for p in there] + [0] * 200


@pytest.mark.parametrize("name, positions, ticks", [
    ("step", [1000] * 400, 400),
    ("move", move_profile(3000, 600), 1700),
])
def test_closed_loop_through_the_pins_follows_as_the_on_chip_motor(
        name: str, positions: list[int], ticks: int) -> None:
    require_emulator()
    with PinsChip(pins=False) as simulated, PinsChip(pins=True) as outside:
        outside.request(cmd="motor", options={})
        on_chip = motion(simulated, positions, ticks)
        pins = motion(outside, positions, ticks)
    common = sorted(set(on_chip) & set(pins))
    assert len(common) >= ticks - 2
    worst = max(abs(pins[c] - on_chip[c]) for c in common)
    peak_on_chip = max(abs(on_chip[c]) for c in common)
    peak_pins = max(abs(pins[c]) for c in common)
    print(f"{name}: worst difference {worst} counts over {len(common)} ticks; peak following"
          f" error {peak_on_chip} on chip, {peak_pins} through the pins")
    differences = [pins[c] - on_chip[c] for c in common]
    print(f"{name}: ticks by difference",
          {d: differences.count(d) for d in sorted(set(differences))})
    assert worst <= FOLLOWING_BOUND_COUNTS


def homing(chip: PinsChip) -> tuple[list[int], list[int]]:
    """Velocity mode onto the lower switch at -2000 counts/s, as usbmotion homes: the latch,
    the shift that puts the edge at machine zero, the status after it."""
    chip.feed("9 7 -3\n10 1 0\n11 0 0\n7 2\n3 1\n")
    for _ in range(40):
        chip.feed("1 50 " + " ".join(["-2000"] * 50) + "\n")
        chip.run(50)
        edge = [int(w) for w in chip.feed("36 1\n")[0].split()[1:]]
        if edge[1] > 0:
            break
    chip.feed("3 0\n")
    chip.run(300)
    chip.feed(f"37 {-edge[3]}\n")
    return edge, chip.status()


def test_homing_through_the_pins_latches_the_edge_at_the_switch() -> None:
    require_emulator()
    lower = -1500
    with PinsChip(pins=False) as simulated, PinsChip(pins=True) as outside:
        simulated.feed(f"34 {lower} 100000\n")
        outside.request(cmd="motor", options={"lower": lower, "upper": 100000})
        edge_on_chip, status_on_chip = homing(simulated)
        edge_pins, status_pins = homing(outside)
        world = outside.request(cmd="world")["world"]
    print(f"homing: edge latched at {edge_pins[3]} through the pins, {edge_on_chip[3]} on"
          f" chip; the switch at {lower}; after the shift {status_pins[1]} and"
          f" {status_on_chip[1]}")
    assert edge_pins[1] == 1 and edge_pins[2] == 1
    # the pins latch the count the instant the switch closed: the switch's own count
    assert edge_pins[3] == lower
    # the on-chip motor latches at the tick after it (2 counts a tick at 2000 counts/s)
    assert lower - 2 <= edge_on_chip[3] <= lower
    # machine zero exactly at the switch: the counter after the shift is where the shaft
    # rests, counted from the switch
    assert status_pins[1] == world["count"] - lower
    # where each axis rests: velocity mode integrates its small differences of speed into
    # position (no position loop), so only roughly alike
    assert abs(status_pins[1] - status_on_chip[1]) <= 20


DEBOUNCE_US = 1000
"""USBMOTION_SWITCH_DEBOUNCE_US (firmware/src/rp2040/pins.h): after an edge a switch is
ignored this long."""


def onto_bouncing_switch(chip: PinsChip, lower: int, *, bounces: int,
                         interval_us: float) -> tuple[list[int], dict[str, object]]:
    """Velocity mode onto the lower switch at -2000 counts/s, the switch bouncing ``bounces``
    times ``interval_us`` apart at each edge; 300 ticks after the edge, the lower switch's
    call 36 record and the world."""
    chip.request(cmd="motor", options={"lower": lower, "upper": 100000, "bounce": bounces,
                                       "bounceNanos": interval_us * 1e3})
    chip.feed("9 7 -3\n10 1 0\n11 0 0\n7 2\n3 1\n")
    for _ in range(40):
        chip.feed("1 50 " + " ".join(["-2000"] * 50) + "\n")
        chip.run(50)
        if chip.request(cmd="world")["world"]["closed"][0]:
            break
    chip.feed("3 0\n")
    chip.run(300)
    edge = [int(w) for w in chip.feed("36 1\n")[0].split()[1:]]
    return edge, chip.request(cmd="world")["world"]


@pytest.mark.parametrize("bounces, interval_us", [(1, 400), (5, 100), (9, 100)])
def test_a_bounce_within_the_debounce_time_is_one_edge_at_the_switch(
        bounces: int, interval_us: float) -> None:
    # the bounce lasts bounces x interval_us, at most 900 us: inside the 1 ms after the edge
    assert bounces * interval_us < DEBOUNCE_US
    require_emulator()
    lower = -1500
    with PinsChip(pins=True) as chip:
        edge, world = onto_bouncing_switch(chip, lower, bounces=bounces,
                                           interval_us=interval_us)
    print(f"bounce {bounces} x {interval_us} us: the pin changed {world['switchPinChanges']}"
          f" times, the firmware took {edge[1]} edge(s), latched at {edge[3]}")
    # the switch's pin did bounce: the edge and each bounce's opening and closing
    assert world["switchPinChanges"] == 1 + 2 * bounces
    # one edge, closed, latched at the switch's own count (the first contact)
    assert edge[1:4] == [1, 1, lower]


def test_a_bounce_longer_than_the_debounce_time_is_caught() -> None:
    # the test of the test: a bounce the debounce does not cover (the switch opens again
    # 1.5 ms after it closed and closes once more at 3 ms, each past the 1 ms) is taken as
    # three edges, and the comparisons above catch it: more than one edge, and the latch at
    # the last contact instead of the first
    require_emulator()
    lower = -1500
    with PinsChip(pins=True) as chip:
        edge, world = onto_bouncing_switch(chip, lower, bounces=1, interval_us=3000)
    print(f"bounce 1 x 3000 us: the firmware took {edge[1]} edges, latched at {edge[3]}")
    assert world["switchPinChanges"] == 3
    assert edge[1] == 3 and edge[2] == 1
    assert edge[1:4] != [1, 1, lower]


def test_the_pin_map_is_the_firmwares() -> None:
    """The harness drives the pins pins.h names (the probe's among them)."""
    root = emulator_dir().parent
    header = (root / "src" / "rp2040" / "pins.h").read_text(encoding="ascii")
    defined = {name: int(number) for name, number
               in re.findall(r"#define PIN_(\w+) (\d+)u", header)}
    source = (emulator_dir() / "lib" / "pins.js").read_text(encoding="utf-8")
    block = re.search(r"PIN_MAP = \{(.*?)\};", source, re.S)
    assert block is not None
    harness = {name: int(number) for name, number in re.findall(r"(\w+): (\d+)", block.group(1))}
    assert harness == {"encoderA": defined["ENCODER_A"], "encoderB": defined["ENCODER_B"],
                       "in1": defined["BRIDGE_IN1"], "in2": defined["BRIDGE_IN2"],
                       "enable": defined["ENABLE"], "lower": defined["SWITCH_LOWER"],
                       "upper": defined["SWITCH_UPPER"], "probe": defined["PROBE"]}


PROBE_SURFACE = -800
"""Where the probe of the tests below touches: at or below this count."""


def probe_down_and_back(chip: PinsChip) -> tuple[list[list[int]], list[int]]:
    """A smooth move from 0 to -1200 counts and back (up to 3.2 counts a tick) across the
    probe's surface, the probe read by call 41 near the bottom (with call 40 changing the
    simulated surface meanwhile, which the pin ignores) and at the end; the largest step of
    the counter between two ticks."""
    chip.feed("21 1\n23 0\n")
    profile = move_profile(-1200, 600)
    replies = []
    lines: list[str] = []
    for start in range(0, len(profile), 500):
        batch = profile[start : start + 500]
        lines += chip.feed(f"1 {len(batch)} {' '.join(map(str, batch))}\n")
        if start == 0:
            lines += chip.feed("3 1\n")
        lines += chip.run(500)
        if start == 0:   # near the bottom: -1120 counts
            replies += chip.feed("41 -1\n40 2 100000\n41 -1\n40 0 0\n")
    replies += chip.feed("3 0\n21 0\n41 -1\n")
    actual = [int(line.split()[3]) for line in lines if line.startswith("D ")]
    steps = [abs(b - a) for a, b in itertools.pairwise(actual)]
    return [[int(word) for word in reply.split()[1:]] for reply in replies], steps


def test_the_probe_pin_latches_the_count_where_the_motor_crossed_its_surface() -> None:
    require_emulator()
    motor = PinsMotor(probe_side=1, probe_counts=PROBE_SURFACE)
    with PinsChip(pins=True) as chip:
        chip.request(cmd="motor", options=motor.options())
        (bottom, after_call_40, end), steps = probe_down_and_back(chip)
        world = chip.request(cmd="world")["world"]
    step = max(steps)
    print(f"probe: closed at {bottom[3]} (tick {bottom[4]}), opened at {end[3]} (tick"
          f" {end[4]}); the surface at {PROBE_SURFACE}, at most {step} counts a tick")
    assert world["probeEdges"] == 2 and not world["probeClosed"]
    # closed, one edge, latched on the tick the pin first read low: at or below the surface,
    # within the counts of that tick's step
    assert bottom[:3] == [1, 1, 1]
    assert PROBE_SURFACE - step <= bottom[3] <= PROBE_SURFACE
    # call 40's simulated surface does not override the pin
    assert after_call_40 == bottom
    # opened again on the way back, above the surface, within a tick's step
    assert end[:3] == [0, 2, 0]
    assert PROBE_SURFACE < end[3] <= PROBE_SURFACE + 1 + step
    assert bottom[4] < end[4]


def test_without_a_probe_surface_the_probe_stays_open() -> None:
    # the test of the test: the same move with no surface latches nothing
    require_emulator()
    with PinsChip(pins=True) as chip:
        chip.request(cmd="motor", options=PinsMotor().options())
        (bottom, _, end), _ = probe_down_and_back(chip)
    assert bottom == end == [0, 0, 0, 0, 0]


def test_the_output_pins_are_the_firmwares() -> None:
    """The harness reads the outputs of call 42 off the pins pins.h names."""
    header = (emulator_dir().parent / "src" / "rp2040" / "pins.h").read_text(encoding="ascii")
    defined = [int(number) for number in re.findall(r"#define PIN_OUTPUT_\d (\d+)u", header)]
    source = (emulator_dir() / "lib" / "pins.js").read_text(encoding="utf-8")
    block = re.search(r"OUTPUT_PINS = \[(.*?)\];", source)
    assert block is not None
    assert [int(pin) for pin in block.group(1).split(",")] == defined == [13, 14, 16, 17]


def levels_tick_by_tick(chip: PinsChip, ticks: int) -> list[tuple[int, list[float]]]:
    """Run tick by tick; after each, the ticks run since power-up and the output pins'
    levels (per mille), read without a line to the device."""
    seen = []
    for _ in range(ticks):
        done = int(chip.request(cmd="run", ticks=1)["tick"])
        seen.append((done, [float(level) for level in chip.request(cmd="outputs")["levels"]]))
    return seen


def first_tick_at(seen: list[tuple[int, list[float]]], output: int, level: float) -> int:
    """The first tick after which ``output`` shows ``level``."""
    return next(done for done, levels in seen if levels[output] == level)


@pytest.mark.parametrize("pins", [False, True], ids=["simulated motor", "motor on the pins"])
def test_the_output_pins_change_on_the_named_tick(pins: bool) -> None:
    """Changes queued for ticks 40, 57 and 90 show on GP13 and on GP16/GP17's PWM duty on
    exactly those ticks: the servo tick that starts with the clock at T is the device's
    (T + 1)-th since power-up on either motor (with the motor on the pins the clock counts
    the ticks completed, one behind, and a tick starts as the one before it completes)."""
    require_emulator()
    with PinsChip(pins=pins) as chip:
        assert chip.request(cmd="outputs")["levels"] == [0, 0, 0, 0], "all off at power-up"
        assert chip.feed("42 0 1000 40\n42 2 375 40\n42 3 1000 57\n42 0 0 90\n") == []
        seen = levels_tick_by_tick(chip, 100)
        (reply,) = chip.feed("43 0\n")
    assert first_tick_at(seen, 0, 1000) == 41
    assert first_tick_at(seen, 2, 375) == 41
    assert first_tick_at(seen, 3, 1000) == 58
    assert next(done for done, levels in seen if done > 41 and levels[0] == 0) == 91
    assert seen[-1][1] == [0, 0, 375, 1000]
    assert all(levels[1] == 0 for _, levels in seen)
    assert reply == "OUTPUTS 0 0 375 1000 0 90"


@pytest.mark.parametrize("pins", [False, True], ids=["simulated motor", "motor on the pins"])
def test_a_fault_turns_the_output_pins_off_on_its_tick(pins: bool) -> None:
    """The watchdog trips: every output pin goes low on the tick the fault latches (with the
    motor on the pins the tick completes, and latches, on the alarm after it started)."""
    require_emulator()
    with PinsChip(pins=pins) as chip:
        chip.feed("42 1 1000 0\n42 2 800 0\n42 3 200 0\n42 0 1000 5000\n28 5\n3 1\n")
        seen = levels_tick_by_tick(chip, 20)
        (fault,) = chip.feed("30 -1\n")
        (outputs,) = chip.feed("43 0\n")
    fault_tick = int(fault.split()[2])
    assert fault.split()[1] == "1"
    off = next(done for done, levels in seen if levels == [0, 0, 0, 0])
    assert off == fault_tick + (1 if pins else 0)
    assert seen[0][1] == [0, 1000, 800, 200]
    assert outputs == "OUTPUTS 0 0 0 0 0 0"
