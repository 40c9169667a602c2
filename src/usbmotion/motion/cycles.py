"""Canned drilling cycles (G73 G81 G82 G83 G85 G89) expanded into straight moves, as
LinuxCNC's interpreter expands them (``interp_cycles.cc``).

Pure geometry in program coordinates (mm): the interpreter resolves the words (absolute or
incremental, the plane, the series' initial level) into a :class:`Cycle` and maps the
points :func:`expand_cycle` returns to machine coordinates. In the plane's terms, the hole
is at (first, second) and the tool moves along the normal axis: Z in G17, Y in G18, X in G19.

- Before the holes, when the series' initial level is below R, a rapid straight up to R.
- The clearance level is R in G99; in G98 the series' initial level, or R when R is higher.
- The first hole: when the tool stands above R, a rapid to the hole at that level, then down
  to R; otherwise one rapid to the hole at the clearance level (XY and Z together when the
  tool stands lower), then down to R when the clearance level is above it. Further holes
  start from the clearance level the same way. Then the cycle's own moves, ending at the
  clearance level.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from usbmotion.motion.gcode_codes import GCode

__all__ = ["CHIP_BREAK_MM", "CYCLE_NAMES", "Cycle", "CycleStep", "expand_cycle"]

CHIP_BREAK_MM = 0.254
"""G73's retract between pecks, and G83's stop above the depth reached: 0.010 inch, in G21
too."""

CYCLE_NAMES: dict[int, str] = {
    code: code.text
    for code in (GCode.G_73, GCode.G_81, GCode.G_82, GCode.G_83, GCode.G_85, GCode.G_89)
}
"""The supported cycles, by G code."""

RAPID, FEED, DWELL = 0, 1, 2

_Go = Callable[[int, float, float, float], None]


@dataclass(frozen=True, slots=True)
class CycleStep:
    """One move of a cycle: ``kind`` RAPID or FEED to ``point`` (program mm), or a DWELL of
    ``seconds`` where the tool stands."""

    kind: int
    point: tuple[float, ...]
    seconds: float = 0.0


@dataclass(frozen=True, slots=True)
class Cycle:
    """A cycle block, resolved.

    Fields:
        code: the cycle (``GCode.G_81``).
        axes: indices into a point of the machine's axes of the plane's first, second and
            normal (drill) axis.
        start: where the tool stands (program mm, one value per axis of the machine).
        hole: (first, second) of the first hole.
        step: (first, second) added for each further hole (zero in G90: L repeats in place).
        initial_mm: the series' initial level along the normal axis (where its first block
            started).
        r_mm: the retract level R along the normal axis; bottom_mm the bottom of the hole.
        clear_mm: the clearance level the tool returns to after each hole.
        repeats: L, the number of holes.
        peck_mm: Q, the peck depth (G73, G83).
        dwell_s: P, the dwell at the bottom (G82, G89).
    """

    code: GCode
    axes: tuple[int, int, int]
    start: tuple[float, ...]
    hole: tuple[float, float]
    step: tuple[float, float]
    initial_mm: float
    r_mm: float
    bottom_mm: float
    clear_mm: float
    repeats: int
    peck_mm: float = 0.0
    dwell_s: float = 0.0


def expand_cycle(cycle: Cycle) -> list[CycleStep]:
    """The moves of a cycle block, in order (zero-length ones included, as LinuxCNC makes
    them)."""
    first, second, normal = cycle.axes
    steps: list[CycleStep] = []
    here = list(cycle.start)

    def go(kind: int, a: float, b: float, c: float) -> None:
        here[first], here[second], here[normal] = a, b, c
        steps.append(CycleStep(kind, tuple(here)))

    r, clear = cycle.r_mm, cycle.clear_mm
    level = here[normal]
    if cycle.initial_mm < r:
        go(RAPID, here[first], here[second], r)
        level = r
    a, b = cycle.hole
    for repeat in range(cycle.repeats):
        if repeat:
            a += cycle.step[0]
            b += cycle.step[1]
        approach = level if level > r else clear
        go(RAPID, a, b, approach)
        if approach > r:
            go(RAPID, a, b, r)
        _body(cycle, steps, go, a, b)
        level = clear
    return steps


def _body(cycle: Cycle, steps: list[CycleStep], go: _Go, a: float, b: float) -> None:
    """The moves of one hole, from R down and back to the clearance level."""
    code, r, bottom, clear = cycle.code, cycle.r_mm, cycle.bottom_mm, cycle.clear_mm
    if code in (GCode.G_81, GCode.G_82):
        go(FEED, a, b, bottom)
        if code == GCode.G_82:
            steps.append(CycleStep(DWELL, steps[-1].point, cycle.dwell_s))
        go(RAPID, a, b, clear)
    elif code in (GCode.G_73, GCode.G_83):
        depth = r - cycle.peck_mm
        while depth > bottom:
            go(FEED, a, b, depth)
            if code == GCode.G_73:
                go(RAPID, a, b, depth + CHIP_BREAK_MM)
            else:
                go(RAPID, a, b, r)
                go(RAPID, a, b, depth + CHIP_BREAK_MM)
            depth -= cycle.peck_mm
        go(FEED, a, b, bottom)
        go(RAPID, a, b, clear)
    elif code == GCode.G_85:
        go(FEED, a, b, bottom)
        go(FEED, a, b, r)
        go(RAPID, a, b, clear)
    else:  # G89
        go(FEED, a, b, bottom)
        steps.append(CycleStep(DWELL, steps[-1].point, cycle.dwell_s))
        go(FEED, a, b, clear)


