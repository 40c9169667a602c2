"""``usbmotion console``: seed 003's serial console, interactive or with piped input."""

from __future__ import annotations

import select
import sys

import typer

from usbmotion.cli.connect import connect_any
from usbmotion.cli.exits import EXIT_FAULT
from usbmotion.cli.machines import MachineOption, load_machine
from usbmotion.cli.signals import stop_on_signals
from usbmotion.errors import UsbMotionError


def console(
    machine: MachineOption = None,
) -> None:
    """Drive the machine from a console: MDI, jog, hold and resume, $c cycle start.

    Reads one command per line from standard input (a prompt is shown on a
    terminal) until end of input or $q; $h lists the commands. The machine moves
    while the console reads on: a G-code line runs at once (MDI; lines written
    while it moves are streamed after), ! holds, ~ resumes a hold or a pause
    (M0, M1, M6), Ctrl-X or $x stops, $j jogs, $o sets the overrides, ? reports
    the state, the line and the positions. Ctrl-C while the machine moves stops
    it along its deceleration; at the prompt it leaves. While it waits it keeps
    the devices' watchdogs fed. At the end of input it waits for what runs; on
    leaving, the servos are disabled (the machine stays homed for the next host).
    """
    from usbmotion.console import Console  # noqa: PLC0415 - keep --help fast

    config = load_machine(machine, "console")
    interactive = sys.stdin.isatty()

    def write(line: str) -> None:
        sys.stdout.write(line + "\n")
        sys.stdout.flush()

    try:
        with connect_any(config) as session:
            for notice in session.notices:
                write(f"notice: {notice}")
            console_session = Console(session, write)
            write(f"usbmotion console on {config.name}: $h for help")
            keep_alive_s = session.keep_alive_period_s() or 1.0
            operator = console_session.operator
            while True:
                if interactive:
                    sys.stdout.write("> ")
                    sys.stdout.flush()
                try:
                    while not select.select([sys.stdin], [], [], keep_alive_s)[0]:
                        operator.keep_alive()
                    line = sys.stdin.readline()
                except KeyboardInterrupt:
                    if console_session.stop():
                        continue
                    break
                if not line:
                    break
                if not console_session.handle(line):
                    break
            with stop_on_signals(session):
                console_session.close()
            try:
                session.shutdown()
            except UsbMotionError as error:
                write(f"error: stopping the machine: {error}")
    except UsbMotionError as error:
        typer.echo(f"usbmotion console: {error}", err=True)
        raise typer.Exit(EXIT_FAULT) from None
