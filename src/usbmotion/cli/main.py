"""Entry point of the ``usbmotion`` command; each sub-command lives in its own module."""

from __future__ import annotations

import typer

from usbmotion import __version__
from usbmotion.cli.console import console
from usbmotion.cli.gcode import gcode_app
from usbmotion.cli.run import run
from usbmotion.cli.sim import sim
from usbmotion.cli.tune import tune
from usbmotion.cli.zero import zero

app = typer.Typer(
    name="usbmotion",
    help="Closed-loop DC servo motion over USB serial: simulate, drive and test devices.",
    no_args_is_help=True,
    add_completion=False,
)


@app.callback()
def _root() -> None:
    """Closed-loop DC servo motion over USB serial."""


@app.command()
def version() -> None:
    """Print the package version."""
    typer.echo(__version__)


app.command()(run)
app.command()(console)
app.command()(tune)
app.command()(sim)
app.command()(zero)
app.add_typer(gcode_app, name="gcode")


def main() -> None:
    """Run the command line."""
    app()
