"""``usbmotion gcode``: what a G-code program does, before anything moves."""

from __future__ import annotations

import json
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, NoReturn

import typer

from usbmotion.cli.exits import EXIT_BAD_INPUT, fail, os_problem
from usbmotion.cli.help import UsbMotionTyper
from usbmotion.errors import ConfigError
from usbmotion.motion.dialects import Dialect, declared_dialect, dialect_named
from usbmotion.motion.gcode import (
    DEFAULT_MACHINE,
    GCodeProgram,
    MachineAxes,
    distinct_ignored,
    ignored_kind_label,
    interpret_until_error,
    move_record,
    read_gcode_text,
)
from usbmotion.motion.offsets import NO_OFFSETS, WorkOffsets
from usbmotion.motion.tools import NO_TOOLS, ToolTable

if TYPE_CHECKING:
    from usbmotion.motion.moves import Point

gcode_app = UsbMotionTyper(
    name="gcode",
    help="Interpret G-code programs (RS274/NGC as LinuxCNC reads them, or grbl's or Marlin's).",
    no_args_is_help=True,
    add_completion=False,
)

_COMMAND = "gcode moves"
_EXIT_INVALID_PROGRAM = 1


@gcode_app.callback()
def _gcode() -> None:
    """Interpret G-code programs (RS274/NGC as LinuxCNC reads them, or grbl's or Marlin's)."""


@dataclass(frozen=True, slots=True)
class _Reading:
    """How a program is read: for a machine file's machine, or for the default one
    (``start`` None: at 0 on every axis)."""

    machine: MachineAxes
    dialect: Dialect
    tools: ToolTable
    offsets: WorkOffsets
    start: Point | None


@gcode_app.command("moves")
def moves(
    file: Annotated[Path, typer.Argument(help="The G-code program.", show_default=False)],
    machine: Annotated[Path | None, typer.Option(
        "--machine", "-m", help="Machine file: read the program as that machine runs it"
        " (default: none; see below).")] = None,
    dialect: Annotated[str | None, typer.Option(
        "--dialect", help="Read the program as linuxcnc, grbl or marlin reads it (default:"
        " the machine file's dialect; linuxcnc without --machine).")] = None,
    quiet: Annotated[
        bool, typer.Option("--quiet", "-q", help="Do not list the ignored words on stderr.")
    ] = False,
) -> None:
    """Print a program's moves as JSON lines: mm, mm/min, machine positions.

    One JSON object per move, in program order, each with the line it comes from. A rapid,
    a linear move and an arc have start and end; linear moves and arcs add feed (mm/min);
    an arc adds plane (XY, XZ or YZ), direction (cw or ccw), rotation (turns, negative
    clockwise) and centre (null along the plane's normal axis). A dwell has position and
    seconds. Every point holds one coordinate per axis of the machine, in X Y Z U V W order.

    With --machine the program is read as that machine runs it: its axes, its dialect, its
    tool table and the work offsets of its parameter file, starting where homing leaves
    it. Without --machine: axes X Y Z, the linuxcnc dialect, no tool table (every tool of
    length 0), every work offset 0 in G54, starting at 0 on every axis, so machine
    positions are the program's own.

    Words that do not move the machine are listed on stderr, one line per kind. An
    invalid program prints the moves before the error, then FILE:LINE: message (column N)
    on stderr, and exits 1. An unreadable program, an invalid machine file, tool table or
    parameter file, or an unknown dialect is one line on stderr and exit status 2.
    """
    chosen = _dialect(dialect)
    reading = _reading(machine, chosen)
    try:
        text = read_gcode_text(file)
    except OSError as exc:
        _fail(f"cannot read {file}: {os_problem(exc)}")
    program, error = interpret_until_error(
        text, file=str(file), start=reading.start, machine=reading.machine,
        dialect=reading.dialect, tools=reading.tools, offsets=reading.offsets)
    _write_moves(program)
    if not quiet:
        for note in _ignored_notes(program):
            typer.echo(note, err=True)
    if error is not None:
        where = f" (column {error.column})" if error.column else ""
        typer.echo(f"{error.file}:{error.line}: {error.message}{where}", err=True)
        hint = dialect_hint(text, reading.dialect)
        if hint is not None:
            typer.echo(hint, err=True)
        raise typer.Exit(_EXIT_INVALID_PROGRAM)


def dialect_hint(text: str, reading: Dialect) -> str | None:
    """For a program that failed read as ``reading`` reads it: the line that says which
    dialect its own comments name, when that is another (a slicer's file read as LinuxCNC
    reads G-code), else None."""
    declared = declared_dialect(text)
    if declared is None or declared.dialect is reading:
        return None
    name = declared.dialect.value
    return (f"hint: the program says it was written for {name} ({declared.words!r}, line"
            f" {declared.line}), and was read as {reading.value} reads G-code: read it with"
            f" --dialect {name}, or give the machine file dialect = \"{name}\"")


def _fail(message: str) -> NoReturn:
    """End the command with one line on stderr and status 2 (bad input)."""
    fail(_COMMAND, message, EXIT_BAD_INPUT)


def _dialect(name: str | None) -> Dialect | None:
    if name is None:
        return None
    try:
        return dialect_named(name)
    except ValueError as error:
        _fail(f"--dialect: {error}")


def _reading(machine: Path | None, dialect: Dialect | None) -> _Reading:
    """The machine file's axes, dialect (``dialect`` when given), tool table and work
    offsets, from where homing leaves it; or the default reading without a machine file."""
    if machine is None:
        return _Reading(DEFAULT_MACHINE, dialect or Dialect.LINUXCNC, NO_TOOLS, NO_OFFSETS,
                        None)
    from usbmotion.cli.machines import load_machine  # noqa: PLC0415 - keeps --help fast
    from usbmotion.motion.offsets import read_parameter_file  # noqa: PLC0415
    from usbmotion.motion.tools import load_tool_table  # noqa: PLC0415
    from usbmotion.session.planning import machine_axes, machine_dialect  # noqa: PLC0415

    config = load_machine(machine, _COMMAND)
    try:
        axes = machine_axes(config)
        tools = load_tool_table(config.tool_table) if config.tool_table else NO_TOOLS
        offsets = read_parameter_file(config.parameter_path)
    except ConfigError as error:
        _fail(str(error))
    return _Reading(axes, machine_dialect(config, dialect), tools, offsets, axes.home_mm)


def _write_moves(program: GCodeProgram) -> None:
    dumps = json.dumps
    out = sys.stdout
    axes = program.axes
    batch: list[str] = []
    for move in program.moves:
        batch.append(dumps(move_record(move, axes=axes)))
        if len(batch) == 1024:
            out.write("\n".join(batch) + "\n")
            batch.clear()
    if batch:
        out.write("\n".join(batch) + "\n")
    out.flush()


def _ignored_notes(program: GCodeProgram) -> list[str]:
    """One line per kind of ignored word, at its first use, with how often it occurs."""
    notes = []
    for word, count in distinct_ignored(program.ignored):
        times = f", {count} times" if count > 1 else ""
        notes.append(
            f"{program.file}:{word.line}: ignored {ignored_kind_label(word.word, count)}"
            f" ({word.meaning}; does not move "
            f"the machine){times}"
        )
    return notes
