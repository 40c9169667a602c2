"""Jogs as programs: the G-code line a jog is (machine or work coordinates, incremental or
absolute, or continuous to the first soft limit on its way), checked first. Pure functions:
where the machine stands is the session's to say."""

from __future__ import annotations

import math
from collections.abc import Mapping

from usbmotion.errors import ArgumentError
from usbmotion.host.config import MachineConfig


def check_jog(moves: Mapping[str, float], feed_mm_min: float, axes: str) -> None:
    """Raise unless ``moves`` names only program axes with finite values and the feed is a
    speed.

    Raises:
        ArgumentError: an axis the machine does not have, a value or feed that is not
            finite (the feed positive), no axis at all.
    """
    for name, value in moves.items():
        if name not in axes:
            raise ArgumentError(f"jog axis {name!r}: allowed {', '.join(axes)}", reason="jog")
        if not math.isfinite(value):
            raise ArgumentError(f"jog {name}{value!r}: not a finite number", reason="jog")
    if not moves:
        raise ArgumentError("a jog names at least one axis", reason="jog")
    if isinstance(feed_mm_min, bool) or not (math.isfinite(feed_mm_min) and feed_mm_min > 0):
        raise ArgumentError(f"jog feed {feed_mm_min!r} mm/min: a speed > 0", reason="feed")


def continuous_targets(config: MachineConfig, here: Mapping[str, float],
                       directions: Mapping[str, float]) -> dict[str, float]:
    """Where a continuous jog from ``here`` along ``directions`` meets the first soft limit.

    Raises:
        ArgumentError: no direction (every value 0).
    """
    length = math.sqrt(sum(v * v for v in directions.values()))
    if length == 0.0:
        raise ArgumentError("a continuous jog needs a direction: a value other than 0",
                            reason="jog")
    reach = math.inf
    for name, value in directions.items():
        if value:
            lower, upper = config.axis(name).travel_mm
            room = (upper - here[name]) if value > 0 else (here[name] - lower)
            reach = min(reach, max(0.0, room) / (abs(value) / length))
    return {name: here[name] + value / length * reach for name, value in directions.items()}


def jog_text(config: MachineConfig, here: Mapping[str, float], moves: Mapping[str, float], *,
             feed_mm_min: float, work: bool, absolute: bool, continuous: bool) -> str:
    """The program a jog runs (a feed move, then M2)."""
    words = dict(moves)
    if continuous:
        words = continuous_targets(config, here, moves)
        work, absolute = False, True
    mode = ("G90" if absolute else "G91") + ("" if work else " G53")
    if not absolute and not work:
        words = {name: here[name] + value for name, value in moves.items()}
        mode = "G90 G53"
    return (f"{mode} G1 " + " ".join(f"{name}{value:.6f}" for name, value in words.items())
            + f" F{feed_mm_min:.6f}\nM2\n")
