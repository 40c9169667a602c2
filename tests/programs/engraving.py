"""A generated engraving, as a web CAM tool writes one: thousands of short feed moves
(0.1 to 0.5 mm, a wandering stroke), a lift, a rapid and a plunge between strokes."""

from __future__ import annotations

import math
import random


def engraving(moves: int, *, seed: int = 1, x0_mm: float = 60.0, y0_mm: float = 60.0,
              z_cut_mm: float = -5.0, z_safe_mm: float = -2.5, feed_mm_min: float = 600.0,
              stroke: int = 300, turn_rad: float = 0.6) -> list[str]:
    """The program's lines (``M2`` last): ``moves`` feed moves in strokes of ``stroke``,
    each turning by up to ``turn_rad`` from the one before, inside X and Y 20..180 mm,
    cutting at ``z_cut_mm``."""
    rng = random.Random(seed)
    lines = ["G21 G90 G17", f"G0 Z{z_safe_mm:.3f}", f"G0 X{x0_mm:.3f} Y{y0_mm:.3f}",
             f"G1 Z{z_cut_mm:.3f} F200"]
    x, y, heading = x0_mm, y0_mm, 0.0
    for index in range(moves):
        if index and index % stroke == 0:
            x = min(max(x + rng.uniform(-5.0, 5.0), 20.0), 180.0)
            y = min(max(y + rng.uniform(-5.0, 5.0), 20.0), 180.0)
            lines += [f"G0 Z{z_safe_mm:.3f}", f"G0 X{x:.3f} Y{y:.3f}",
                      f"G1 Z{z_cut_mm:.3f} F200"]
        heading += rng.uniform(-turn_rad, turn_rad)
        step = rng.uniform(0.1, 0.5)
        x = min(max(x + step * math.cos(heading), 20.0), 180.0)
        y = min(max(y + step * math.sin(heading), 20.0), 180.0)
        lines.append(f"G1 X{x:.3f} Y{y:.3f} F{feed_mm_min:g}")
    lines += [f"G0 Z{z_safe_mm:.3f}", "M2"]
    return lines
