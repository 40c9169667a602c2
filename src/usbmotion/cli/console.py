"""``usbmotion console``: seed 003's serial console, interactive or with piped input."""

from __future__ import annotations

import select
import sys

import typer

from usbmotion.cli.run import (
    EXIT_BAD_INPUT,
    EXIT_FAULT,
    MachineOption,
    load_machine,
    stop_on_signals,
)
from usbmotion.errors import ConfigError, UsbMotionError


def console(
    machine: MachineOption = None,
) -> None:
    """Drive the machine from a console: $c cycle start, $r reset and home, $d N demo.

    Reads one command per line from standard input (a prompt is shown on a
    terminal) until end of input or $q. $h lists the commands. Ctrl-C during a
    command brings every axis to rest along its deceleration and returns to
    the prompt; a second one stops at once. While it waits for a command it
    keeps the devices' watchdogs fed, so an enabled machine stays enabled. On
    leaving, the servos are disabled (the machine stays homed for the next
    host).
    """
    from usbmotion.console import Console  # noqa: PLC0415 - keep --help fast
    from usbmotion.session import MachineSession  # noqa: PLC0415
    from usbmotion.sim.machine import connect_session  # noqa: PLC0415

    try:
        config = load_machine(machine)
    except ConfigError as error:
        typer.echo(f"usbmotion console: {error}", err=True)
        raise typer.Exit(EXIT_BAD_INPUT) from None
    interactive = sys.stdin.isatty()

    def write(line: str) -> None:
        sys.stdout.write(line + "\n")
        sys.stdout.flush()

    try:
        with (connect_session(config) if config.is_simulated
              else MachineSession.connect(config)) as session:
            for notice in session.notices:
                write(f"notice: {notice}")
            console_session = Console(session, write)
            write(f"usbmotion console on {config.name}: $h for help")
            keep_alive_s = session.keep_alive_period_s()
            while True:
                if interactive:
                    sys.stdout.write("> ")
                    sys.stdout.flush()
                try:
                    while keep_alive_s and not select.select([sys.stdin], [], [],
                                                              keep_alive_s)[0]:
                        session.keep_alive()
                    line = sys.stdin.readline()
                except KeyboardInterrupt:
                    break
                if not line:
                    break
                with stop_on_signals(session):
                    going = console_session.handle(line)
                if not going:
                    break
            try:
                session.shutdown()
            except UsbMotionError as error:
                write(f"error: stopping the machine: {error}")
    except UsbMotionError as error:
        typer.echo(f"usbmotion console: {error}", err=True)
        raise typer.Exit(EXIT_FAULT) from None
