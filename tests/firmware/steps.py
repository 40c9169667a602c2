"""Step/direction pulses read off the emulated chip's pins, and what PROTOCOL.md asks of them.

The firmware's step generator (``firmware/src/rp2040/step_dir.pio``) drives STEP (GP18) and
DIR (GP19) from a PIO block that the harness runs on the timer's time; its tick clock raises
PIO flag 4 at the start of every tick's frame. The harness's ``capture`` request records
every change of those pins and every flag with its time (ns of the timer), and the flag with
the ticks done then: in the deterministic mode the frame that starts after tick N's alarm
plays the steps tick N issued. :func:`check_pulses` holds that record against the steps the
Python device issued on each tick and call 46's timing: the count and the direction of
every tick, the pulse's high and low times, the direction's set-up, the pulses within their
tick, and their spacing against the ideal times.
"""

from __future__ import annotations

import bisect
import itertools
from dataclasses import dataclass
from typing import Any

from usbmotion.device.stepper import cycles

STEP_PIN = 18
DIR_PIN = 19
ENABLE_PIN = 20
TICK_FLAG = 4
CYCLE_NS = 8
"""One period of the 125 MHz step clock."""
MIN_SETUP_CYCLES = 2
"""The least set-up the step generator gives (a shorter call-46 set-up is made this long)."""
RUN_SWITCH_CYCLES = 5
"""What the step generator's switch from a tick's first run of steps to its second takes
beyond the second's spacing (firmware/src/rp2040/step_dir.pio)."""

Edge = tuple[int, int, int]
"""(pin, level, ns)"""
Flag = tuple[int, int, int]
"""(flag, ns, ticks done)"""


@dataclass(frozen=True, slots=True)
class StepTiming:
    """Call 46's timing at a servo period, in step-clock periods."""

    pulse: int
    setup: int
    tick: int

    @classmethod
    def of(cls, pulse_ns: int, setup_ns: int, tick_us: int) -> StepTiming:
        return cls(cycles(pulse_ns), cycles(setup_ns), tick_us * 125)

    @property
    def max_per_tick(self) -> int:
        return (self.tick - self.setup) // (2 * self.pulse)


@dataclass(frozen=True, slots=True)
class Frame:
    """One tick's pulses: from its start (the tick clock's flag) to the next tick's."""

    tick: int
    """Ticks done at its start: the tick whose steps it plays."""
    start_ns: int
    end_ns: int
    rises: tuple[int, ...]
    directions: tuple[int, ...]
    """DIR's level at each rise."""


@dataclass(frozen=True, slots=True)
class PulseReport:
    """What the pins showed over a capture (times in ns)."""

    ticks: int
    steps: int
    """Rising edges, all ticks."""
    net_steps: int
    """Each rise counted +1 with DIR high, -1 with DIR low."""
    busiest: int
    """The most rises in one tick."""
    min_high_ns: int
    min_low_ns: int
    min_setup_ns: int | None
    """From a change of DIR to the next rise (None: DIR never changed before a rise)."""
    direction_changes: int
    max_jitter_ns: float
    """The farthest rise from its ideal time in whole periods (:func:`ideal_rises`)."""
    max_drift_ns: float
    """The farthest rise from the exactly even time: the tick's start + set-up + k x (tick -
    set-up) / steps, in fractions of a period (what whole periods cost)."""
    min_end_gap_ns: int | None
    """From a tick's last fall to the next tick's start (its pulses end within the tick)."""


def ideal_rises(steps: int, timing: StepTiming) -> list[int]:
    """The step generator's rises for a tick of ``steps`` steps, periods from the tick's
    start: the room (tick - set-up) over the steps is s periods and r left over; the first
    r - 4 steps are s + 1 apart, the rest s, the switch between the two runs s + 5 (r under
    5: all s apart); the first rise after the set-up (at least 2 periods)."""
    room = timing.tick - timing.setup
    spacing, rest = divmod(room, steps)
    first = max(timing.setup, MIN_SETUP_CYCLES)
    if rest < RUN_SWITCH_CYCLES:
        return [first + k * spacing for k in range(steps)]
    longer = rest - (RUN_SWITCH_CYCLES - 1)
    rises = [first + k * (spacing + 1) for k in range(longer)]
    switch = rises[-1] + spacing + RUN_SWITCH_CYCLES
    return rises + [switch + k * spacing for k in range(steps - longer)]


