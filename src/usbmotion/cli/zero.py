"""``usbmotion zero``: set the work origin (G54) where the machine stands, as a sender's zero
button does."""

from __future__ import annotations

from typing import Annotated

import typer

from usbmotion.cli.exits import EXIT_BAD_INPUT, EXIT_FAULT, fail
from usbmotion.cli.machines import MachineOption, load_machine
from usbmotion.errors import ConfigError, UsbMotionError
from usbmotion.motion.offsets import format_point


def zero(
    axes: Annotated[list[str] | None, typer.Argument(
        help="The axes to zero: X, Y, Z (those of the machine; default: all).",
        show_default=False)] = None,
    machine: MachineOption = None,
    no_home: Annotated[bool, typer.Option(
        "--no-home", help="Refuse rather than home a machine that is not homed.")] = False,
) -> None:
    """Set G54's origin to where the machine stands, for the named axes (all by default).

    The offset is kept in the machine's parameter file (LinuxCNC's parameters
    5221-5223), so the next `usbmotion run` puts program zero here. A machine
    that is not homed is homed first (its position means nothing before),
    unless --no-home, which refuses instead.

    Exit status: 0 set; 1 a device fault or failed homing; 2 a bad axis or
    machine file, or not homed with --no-home.
    """
    from usbmotion.session import MachineSession  # noqa: PLC0415
    from usbmotion.session.planning import program_axes  # noqa: PLC0415
    from usbmotion.sim.machine import connect_session  # noqa: PLC0415

    config = load_machine(machine, "zero")
    try:
        machine_letters = program_axes(config)
    except ConfigError as error:
        fail("zero", str(error), EXIT_BAD_INPUT)
    names = [name.upper() for name in axes or machine_letters]
    for name in names:
        if name not in machine_letters:
            fail("zero", f"no axis {name!r}; {config.path} has {', '.join(machine_letters)}",
                 EXIT_BAD_INPUT)
    try:
        with (connect_session(config) if config.is_simulated
              else MachineSession.connect(config)) as session:
            if not session.is_homed:
                if no_home:
                    typer.echo("usbmotion zero: the machine is not homed, so its position means"
                               " nothing; home it (usbmotion run homes it) or drop --no-home",
                               err=True)
                    raise typer.Exit(EXIT_BAD_INPUT)
                session.home()
            where = session.positions_mm()
            offsets = session.set_work_origin({name: where[name] for name in names})
            session.shutdown()
    except ConfigError as error:
        typer.echo(f"usbmotion zero: {error}", err=True)
        raise typer.Exit(EXIT_BAD_INPUT) from None
    except UsbMotionError as error:
        typer.echo(f"usbmotion zero: {error}", err=True)
        raise typer.Exit(EXIT_FAULT) from None
    origin = "  ".join(format_point(offsets.g5x[0], a, separator=" ") for a in machine_letters)
    typer.echo(f"G54 origin {origin} mm (machine); {', '.join(names)} set here;"
               f" saved in {config.parameter_path}")
