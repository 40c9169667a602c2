"""Entry point of the ``usbmotion`` command; each sub-command lives in its own module."""

from __future__ import annotations

import gc
import sys
from collections.abc import Sequence
from typing import Annotated, Any

import typer
from typer.main import get_command_name
from typer.models import CommandInfo

from usbmotion import __version__
from usbmotion.cli.console import console
from usbmotion.cli.devices import devices
from usbmotion.cli.exits import EXIT_FAULT, os_problem
from usbmotion.cli.gcode import gcode_app
from usbmotion.cli.grbl import grbl
from usbmotion.cli.help import UsbMotionTyper
from usbmotion.cli.jog import jog
from usbmotion.cli.name import name
from usbmotion.cli.params import get, set_parameter
from usbmotion.cli.play import play
from usbmotion.cli.run import run
from usbmotion.cli.sim import sim
from usbmotion.cli.status import home, status
from usbmotion.cli.tune import tune
from usbmotion.cli.web import web
from usbmotion.cli.zero import zero
from usbmotion.errors import UsbMotionError

_SETTINGS: dict[str, Any] = {
    "name": "usbmotion",
    "help": "Closed-loop DC servo motion over USB serial: simulate, drive and test devices.",
    "no_args_is_help": True,
    "add_completion": False,
}
app = UsbMotionTyper(**_SETTINGS)


def _print_version(asked: bool) -> None:
    if asked:
        typer.echo(__version__)
        raise typer.Exit()


@app.callback()
def _root(
    version: Annotated[bool, typer.Option(
        "--version", help="Print the package version and exit.", is_eager=True,
        callback=_print_version)] = False,
) -> None:
    """Closed-loop DC servo motion over USB serial."""


@app.command()
def version() -> None:
    """Print the package version."""
    typer.echo(__version__)


app.command()(run)
app.command()(play)
app.command()(console)
app.command()(tune)
app.command()(sim)
app.command()(grbl)
app.command()(web)
app.command()(zero)
app.command()(status)
app.command()(home)
app.command(context_settings={"ignore_unknown_options": True})(jog)
app.command()(get)
app.command(name="set", context_settings={"ignore_unknown_options": True})(set_parameter)
app.command()(devices)
app.command()(name)
app.add_typer(gcode_app, name="gcode")


def app_for(args: Sequence[str]) -> typer.Typer:
    """The application to run ``args`` with: when they begin with the name of a command,
    one that holds that command alone (the command-line library reads the parameters of
    every command it holds from its signature on every run, about 20 ms for all of them,
    and a command runs the same either way); else the whole application, whose help and
    errors name every command."""
    if not args or args[0].startswith("-"):
        return app
    commands = [info for info in app.registered_commands if _named(info) == args[0]]
    groups = [info for info in app.registered_groups if info.name == args[0]]
    if len(commands) + len(groups) != 1:
        return app
    alone = UsbMotionTyper(**_SETTINGS)
    alone.registered_callback = app.registered_callback
    alone.registered_commands = commands
    alone.registered_groups = groups
    return alone


def _named(command: CommandInfo) -> str | None:
    """The name a command is called by."""
    if command.name:
        return command.name
    return None if command.callback is None else get_command_name(command.callback.__name__)


def main() -> None:
    """Run the command line: an error of the package or the system that a command let
    through is one line, exit status 1, not a traceback (usage errors are one line and
    status 2: :class:`usbmotion.cli.help.UsbMotionGroup`).

    The process ends after it: its objects are frozen out of the garbage collector
    (``gc.freeze``) first, so the interpreter's last collection does not visit every
    object a run made (a third of a second after a long simulated run)."""
    try:
        app_for(sys.argv[1:])()
    except UsbMotionError as error:
        sys.stderr.write(f"usbmotion: {error}\n")
        sys.exit(EXIT_FAULT)
    except OSError as error:
        where = f"{error.filename}: " if error.filename else ""
        sys.stderr.write(f"usbmotion: {where}{os_problem(error)}\n")
        sys.exit(EXIT_FAULT)
    finally:
        gc.freeze()