def frames_of(edges: list[Edge], flags: list[Flag], *, end_ns: int | None = None) -> list[Frame]:
    """The captured edges cut into frames at the tick clock's flags. DIR's level before the
    first captured edge is taken as low (the level it has from power-up)."""
    starts = [(ns, ticks) for flag, ns, ticks in flags if flag == TICK_FLAG]
    last = end_ns if end_ns is not None else (max((e[2] for e in edges), default=0) + 1)
    bounds = [ns for ns, _ in starts[1:]] + [max(last, starts[-1][0] + 1) if starts else last]
    frames: list[Frame] = []
    direction = 0
    edge_index = 0
    ordered = sorted(edges, key=lambda e: (e[2], e[0] != DIR_PIN))
    for (start, ticks), end in zip(starts, bounds, strict=True):
        rises: list[int] = []
        directions: list[int] = []
        while edge_index < len(ordered) and ordered[edge_index][2] < start:
            pin, level, _ = ordered[edge_index]
            if pin == DIR_PIN:
                direction = level
            edge_index += 1
        while edge_index < len(ordered) and ordered[edge_index][2] < end:
            pin, level, ns = ordered[edge_index]
            if pin == DIR_PIN:
                direction = level
            elif pin == STEP_PIN and level == 1:
                rises.append(ns)
                directions.append(direction)
            edge_index += 1
        frames.append(Frame(ticks, start, end, tuple(rises), tuple(directions)))
    return frames


