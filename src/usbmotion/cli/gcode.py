"""``usbmotion gcode``: what a G-code program does, before anything moves."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Annotated

import typer

from usbmotion.cli.exits import fail, os_problem
from usbmotion.cli.help import UsbMotionTyper
from usbmotion.motion.gcode import (
    GCodeProgram,
    distinct_ignored,
    ignored_kind_label,
    interpret_until_error,
    move_record,
    read_gcode_text,
)

gcode_app = UsbMotionTyper(
    name="gcode",
    help="Interpret G-code programs (RS274/NGC, as LinuxCNC reads them).",
    no_args_is_help=True,
    add_completion=False,
)

_EXIT_INVALID_PROGRAM = 1
_EXIT_UNREADABLE_FILE = 2


@gcode_app.callback()
def _gcode() -> None:
    """Interpret G-code programs (RS274/NGC, as LinuxCNC reads them)."""


@gcode_app.command("moves")
def moves(
    file: Annotated[Path, typer.Argument(help="The G-code program.", show_default=False)],
    quiet: Annotated[
        bool, typer.Option("--quiet", "-q", help="Do not list the ignored words on stderr.")
    ] = False,
) -> None:
    """Print a program's moves as JSON lines: mm, mm/min, absolute machine positions.

    One object per move: line, type (rapid, linear, arc, dwell), start and end; feed for
    linear and arc moves; plane, direction, rotation and centre for arcs; seconds for
    dwells. Words that do not move the machine are listed on stderr. An invalid program
    prints the moves before the error, then FILE:LINE: message on stderr, and exits 1.
    """
    try:
        text = read_gcode_text(file)
    except OSError as exc:
        fail("gcode moves", f"cannot read {file}: {os_problem(exc)}", _EXIT_UNREADABLE_FILE)
    program, error = interpret_until_error(text, file=str(file))
    _write_moves(program)
    if not quiet:
        for note in _ignored_notes(program):
            typer.echo(note, err=True)
    if error is not None:
        where = f" (column {error.column})" if error.column else ""
        typer.echo(f"{error.file}:{error.line}: {error.message}{where}", err=True)
        raise typer.Exit(_EXIT_INVALID_PROGRAM)


def _write_moves(program: GCodeProgram) -> None:
    dumps = json.dumps
    out = sys.stdout
    batch: list[str] = []
    for move in program.moves:
        batch.append(dumps(move_record(move)))
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
