"""The step rate of one axis on the RP2040's pins, beside Klipper's, and what it costs core1.

    python benchmarks/step_rate.py [--ticks 1000] [--runs 1] [--json]
                                   [--uf2 build/firmware/usbmotion.uf2]

One emulated chip (``firmware/emulator``, deterministic) running the firmware's open-loop
step drive (call 44 1) with a TMC2209's timing (call 46 100 20: 100 ns high, 20 ns set-up,
rounded up to 13 and 3 periods of the 125 MHz step clock) at a 10 kHz servo, commanded
faster than a tick can issue, so every tick issues call 48's ``max_per_tick``. The pins are
recorded (the harness's ``capture``: every edge of STEP and DIR with its time) and held
against the Python device's steps and call 46's rules (``tests/firmware/steps.py``):

- the step rate: STEP's rising edges counted over whole ticks of chip time, per second;
  printed beside Klipper's published figure for one stepper on an RP2040 (its
  docs/Benchmarks.md, "RPxxxx step rate benchmark": 3 ticks of its 12 MHz scheduling timer
  a step for 1 stepper, 4,000K steps per second, the core at 200 MHz, no pulse width asked),
  and their ratio;
- the timing: every rise against its ideal time in whole periods (the generator's schedule,
  ``ideal_rises``: the tick's room over its steps, s or s + 1 periods apart): the jitter;
  the rise-to-rise periods seen; the farthest rise from its exactly even time (the tick's
  start + set-up + k x room / steps, in fractions of a period); the pulse's high and low
  times;
- core1's cost: the cycles of the step hook (``platform_steps_issue``, and
  ``step_pins_take_timing`` when the timing changed, by the emulator's per-function profile;
  beside them a comparison in the alarm's interrupt) per tick, and the whole
  tick's (the alarm interrupt, the device's tick, its diagnostics line) as a share of the
  12,500-cycle period, whose goal is at most 30 % (``benchmarks/firmware_budget.py``).

The emulator is deterministic: every run gives the same figures.
"""

from __future__ import annotations

import itertools
import statistics
import sys
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from _common import argument_parser, emit, parse_arguments
from firmware.pins import PinsChip
from firmware.sessions import Run, lines, python_replay
from firmware.steps import (
    CYCLE_NS,
    DIR_PIN,
    STEP_PIN,
    StepTiming,
    capture,
    check_pulses,
    frames_of,
    issued_by_tick,
)
from usbmotion.sim.firmware import default_uf2

KLIPPER_RP2040_STEPS_S = 4_000_000
"""Klipper's docs/Benchmarks.md: rp2040, 1 stepper, 3 ticks of 12 MHz a step: 4,000K steps/s."""
PULSE_NS = 100
SETUP_NS = 20
INTERVAL_DMS = 1
TICK_BUDGET = 12_500
TICK_GOAL = 0.30
HOOK = ("platform_steps_issue", "step_pins_take_timing")
"""The step hook's functions; besides them every tick compares two words in the alarm's
interrupt (step_pins_tick, inline in servo_alarm_irq)."""


def _setup(ticks: int) -> list[str]:
    """The lines before the run: 10 kHz, the TMC2209's timing, open loop, a diagnostics line
    every tick, a move at 600 steps a tick queued (more than the 480 a tick can issue)."""
    positions = " ".join(str(600 * k) for k in range(1, ticks + 1))
    return [f"5 {INTERVAL_DMS}", f"46 {PULSE_NS} {SETUP_NS}", "44 1", "21 1",
            f"1 {ticks} {positions}", "3 1"]


