"""Klipper's planner on the same moves: the peer of ``planner_speed.py``'s mixed program.

Klipper plans a G2/G3 as its ``gcode_arcs`` module does (``ArcSupport.planArc``: chords of
1 mm by default, each a G1) and every line through its look-ahead (``toolhead.Move`` and
``toolhead.LookAheadQueue``: junction speeds, the backward and forward passes, flushed as
``ToolHead.move`` flushes it). Both are pure Python; they are loaded from a Klipper checkout
(``--klipper PATH``, or ``KLIPPER_PATH``), used in place, with the modules ``toolhead.py``
imports for its MCU side (``mcu``, ``chelper``, ``kinematics.extruder``) stood in for by
empty ones while it loads: the planning calls none of them. What stays out: Klipper's
kinematic checks (its Z limits), the trapezoid queue and step generation (C), the G-code
parsing.

Get Klipper with ``git clone https://github.com/Klipper3d/klipper``.
"""

from __future__ import annotations

import importlib
import sys
import types
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from usbmotion.motion.moves import Arc, Dwell, Linear, Move, Rapid

_STAND_INS = ("mcu", "chelper", "kinematics", "kinematics.extruder")


@contextmanager
def _klippy_on_path(klippy: Path) -> Iterator[None]:
    saved = {name: sys.modules.get(name) for name in (*_STAND_INS, "toolhead", "extras",
                                                      "extras.gcode_arcs")}
    for name in _STAND_INS:
        sys.modules[name] = types.ModuleType(name)
    sys.path.insert(0, str(klippy))
    try:
        yield
    finally:
        sys.path.remove(str(klippy))
        for name, module in saved.items():
            if module is None:
                sys.modules.pop(name, None)
            else:
                sys.modules[name] = module


class KlipperPlanner:
    """Klipper's arc segmentation and look-ahead, loaded from a checkout.

    Raises:
        FileNotFoundError: ``path`` holds no ``klippy/toolhead.py``.
    """

    def __init__(self, path: Path, *, max_velocity: float, max_accel: float,
                 junction_deviation_mm: float, mm_per_arc_segment: float = 1.0) -> None:
        klippy = path / "klippy"
        if not (klippy / "toolhead.py").is_file():
            raise FileNotFoundError(f"{path}: no klippy/toolhead.py (a Klipper checkout)")
        with _klippy_on_path(klippy):
            toolhead = importlib.import_module("toolhead")
            arcs = importlib.import_module("extras.gcode_arcs")
        self.move_class: Any = toolhead.Move
        self.queue_class: Any = toolhead.LookAheadQueue
        self.version = _describe(path)
        self.toolhead = types.SimpleNamespace(
            max_velocity=max_velocity, max_accel=max_accel,
            junction_deviation=junction_deviation_mm, mcr_pseudo_accel=max_accel * 0.5,
            extra_axes=[])
        segments: list[list[float]] = []
        self._segments = segments
        gcode = types.SimpleNamespace(
            create_gcode_command=lambda _c, _l, params: params)
        gcode_move = types.SimpleNamespace(
            cmd_G1=lambda params: segments.append([params["X"], params["Y"], params["Z"]]))
        self._arcs: Any = types.SimpleNamespace(
            mm_per_arc_segment=mm_per_arc_segment, gcode=gcode, gcode_move=gcode_move)
        self._plan_arc: Callable[..., None] = arcs.ArcSupport.planArc
        self._no_words = types.SimpleNamespace(get_float=lambda _name, default: default)

    def plan(self, moves: list[Move]) -> int:
        """Plan ``moves`` as Klipper would; returns the number of moves its look-ahead
        planned (lines and arc chords)."""
        queue = self.queue_class()
        move_class, toolhead = self.move_class, self.toolhead
        planned = 0
        for move in moves:
            if isinstance(move, Dwell):
                continue
            if isinstance(move, Arc):
                first, second, normal = move.plane.axes
                start = move.start
                offset = (move.centre[first] - start[first], move.centre[second] - start[second])
                self._segments.clear()
                self._plan_arc(self._arcs, list(start), list(move.end), offset, move.clockwise,
                               self._no_words, True, first, second, normal)
                ends = list(self._segments)
                speed = move.feed_mm_min / 60.0
            else:
                ends = [list(move.end)]
                speed = (toolhead.max_velocity if isinstance(move, Rapid)
                         else move.feed_mm_min / 60.0)
                assert isinstance(move, Linear | Rapid)
            position = [*move.start, 0.0]
            for end in ends:
                target = [*end, 0.0]
                if queue.add_move(move_class(toolhead, position, target, speed)):
                    planned += len(queue.flush(lazy=True))
                position = target
        planned += len(queue.flush())
        return planned


def _describe(path: Path) -> str:
    head = path / ".git" / "HEAD"
    try:
        text = head.read_text(encoding="ascii").strip()
    except OSError:
        return str(path)
    if text.startswith("ref: "):
        ref = path / ".git" / text[5:]
        try:
            text = ref.read_text(encoding="ascii").strip()
        except OSError:
            return f"{path} ({text[5:]})"
    return f"{path} ({text[:10]})"
