"""The RP2040 firmware's budget: cycles per servo tick and per setpoint, memory, boot time.

    python benchmarks/firmware_budget.py [--ticks 2000] [--runs 3] [--profile] [--json]
                                         [--uf2 build/firmware/usbmotion.uf2] [--modes loop]

Every figure comes from the emulated chip (``firmware/emulator``, deterministic mode), from
the cycles each core executed while awake (rp2040js's cycle model of the Cortex-M0+, which
reads flash as fast as RAM: the build runs from RAM, copy_to_ram, so the chip does too):

- core1 cycles per servo tick at 10 kHz (a 100 us period: 12,500 cycles of a 125 MHz
  RP2040), with a diagnostics line every tick and the statistics counting, in position
  mode (a ramp streamed through the motion queue), velocity mode and curve mode (four
  keyframes, appended again while the curve plays, and in "curve start" a new curve after
  the last one ended, the motor still moving): each tick measured alone (the alarm
  interrupt, the tick, its records, the re-arm), the median and the largest, as a share of
  the period; the goal is at most 30 %; each mode again with the motor on the pins (call
  39, the default motor outside the chip: the encoder read from the PIO decoder, the
  switches sampled, the bridge's PWM set); and position and curve start again with an
  output change (call 42) applied on every tick, a digital pin or a PWM level set, and
  again with all four outputs changed on every tick; and the step/direction drives (call 44,
  open and closed loop: a NEMA 17 stepper simulated on the chip, integrated in 100 us steps,
  one a tick) in each mode, and in position mode at 1 kHz too (a 1 ms period of 125,000
  cycles: ten integration steps a tick), each as a share of its own period;
- core0 cycles per setpoint received: call-1 batches of 600 setpoints with the CRC
  acknowledgement (``8 1 2``) and a queue query behind each, as the host streams; and the
  share of core0 a device at 10 kHz taking 10,000 setpoints/s keeps busy (goal: under half),
  with its diagnostics line every 10 ticks;
- flash and RAM used (``arm-none-eabi-size``), and the stacks' high-water marks;
- boot to first reply: from reset to the firmware enabling USB, to the host having
  configured the port (its 10 ms bus reset included), to the first byte of the answer.

The emulator is deterministic: a figure is the same run after run. ``--runs`` repeats each
anyway (the median is quoted, and a difference between runs would be reported). With
``--profile`` the cycles of each function are counted in the costliest tick of each mode
and in a batch of setpoints (what costs what).
"""

from __future__ import annotations

import random
import shutil
import statistics
import subprocess
import sys
from pathlib import Path
from typing import Any

from _common import argument_parser, emit, parse_arguments
from usbmotion.sim.firmware import EmulatedDevice, default_uf2

CLOCK_HZ = 125_000_000
PERIOD_DMS = 1
"""Call 5: 1 dms = 100 us, 10 kHz."""
TICK_BUDGET = CLOCK_HZ // 10_000
TICK_GOAL = 0.30
BATCH = 600
SETPOINTS_S = 10_000
CORE0_GOAL = 0.5

_RAMP = " ".join(str(3 * k) for k in range(1, 1001))
MODES: dict[str, tuple[str, ...]] = {
    "position": ("21 1", "3 1", f"1 1000 {_RAMP}"),
    "velocity": ("21 1", "7 2", "3 1", "1 1000 " + " ".join(["20000"] * 1000)),
    "curve": ("21 1", "7 3", "3 1", "25 20 400 0 0", "25 10 -100 512 -512",
              "25 30 2000 100 -100", "25 25 -3000 0 0"),
}
MODES["curve start"] = MODES["curve"]
for _mode in ("position", "velocity", "curve", "curve start"):
    MODES[f"{_mode}, pins"] = MODES[_mode]
for _mode in ("position", "curve start"):
    MODES[f"{_mode}, outputs"] = MODES[_mode]
    MODES[f"{_mode}, four outputs"] = MODES[_mode]
