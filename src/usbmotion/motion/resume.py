"""Running a program from a line: the program as interpreted from its start, joined at line
``N`` by a safe re-entry from where the machine stands.

Every line before ``N`` has been interpreted (units, distance mode, work and tool offsets,
G92, the feed, the plane: the moves are at absolute machine positions), so the moves from
line ``N`` on are the very moves the uninterrupted program makes there. The re-entry, made
of moves numbered ``N`` (the line the operator asked for is the one shown while it runs):

1. up to the safe height at rapid (machine Z, where homing leaves Z: the top of its travel,
   as Z homes up), unless the machine already stands at or above it;
2. at rapid, at that height, above the point the program stands at before line ``N``;
3. down to that point at the feed of the first feed move from line ``N`` on (when the rest
   of the program has none, at the descent feed the caller gives).

No re-entry rapid moves below the safe height but the retract straight up from where the
machine stands.

A machine without Z (a plotter, a laser table) goes straight to that point at rapid.
"""

from __future__ import annotations

import math
from dataclasses import replace

from usbmotion.errors import ArgumentError
from usbmotion.motion.gcode import GCodeProgram, Pause
from usbmotion.motion.moves import Arc, Dwell, Linear, Move, Point, Rapid, start_of


def first_move_from(program: GCodeProgram, line: int) -> int:
    """The index of the program's first move on line ``line`` or after it.

    Raises:
        ArgumentError: ``line`` is not a line of the program, or no move follows it.
    """
    last = program.end_line or max((move.line for move in program.moves), default=0)
    if isinstance(line, bool) or not isinstance(line, int) or not 1 <= line <= max(last, 1):
        raise ArgumentError(f"from line {line!r}: allowed 1..{max(last, 1)} (the lines of"
                            f" {program.file})", reason="from_line")
    for index, move in enumerate(program.moves):
        if move.line >= line:
            return index
    raise ArgumentError(f"from line {line}: {program.file} makes no move from there to its"
                        f" end (line {last}): nothing to run", reason="from_line")


def reentry_moves(here: Point, target: Point, *, line: int, axes: str,
                  safe_z_mm: float | None, feed_mm_min: float) -> list[Move]:
    """The safe re-entry from ``here`` to ``target`` (machine mm, one per axis of ``axes``),
    numbered ``line`` (see the module's docstring); moves of no length are left out.

    Raises:
        ArgumentError: a position or the safe height is not finite, or the feed is not
            positive.
    """
    for name, point in (("here", here), ("target", target)):
        if len(point) != len(axes) or not all(math.isfinite(value) for value in point):
            raise ArgumentError(f"{name} {point!r}: one finite coordinate per axis of {axes}",
                                reason="position")
    if safe_z_mm is not None and not math.isfinite(safe_z_mm):
        raise ArgumentError(f"safe Z {safe_z_mm!r} mm: not a finite number", reason="safe_z")
    if not (math.isfinite(feed_mm_min) and feed_mm_min > 0):
        raise ArgumentError(f"re-entry feed {feed_mm_min!r} mm/min: a positive number",
                            reason="feed")
    moves: list[Move] = []

    def go(end: Point, feed: float | None) -> None:
        start = moves[-1].end if moves else here  # type: ignore[union-attr]
        if end == start:
            return
        moves.append(Rapid(line, start, end) if feed is None else
                     Linear(line, start, end, feed))

    z = axes.find("Z")
    if z < 0 or safe_z_mm is None:
        go(tuple(target), None)
        return moves
    travel_z = max(here[z], safe_z_mm)
    go(_with(here, z, travel_z), None)
    go(_with(target, z, travel_z), None)
    go(tuple(target), feed_mm_min)
    return moves


def resume_from_line(program: GCodeProgram, line: int, *, here: Point,
                     safe_z_mm: float | None, descent_feed_mm_min: float) -> GCodeProgram:
    """``program`` run from line ``line`` with the machine at ``here`` (machine mm): the
    re-entry (descending at ``descent_feed_mm_min`` when no feed move follows), then the
    program's own moves from that line on; its pauses, tool changes, ignored words and
    offset frames from that line on, renumbered to the new moves.

    Raises:
        ArgumentError: as :func:`first_move_from` and :func:`reentry_moves`.
    """
    first = first_move_from(program, line)
    rest = program.moves[first:]
    feed = next((move.feed_mm_min for move in rest if isinstance(move, Linear | Arc)),
                descent_feed_mm_min)
    entry = reentry_moves(here, start_of(rest[0]), line=line, axes=program.axes,
                          safe_z_mm=safe_z_mm, feed_mm_min=feed)
    # The spindle as the lines before leave it, started before the re-entry goes over and
    # down (LinuxCNC's run from a line restores it): after the retract straight up.
    spun = [pause for pause in program.pauses
            if pause.move < first and pause.spindle_rpm is not None]
    spindle: list[Pause] = []
    if spun and spun[-1].spindle_rpm:
        z = program.axes.find("Z")
        retract = entry[0] if entry else None
        up = (z >= 0 and isinstance(retract, Rapid) and retract.end[z] > here[z]
              and retract.end == _with(here, z, retract.end[z]))
        at = 1 if up else 0
        where = start_of(entry[at]) if at < len(entry) else start_of(rest[0])
        entry.insert(at, Dwell(line, where, 0.0))
        rpm = spun[-1].spindle_rpm
        spindle.append(Pause(line, spun[-1].code, f"spindle to {abs(rpm):g} rpm"
                             + (" counter-clockwise" if rpm < 0 else "")
                             + f" (as line {spun[-1].line} left it)", at, rpm))
    shift = len(entry) - first
    frames: list[tuple[int, Point]] = []
    for index, offset in program.frames:
        if index <= first:
            frames[:] = [(0, offset)]
        else:
            frames.append((index + shift, offset))
    return replace(
        program,
        moves=(*entry, *rest),
        pauses=(*spindle, *(replace(pause, move=pause.move + shift)
                            for pause in program.pauses if pause.move >= first)),
        tool_changes=tuple(change for change in program.tool_changes if change.line >= line),
        ignored=tuple(word for word in program.ignored if word.line >= line),
        frames=tuple(frames),
    )


def _with(point: Point, index: int, value: float) -> Point:
    return (*point[:index], value, *point[index + 1:])


__all__ = ["first_move_from", "reentry_moves", "resume_from_line"]