def measure(uf2: Path, *, ticks: int) -> dict[str, Any]:
    """One run: the rate, the timing and the cycles over ``ticks`` ticks at full rate."""
    with PinsChip(pins=False, uf2=uf2) as chip:
        chip.request(cmd="capture", pins=[STEP_PIN, DIR_PIN])
        for line in _setup(ticks):
            chip.feed(line + "\n")
        chip.request(cmd="profile", on=True)
        per_tick: list[int] = []
        printed: list[tuple[int, str]] = []
        for _ in range(ticks):
            reply = chip.request(cmd="run", ticks=1)
            per_tick.append(reply["cycles"][1])
            printed += PinsChip.lines(reply)
        functions = chip.request(cmd="profile", on=False)["functions"][1]
        edges, flags = capture(chip.request(cmd="capture"))
    python = [(tick, line.decode("ascii")) for tick, line in
              python_replay([lines(*_setup(ticks)), Run(ticks)])]
    chip_lines = [entry for entry in printed if entry[1].startswith("D ")]
    assert chip_lines == [entry for entry in python if entry[1].startswith("D ")], (
        "the chip's diagnostics lines differ from the Python device's")
    timing = StepTiming.of(PULSE_NS, SETUP_NS, INTERVAL_DMS * 100)
    # a tick's frame plays from just after its start to just after the next tick's: the last
    # two ticks' are not whole in the capture
    end_ns = min(ns for flag, ns, tick in flags if tick == ticks - 1)
    edges = [edge for edge in edges if edge[2] < end_ns]
    flags = [flag for flag in flags if flag[1] < end_ns]
    issued = {tick: steps for tick, steps in issued_by_tick(python).items() if tick < ticks - 1}
    report = check_pulses(edges, flags, issued, timing)
    frames = [frame for frame in frames_of(edges, flags) if frame.rises]
    # whole ticks at full rate: from the start of the first to the start of the last
    full = [frame for frame in frames if len(frame.rises) == timing.max_per_tick]
    window_ns = full[-1].start_ns - full[0].start_ns
    steps = sum(len(frame.rises) for frame in full[:-1])
    rate = steps / (window_ns / 1e9)
    hook = dict.fromkeys(HOOK, 0)
    for entry in functions:
        if entry["name"] in hook:
            hook[entry["name"]] += entry["cycles"]
    rises = sorted(ns for pin, level, ns in edges if pin == STEP_PIN and level == 1
                   and full[0].start_ns <= ns < full[-1].start_ns)
    periods = [later - earlier for earlier, later in itertools.pairwise(rises)]
    return {
        "pulse_cycles": timing.pulse,
        "setup_cycles": timing.setup,
        "tick_cycles": timing.tick,
        "max_per_tick": timing.max_per_tick,
        "ticks": ticks,
        "full_rate_ticks": len(full) - 1,
        "steps_per_s": rate,
        "klipper_steps_per_s": KLIPPER_RP2040_STEPS_S,
        "ratio_to_klipper": rate / KLIPPER_RP2040_STEPS_S,
        "periods_ns": sorted(set(periods)),
        "even_period_ns": (timing.tick - timing.setup) * CYCLE_NS / timing.max_per_tick,
        "jitter_ns": report.max_jitter_ns,
        "drift_from_even_ns": report.max_drift_ns,
        "min_high_ns": report.min_high_ns,
        "min_low_ns": report.min_low_ns,
        "steps_checked": report.steps,
        "hook_cycles_per_tick": {name: cycles / ticks for name, cycles in hook.items()},
        "hook_cycles_per_tick_total": sum(hook.values()) / ticks,
        "tick_median_cycles": statistics.median(per_tick),
        "tick_max_cycles": max(per_tick),
    }


def report(figures: dict[str, Any]) -> str:
    f = figures
    out = [f"One axis, open loop, TMC2209 timing (call 46 {PULSE_NS} {SETUP_NS}: "
           f"{f['pulse_cycles']} / {f['setup_cycles']} periods of 8 ns) at a 10 kHz servo, on "
           f"the emulated pins ({f['full_rate_ticks']} whole ticks at {f['max_per_tick']} steps)"]
    out.append(f"  step rate        {f['steps_per_s'] / 1e3:,.0f}K steps/s   Klipper (rp2040, 1 "
               f"stepper) {f['klipper_steps_per_s'] / 1e3:,.0f}K steps/s   ratio "
               f"{f['ratio_to_klipper']:.2f}")
    periods = ", ".join(str(period) for period in f["periods_ns"])
    out.append(f"  edges            {f['steps_checked']:,} steps checked: every rise on the "
               f"generator's schedule (jitter {f['jitter_ns']:.0f} ns); rise to rise {periods} "
               f"ns (exactly even: {f['even_period_ns']:.1f} ns), the farthest rise "
               f"{f['drift_from_even_ns']:.0f} ns from its exactly even time; high "
               f"{f['min_high_ns']} ns, low {f['min_low_ns']} ns at least")
    hook = ", ".join(f"{name} {cycles:.0f}" for name, cycles in
                     f["hook_cycles_per_tick"].items())
    out.append(f"  core1            the step hook {f['hook_cycles_per_tick_total']:.0f} cycles a "
               f"tick ({hook}); the whole tick median {f['tick_median_cycles']:.0f}, max "
               f"{f['tick_max_cycles']} cycles ({f['tick_max_cycles'] / TICK_BUDGET:.1%} of "
               f"{TICK_BUDGET:,}; goal <= {TICK_GOAL:.0%}: "
               f"{'met' if f['tick_max_cycles'] <= TICK_GOAL * TICK_BUDGET else 'NOT met'})")
    return "\n".join(out)


def main(argv: list[str] | None = None) -> dict[str, Any]:
    """Run the benchmark, print the figures (or JSON) and return them."""
    parser = argument_parser(__doc__, runs=1)
    parser.add_argument("--ticks", type=int, default=1000, help="servo ticks at full rate")
    parser.add_argument("--uf2", type=Path, default=default_uf2(), help="firmware image")
    args = parse_arguments(parser, argv)
    if not 10 <= args.ticks <= 1000:
        parser.error(f"--ticks {args.ticks!r}: 10 to 1000 (one queue of setpoints)")
    runs = [measure(args.uf2, ticks=args.ticks) for _ in range(args.runs)]
    figures = runs[0]
    figures["runs_identical"] = all(run == runs[0] for run in runs)
    return emit(figures, report, as_json=args.json)


if __name__ == "__main__":
    main(sys.argv[1:])