_STEPPER = ("12 1", "17 1 -5", "33 20 0", "16 4000")
"""A NEMA 17 stepper's rotor and a small load, a 1000-line encoder, 100 us integration steps."""
for _drive, _loop in ((1, "open loop"), (2, "closed loop")):
    for _mode in ("position", "velocity", "curve"):
        MODES[f"{_loop}, {_mode}"] = (*_STEPPER, f"44 {_drive}", *MODES[_mode])
    MODES[f"{_loop}, position, 1 kHz"] = ("5 10", *_STEPPER, f"44 {_drive}",
                                          *MODES["position"])
"""Each mode's set-up after ``5 1`` (10 kHz): a diagnostics line every tick, the servo
enabled, motion to follow (and again: _refeed). The statistics count in position and curve
mode. A mode ", outputs" has an output change due on every tick, a mode ", four outputs"
all four outputs changed on every tick (_refeed). A mode "open loop, ..." or "closed loop,
..." runs a step drive; one ending ", 1 kHz" a 1 ms period (``5 10``)."""


def _kind(mode: str) -> str:
    """The motion a mode follows: position, velocity, curve or curve start."""
    for suffix in (", four outputs", ", outputs", ", pins", ", 1 kHz"):
        mode = mode.removesuffix(suffix)
    return mode.split(", ")[-1]


def period_cycles(mode: str) -> int:
    """The mode's servo period in cycles of the 125 MHz clock."""
    return CLOCK_HZ // 1000 if mode.endswith(", 1 kHz") else TICK_BUDGET
OUTPUT_BATCH = 16
"""Output changes queued at once (the device's whole queue): one for each of the next 16
ticks, or in a mode ", four outputs" one for each output on each of the next 4 ticks."""
_CURVE_AGAIN = ("25 20 400 0 0", "25 10 -100 512 -512", "25 30 2000 100 -100",
                "25 25 -3000 0 0")


def _lines(*texts: str) -> bytes:
    return b"".join(text.encode("ascii") + b"\n" for text in texts)


