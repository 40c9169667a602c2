"""The text of grbl's push messages, no I/O: settings, ``$#``, ``$G``, ``$I``, numbers.

Numbers print as grbl prints them: coordinates with 3 decimals in millimetres (4 in
inches), rates with none in millimetres (1 in inches), settings with 3.
"""

from __future__ import annotations

from collections.abc import Iterable

from usbmotion.grbl.interface import MachineSettings, ModalState, WorkOffsets
from usbmotion.grbl.lines import MM_PER_INCH

GRBL_VERSION = "1.1h"
GRBL_BUILD_DATE = "20190825"
BANNER = f"Grbl {GRBL_VERSION} ['$' for help]"
HELP = "[HLP:$$ $# $G $I $N $x=val $Nx=line $J=line $SLP $C $X $H ~ ! ? ctrl-x]"
UNLOCK_HINT = "[MSG:'$H'|'$X' to unlock]"

AXIS_SETTING_BASES = (100, 110, 120, 130)
"""Steps (counts) per mm, max rate, acceleration, max travel: ``base + axis index``."""

NOT_APPLICABLE: dict[int, tuple[float, str]] = {
    0: (10, "step pulse time: servo axes take no step pulses"),
    1: (255, "step idle delay: servo axes hold position while enabled"),
    2: (0, "step pulse invert: servo axes take no step pulses"),
    3: (0, "step direction invert: set the axis direction in the machine file"),
    4: (0, "step enable invert: servo axes take no enable pin"),
    5: (0, "limit pins invert: set the switch polarity in the machine file"),
    6: (0, "probe pin invert: no probe input"),
    30: (1000, "maximum spindle speed: no spindle"),
    31: (0, "minimum spindle speed: no spindle"),
    32: (0, "laser mode: no laser output"),
}
"""grbl settings with no meaning on this machine: the value ``$$`` shows, and why."""

INTEGER_SETTINGS = frozenset({0, 1, 2, 3, 4, 5, 6, 10, 13, 20, 21, 22, 23, 26, 32, 30, 31})
"""Settings grbl prints without decimals (masks, booleans, milliseconds, RPM)."""


def coordinate(value_mm: float, *, inches: bool = False) -> str:
    """One coordinate as grbl prints it (no negative zero)."""
    text = f"{value_mm / MM_PER_INCH:.4f}" if inches else f"{value_mm:.3f}"
    return text[1:] if text.startswith("-") and float(text) == 0 else text


def coordinates(values_mm: Iterable[float], *, inches: bool = False, axes: str = "") -> str:
    """Comma-separated coordinates; those of the rotary axes among ``axes`` (one letter a
    value) are degrees, never inches (grblHAL's way: ``MPos:x,y,z,a``)."""
    return ",".join(
        coordinate(value, inches=inches and not (index < len(axes) and axes[index] in "ABC"))
        for index, value in enumerate(values_mm))


def rate(value_mm_min: float, *, inches: bool = False) -> str:
    """A feed rate as grbl prints it."""
    if inches:
        return f"{value_mm_min / MM_PER_INCH:.1f}"
    return f"{round(value_mm_min) + 0:d}"


def setting_value(number: int, value: float) -> str:
    """A setting's value as ``$$`` prints it."""
    if number in INTEGER_SETTINGS and (number != 0 or value == round(value)):
        return f"{round(value):d}"  # $0: a stepper driver's pulse may be under a microsecond
    return f"{value:.3f}"


def machine_setting_values(settings: MachineSettings) -> dict[int, float]:
    """The ``$N`` numbers the machine's settings fill, and their values."""
    values: dict[int, float] = {
        11: settings.junction_deviation_mm,
        12: settings.arc_tolerance_mm,
        20: float(settings.soft_limits),
        21: float(settings.hard_limits),
        22: float(settings.homing),
        23: float(settings.homing_dir_mask),
        24: settings.homing_feed_mm_min,
        25: settings.homing_seek_mm_min,
        26: float(settings.homing_debounce_ms),
        27: settings.homing_pull_off_mm,
    }
    for index, axis in enumerate(settings.axes):
        values[100 + index] = axis.counts_per_mm
        values[110 + index] = axis.max_rate_mm_min
        values[120 + index] = axis.accel_mm_s2
        values[130 + index] = axis.max_travel_mm
    values.update(settings.extra)
    return values


def settings_lines(settings: MachineSettings, *, report_mask: int,
                   report_inches: bool) -> list[str]:
    """The ``$$`` print-out, in grbl's order."""
    values = {number: value for number, (value, _) in NOT_APPLICABLE.items()}
    values[10] = report_mask
    values[13] = float(report_inches)
    values.update(machine_setting_values(settings))
    return [f"${number}={setting_value(number, values[number])}" for number in sorted(values)]


def parameter_lines(offsets: WorkOffsets, *, inches: bool = False) -> list[str]:
    """The ``$#`` print-out."""
    names = ("G54", "G55", "G56", "G57", "G58", "G59")
    lines = [f"[{name}:{coordinates(values, inches=inches)}]"
             for name, values in zip(names, offsets.coordinate_systems, strict=True)]
    lines.append(f"[G28:{coordinates(offsets.g28, inches=inches)}]")
    lines.append(f"[G30:{coordinates(offsets.g30, inches=inches)}]")
    lines.append(f"[G92:{coordinates(offsets.g92, inches=inches)}]")
    lines.append(f"[TLO:{coordinate(offsets.tool_length_offset, inches=inches)}]")
    lines.append(probe_line(offsets, inches=inches))
    return lines


def probe_line(offsets: WorkOffsets, *, inches: bool = False) -> str:
    """``[PRB:x,y,z:1]``: the last probe's position (machine coordinates; zeros before any)
    and whether it touched, as ``$#`` and a probing line's answer print it."""
    probe = offsets.probe or (0.0,) * len(offsets.g92)
    return f"[PRB:{coordinates(probe, inches=inches)}:{int(offsets.probe_succeeded)}]"


def modal_line(modal: ModalState) -> str:
    """The ``$G`` line: ``[GC:G0 G54 G17 G21 G90 G94 M5 M9 T0 F0 S0]``."""
    words = [modal.motion, modal.coordinate_system, modal.plane, modal.units,
             modal.distance, modal.feed_rate_mode]
    if modal.program is not None:
        words.append(modal.program)
    words += [modal.spindle, modal.coolant, f"T{modal.tool}",
              f"F{_modal_number(modal.feed)}", f"S{_modal_number(modal.spindle_speed)}"]
    return f"[GC:{' '.join(words)}]"


def _modal_number(value: float) -> str:
    return f"{round(value):d}" if value == round(value) else f"{value:.1f}"


def build_info_lines(user_text: str, *, planner_blocks: int, rx_buffer_bytes: int) -> list[str]:
    """The ``$I`` print-out: version and build date, then the build options (V variable
    spindle reporting, N line numbers; ``*$#``: no ``$RST``), planner blocks, RX bytes."""
    return [f"[VER:{GRBL_VERSION}.{GRBL_BUILD_DATE}:{user_text}]",
            f"[OPT:VN*$#,{planner_blocks},{rx_buffer_bytes}]"]


def message(text: str) -> str:
    """A ``[MSG:...]`` line carrying ``text`` safely (one line, no closing bracket)."""
    flat = " ".join(text.replace("]", ")").replace("[", "(").split())
    return f"[MSG:{flat.encode('ascii', 'replace').decode('ascii')}]"