def check_pulses(edges: list[Edge], flags: list[Flag], issued: dict[int, int],
                 timing: StepTiming) -> PulseReport:
    """Holds the captured pins against the steps issued on each tick (``issued``: tick ->
    signed steps, as the Python device's diagnostics lines give them) and call 46's timing.

    Raises AssertionError naming the first tick or edge that breaks a rule: a tick whose
    rises differ in number or direction from its steps; a pulse high or low for less than
    the pulse; a rise less than the set-up after a change of DIR, or DIR changing while STEP
    is high; a tick's pulses not ending before the next tick starts; a rise off its ideal
    time (:func:`ideal_rises`) by a period or more.
    """
    pulse_ns = timing.pulse * CYCLE_NS
    setup_ns = max(timing.setup, MIN_SETUP_CYCLES) * CYCLE_NS
    frames = frames_of(edges, flags)
    assert frames, "the tick clock raised no flag: no tick's start was seen"
    starts = [frame.start_ns for frame in frames]
    period_ns = timing.tick * CYCLE_NS
    for before, after in itertools.pairwise(starts[1:]):
        # the first start may follow a restart of the tick clock (a new period)
        assert after - before == period_ns, (
            f"ticks started {after - before} ns apart at {after} ns, not the period {period_ns} ns")
    by_tick = {frame.tick: frame for frame in frames}
    for tick, steps in sorted(issued.items()):
        frame = by_tick.get(tick)
        rises = frame.rises if frame is not None else ()
        assert len(rises) == abs(steps), (
            f"tick {tick}: {len(rises)} rising edges of STEP for the {steps} steps issued")
        want = 1 if steps > 0 else 0
        assert frame is None or all(level == want for level in frame.directions), (
            f"tick {tick}: DIR {frame.directions} at the rises of {steps} steps")
    for frame in frames:
        if frame.tick not in issued:
            assert not frame.rises, (
                f"tick {frame.tick}: {len(frame.rises)} rising edges where no step was issued")

    step_edges = sorted((ns, level) for pin, level, ns in edges if pin == STEP_PIN)
    highs = [b[0] - a[0] for a, b in itertools.pairwise(step_edges)
             if a[1] == 1 and b[1] == 0]
    lows = [b[0] - a[0] for a, b in itertools.pairwise(step_edges)
            if a[1] == 0 and b[1] == 1]
    for index, (a, b) in enumerate(itertools.pairwise(step_edges)):
        assert a[1] != b[1], f"STEP edge {index + 1}: two {b[1]} levels in a row"
    min_high = min(highs, default=pulse_ns)
    min_low = min(lows, default=pulse_ns)
    assert min_high >= pulse_ns, f"a STEP pulse high for {min_high} ns, under {pulse_ns} ns"
    assert min_low >= pulse_ns, f"STEP low for {min_low} ns between pulses, under {pulse_ns} ns"

    all_rises = [ns for ns, level in step_edges if level == 1]
    falls = [ns for ns, level in step_edges if level == 0]
    changes = sorted(ns for pin, _, ns in edges if pin == DIR_PIN)
    setups: list[int] = []
    for change in changes:
        after = bisect.bisect_left(all_rises, change)
        if after < len(all_rises):
            setups.append(all_rises[after] - change)
        if after > 0 and after - 1 < len(falls):
            assert falls[after - 1] <= change, (
                f"DIR changed at {change} ns while STEP was high (since {all_rises[after - 1]} ns)")
    min_setup = min(setups) if setups else None
    assert min_setup is None or min_setup >= timing.setup * CYCLE_NS, (
        f"a rise {min_setup} ns after DIR changed, under the set-up {timing.setup * CYCLE_NS} ns")

    jitter = 0.0
    drift = 0.0
    end_gaps: list[int] = []
    fall_after = dict(zip(all_rises, falls, strict=False))
    for frame in frames:
        count = len(frame.rises)
        if count == 0:
            continue
        room = timing.tick - timing.setup
        for k, (rise, ideal) in enumerate(zip(frame.rises, ideal_rises(count, timing),
                                              strict=True)):
            ideal_ns = frame.start_ns + ideal * CYCLE_NS
            even = frame.start_ns + setup_ns + k * room * CYCLE_NS / count
            jitter = max(jitter, abs(rise - ideal_ns))
            drift = max(drift, abs(rise - even))
        last_fall = fall_after.get(frame.rises[-1])
        if frame is not frames[-1]:
            assert last_fall is not None and last_fall < frame.end_ns, (
                f"tick {frame.tick}: its last pulse ends at {last_fall} ns, after the next tick"
                f" started at {frame.end_ns} ns")
            end_gaps.append(frame.end_ns - last_fall)
    assert jitter < CYCLE_NS, f"a rise {jitter} ns off its ideal time"
    return PulseReport(
        ticks=len(frames),
        steps=len(all_rises),
        net_steps=sum(1 if level else -1 for frame in frames for level in frame.directions),
        busiest=max((len(frame.rises) for frame in frames), default=0),
        min_high_ns=min_high,
        min_low_ns=min_low,
        min_setup_ns=min_setup,
        direction_changes=len(changes),
        max_jitter_ns=jitter,
        max_drift_ns=drift,
        min_end_gap_ns=min(end_gaps) if end_gaps else None,
    )


def issued_by_tick(printed: list[tuple[int, str]]) -> dict[int, int]:
    """Tick -> the signed steps its diagnostics line (``D ... {output_mv} ...``: the steps x
    1000 with a step drive) says it issued, for every diagnostics line printed."""
    issued: dict[int, int] = {}
    for tick, line in printed:
        if line.startswith("D "):
            output_mv = int(line.split()[5])
            assert output_mv % 1000 == 0, line
            issued[tick] = output_mv // 1000
    return issued


def capture(reply: dict[str, Any]) -> tuple[list[Edge], list[Flag]]:
    """The edges and flags of a ``capture`` reply, as tuples."""
    edges = [(int(pin), int(level), int(ns)) for pin, level, ns in reply["edges"]]
    flags = [(int(flag), int(ns), int(ticks)) for flag, ns, ticks in reply["flags"]]
    return edges, flags