def _refeed(device: EmulatedDevice, mode: str, index: int) -> None:
    """More motion before tick ``index + 1``: in position and velocity mode the ramp again
    before the queue runs dry; in curve mode the keyframes again while the curve plays (core0
    prepares their segments as it appends them); in "curve start" a new curve 30 ticks after
    the last one ended, the motor still settling (its first segment is prepared as it
    starts: the costliest ticks of curve mode)."""
    if mode.endswith(", four outputs"):
        if index % (OUTPUT_BATCH // 4) == 0:
            # the clock is ``index`` here: each of the next 4 ticks changes every output, the
            # two digital ones toggled, the two PWM levels stepped
            device.feed(_lines(*(
                f"42 {k % 4} {1000 * ((index + k // 4) % 2) if k % 4 < 2 else 60 * k}"
                f" {index + k // 4}" for k in range(OUTPUT_BATCH))))
    elif mode.endswith(", outputs") and index % OUTPUT_BATCH == 0:
        # the clock is ``index`` here: one change for each of the next 16 ticks, the two
        # digital outputs toggled and the two PWM levels stepped in turn
        device.feed(_lines(*(
            f"42 {k % 4} {1000 * ((index + k) // 4 % 2) if k % 4 < 2 else 60 * k} {index + k}"
            for k in range(OUTPUT_BATCH))))
    kind = _kind(mode)
    again = ((kind == "curve" and index % 800 == 799)
             or (kind == "curve start" and index % 900 == 879))
    if again:
        device.feed(_lines(*_CURVE_AGAIN))
    elif kind in ("position", "velocity") and index % 900 == 899:
        device.feed(_lines(MODES[mode][-1]))


def _power_up(device: EmulatedDevice, mode: str) -> None:
    """Blank flash; for a mode ", pins" the motor on the pins (call 39, a power cycle) with
    the default motor outside the chip (the harness's motor request)."""
    device.power_up(erase_flash=True)
    if mode.endswith(", pins"):
        device.use_pins_motor()


def tick_cycles(device: EmulatedDevice, mode: str, ticks: int, *,
                profile: bool) -> dict[str, Any]:
    """core1's cycles of each of ``ticks`` ticks in ``mode`` at 10 kHz, one at a time."""
    _power_up(device, mode)
    device.feed(_lines("5 1", *MODES[mode]))
    per_tick: list[int] = []
    core0: list[int] = []
    for index in range(ticks):
        _refeed(device, mode, index)
        span = device.run(1)
        per_tick.append(span.busy_cycles[1])
        core0.append(span.busy_cycles[0])
    worst = max(range(ticks), key=per_tick.__getitem__)
    figures: dict[str, Any] = {
        "ticks": ticks,
        "median_cycles": statistics.median(per_tick),
        "mean_cycles": statistics.fmean(per_tick),
        "p99_cycles": sorted(per_tick)[int(0.99 * (ticks - 1))],
        "max_cycles": per_tick[worst],
        "max_tick": worst + 1,
        "core0_median_cycles": statistics.median(core0),
    }
    if profile:
        _power_up(device, mode)
        device.feed(_lines("5 1", *MODES[mode]))
        for index in range(worst):
            _refeed(device, mode, index)
            device.run(1)
        device.start_profile()
        device.run(1)
        figures["profile_worst_tick"] = _top(device.stop_profile()[1])
        device.start_profile()
        device.run(200)
        figures["profile_200_ticks_per_tick"] = {name: cycles / 200 for name, cycles in
                                                 _top(device.stop_profile()[1]).items()}
    return figures


def _top(cycles: dict[str, int], count: int = 12) -> dict[str, int]:
    return dict(sorted(cycles.items(), key=lambda item: -item[1])[:count])


def setpoint_cycles(device: EmulatedDevice, *, profile: bool) -> dict[str, Any]:
    """core0's cycles per setpoint of 600-setpoint batches with the CRC acknowledgement, and
    core0's busy share at 10 kHz taking 10,000 setpoints/s."""
    rng = random.Random(2)
    device.power_up(erase_flash=True)
    device.feed(_lines("5 1", "8 1 2", "3 1"))
    per_setpoint: list[float] = []
    base = 0
    for _ in range(8):
        values = [base + rng.randint(-40, 40) + 3 * k for k in range(BATCH)]
        base = values[-1]
        span = device.feed(_lines(f"1 {BATCH} {' '.join(map(str, values))}", "2 -1"))
        assert span.data.startswith(b"ADDED 600 CRC "), span.data
        per_setpoint.append(span.busy_cycles[0] / BATCH)
        device.run(BATCH)
    figures: dict[str, Any] = {"batch": BATCH, "median_cycles_per_setpoint":
                               statistics.median(per_setpoint)}
    # one emulated second of streaming at 10 kHz: a batch every 600 ticks, D every 10 ticks
    device.power_up(erase_flash=True)
    device.feed(_lines("5 1", "8 1 2", "21 10", "3 1"))
    busy = 0
    ticks = 0
    base = 0
    while ticks < SETPOINTS_S:
        values = [base + 3 * k for k in range(1, BATCH + 1)]
        base = values[-1]
        busy += device.feed(_lines(f"1 {BATCH} {' '.join(map(str, values))}", "2 -1"))\
            .busy_cycles[0]
        busy += device.run(BATCH).busy_cycles[0]
        ticks += BATCH
    figures["streaming_core0_busy_share"] = busy / (CLOCK_HZ * ticks / SETPOINTS_S)
    if profile:
        values = [3 * k for k in range(BATCH)]
        device.feed(_lines("4 0"))
        device.start_profile()
        device.feed(_lines(f"1 {BATCH} {' '.join(map(str, values))}", "2 -1"))
        figures["profile_batch_per_setpoint"] = {
            name: cycles / BATCH for name, cycles in _top(device.stop_profile()[0]).items()}
    return figures


def memory(elf: Path) -> dict[str, Any]:
    """arm-none-eabi-size of the ELF: what the flash holds and what RAM the image takes."""
    size = shutil.which("arm-none-eabi-size")
    if size is None:
        return {}
    sections = subprocess.run([size, "-A", "-d", str(elf)], capture_output=True, text=True,
                              check=True).stdout
    table = {}
    for line in sections.splitlines():
        fields = line.split()
        if len(fields) == 3 and fields[1].isdigit():
            table[fields[0]] = (int(fields[1]), int(fields[2]))
    flash = sum(n for n, address in table.values() if 0x10000000 <= address < 0x11000000)
    # copy_to_ram: the code and data are copied to SRAM at boot, so they count there too
    ram_sections = {name: n for name, (n, address) in table.items()
                    if 0x20000000 <= address < 0x20042000}
    bin_file = elf.with_suffix(".bin")
    return {
        "flash_bytes": bin_file.stat().st_size if bin_file.exists() else flash,
        "ram_bytes": sum(ram_sections.values()),
        "ram_total_bytes": 264 * 1024,
        "ram_sections": ram_sections,
        "runs_from_ram": ".text" in ram_sections,
    }


def stacks(device: EmulatedDevice) -> dict[str, Any]:
    """The stacks' high-water marks over a parameter-heavy session and a long line."""
    device.power_up(erase_flash=True)
    device.feed(_lines("8 3 1", "5 1", "12 1", "13 1200 -2", "14 3346 -4", "34 -1000 1000",
                       "18 6 88 32 65 88 73 83", "19 2", "21 1", "3 1",
                       "1 1000 " + " ".join(["-2147483648"] * 1000), "35 -1", "20 -1"))
    device.feed(b"9" * 20000 + b"\n")
    device.run(50)
    usage = device.stack_usage()
    return {f"core{index}": None if u is None else {"used": u.used, "size": u.size}
            for index, u in enumerate(usage)}


def boot(device: EmulatedDevice) -> dict[str, Any]:
    times = device.boot_to_first_reply(b"2 -1\n")
    return {"usb_enabled_ms": times.usb_enabled_ns / 1e6,
            "configured_ms": times.configured_ns / 1e6,
            "first_reply_ms": times.reply_ns / 1e6,
            "core0_cycles_to_reply": times.busy_cycles[0]}


def measure(uf2: Path, *, ticks: int, runs: int, profile: bool,
            modes_with: str = "") -> dict[str, Any]:
    figures: dict[str, Any] = {"uf2": str(uf2), "clock_hz": CLOCK_HZ,
                               "tick_budget_cycles": TICK_BUDGET}
    with EmulatedDevice(uf2) as device:
        modes = {}
        for mode in (m for m in MODES if modes_with in m):
            repeats = [tick_cycles(device, mode, ticks, profile=profile and index == 0)
                       for index in range(runs)]
            first = repeats[0]
            first["runs_identical"] = all(
                r["median_cycles"] == first["median_cycles"]
                and r["max_cycles"] == first["max_cycles"] for r in repeats)
            modes[mode] = first
        for mode, m in modes.items():
            m["period_cycles"] = period_cycles(mode)
        figures["tick"] = modes
        figures["tick_worst_median_share"] = max(m["median_cycles"] / m["period_cycles"]
                                                 for m in modes.values())
        figures["tick_worst_max_share"] = max(m["max_cycles"] / m["period_cycles"]
                                              for m in modes.values())
        repeats = [setpoint_cycles(device, profile=profile and index == 0)
                   for index in range(runs)]
        figures["setpoints"] = repeats[0]
        figures["setpoints"]["runs_identical"] = len(
            {r["median_cycles_per_setpoint"] for r in repeats}) == 1
        figures["stacks"] = stacks(device)
        figures["boot"] = boot(device)
    figures["memory"] = memory(uf2.with_suffix(".elf"))
    return figures


def report(figures: dict[str, Any]) -> str:
    out = [f"RP2040 firmware budget ({figures['uf2']}), emulated cycles at 125 MHz"]
    out.append(f"core1 per servo tick at 10 kHz ({TICK_BUDGET} cycles; a mode at 1 kHz: "
               f"{CLOCK_HZ // 1000}), D every tick, as a share of the period:")
    for mode, m in figures["tick"].items():
        budget = m["period_cycles"]
        out.append(
            f"  {mode:<30} median {m['median_cycles']:>7.0f}"
            f" ({m['median_cycles'] / budget:6.1%})"
            f"  p99 {m['p99_cycles']:>7}  max {m['max_cycles']:>7}"
            f" ({m['max_cycles'] / budget:6.1%}, tick {m['max_tick']})"
            f"  core0 {m['core0_median_cycles']:>6.0f}/tick"
            f"{'' if m['runs_identical'] else '  RUNS DIFFER'}")
        for key in ("profile_worst_tick", "profile_200_ticks_per_tick"):
            if key in m:
                out.append(f"    {key}: " + ", ".join(f"{k} {v:.0f}" for k, v in m[key].items()))
    share = figures["tick_worst_median_share"]
    worst = figures["tick_worst_max_share"]
    out.append(f"  goal <= {TICK_GOAL:.0%}: the worst median {share:.1%} "
               f"({'met' if share <= TICK_GOAL else 'NOT met'}), the worst single tick "
               f"{worst:.1%} ({'met' if worst <= TICK_GOAL else 'NOT met'})")
    s = figures["setpoints"]
    out.append(f"core0 per setpoint ({s['batch']}-setpoint batches, CRC acknowledged): "
               f"{s['median_cycles_per_setpoint']:.0f} cycles")
    out.append(f"  10 kHz taking {SETPOINTS_S} setpoints/s, D every 10 ticks: core0 "
               f"{s['streaming_core0_busy_share']:.1%} busy (goal < {CORE0_GOAL:.0%}: "
               f"{'met' if s['streaming_core0_busy_share'] < CORE0_GOAL else 'NOT met'})")
    if "profile_batch_per_setpoint" in s:
        out.append("    per setpoint: " + ", ".join(
            f"{k} {v:.0f}" for k, v in s["profile_batch_per_setpoint"].items()))
    mem = figures["memory"]
    if mem:
        where = ("the image runs from RAM: copy_to_ram" if mem["runs_from_ram"]
                 else "the code runs from flash: XIP")
        out.append(f"flash {mem['flash_bytes']} bytes (image); RAM {mem['ram_bytes']} of "
                   f"{mem['ram_total_bytes']} bytes ({where})")
    st = figures["stacks"]
    out.append("stacks (high water / size): " + ", ".join(
        f"{core} {v['used']}/{v['size']}" for core, v in st.items() if v))
    b = figures["boot"]
    out.append(f"boot: USB enabled {b['usb_enabled_ms']:.2f} ms after reset, port configured "
               f"{b['configured_ms']:.2f} ms (the host's 10 ms bus reset included), first "
               f"reply {b['first_reply_ms']:.2f} ms")
    return "\n".join(out)


def main(argv: list[str] | None = None) -> dict[str, Any]:
    """Run the benchmark, print the figures (or JSON) and return them."""
    parser = argument_parser(__doc__, runs=3)
    parser.add_argument("--ticks", type=int, default=2000, help="servo ticks per mode")
    parser.add_argument("--profile", action="store_true", help="cycles by function")
    parser.add_argument("--uf2", type=Path, default=default_uf2(), help="firmware image")
    parser.add_argument("--modes", default="", metavar="TEXT",
                        help="measure only the modes whose name holds TEXT (\"loop\": the "
                             "step drives)")
    args = parse_arguments(parser, argv)
    if args.ticks < 100:
        parser.error(f"--ticks {args.ticks!r}: at least 100")
    figures = measure(args.uf2, ticks=args.ticks, runs=args.runs, profile=args.profile,
                      modes_with=args.modes)
    return emit(figures, report, as_json=args.json)


if __name__ == "__main__":
    main(sys.argv[1:])
