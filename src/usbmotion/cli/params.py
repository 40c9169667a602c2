"""``usbmotion get`` and ``usbmotion set``: a device's parameters by name."""

from __future__ import annotations

from typing import TYPE_CHECKING, Annotated, NoReturn

import typer

from usbmotion.cli.connect import SIMULATED_NOTE, opened_machine
from usbmotion.cli.exits import EXIT_BAD_INPUT, EXIT_FAULT, fail
from usbmotion.cli.machines import MachineOption, load_machine
from usbmotion.errors import ArgumentError, OutOfRangeError, UsbMotionError

if TYPE_CHECKING:
    from usbmotion.host.config import MachineConfig
    from usbmotion.host.machine import Axis
    from usbmotion.host.parameters import Parameter

STORAGE_NOTE = (
    "RAM values are lost at power-off, and usbmotion run, home, jog and console set them"
    " again from the machine file when they take the machine over; flash values (name,"
    " default_mode) are kept across power cycles."
)


def _axes(config: MachineConfig, axis: str | None, command: str) -> list[str]:
    if axis is None:
        return list(config.axis_names)
    letter = axis.upper()
    if letter not in config.axis_names:
        fail(command, f"no axis {axis!r}; {config.path} has {', '.join(config.axis_names)}",
             EXIT_BAD_INPUT)
    return [letter]


def _parameter(name: str, command: str) -> Parameter:
    from usbmotion.host.parameters import parameter  # noqa: PLC0415 - keeps --help fast

    try:
        return parameter(name)
    except ArgumentError as error:
        fail(command, str(error), EXIT_BAD_INPUT)


def _row(axis: Axis, each: Parameter, *, listing: bool = False) -> str:
    value = each.read(axis.client)
    shown = repr(value) if each.name == "name" else value
    if listing:
        return (f"  {each.name:<28} {f'{shown} {each.unit}'.rstrip():<22}"
                f" {each.storage.value:<6} {each.meaning}")
    return f"{axis.name} {each.name} {shown} {each.unit}".rstrip()


def get(
    axis: Annotated[str | None, typer.Argument(
        help="The axis (X, Y, Z ...); every axis when omitted.", show_default=False)] = None,
    name: Annotated[str | None, typer.Argument(
        help="The parameter; every parameter when omitted.", show_default=False)] = None,
    machine: MachineOption = None,
) -> None:
    """Print device parameters by name, with their units, as each device holds them.

    The parameters: kp, ki, kd (the PID's gains), watchdog_ms, following_error_limit_counts,
    servo_interval_us, motion_scalar, diagnostics_interval_ticks, control_mode, and in
    flash default_mode and name (the device name as text). Without a name every
    parameter is listed with its storage (RAM or flash) and what it is.

    Exit status: 0 read; 1 a port could not be opened or a device did not answer; 2 an
    unknown axis or parameter, or a bad machine file.
    """
    from usbmotion.host.parameters import PARAMETERS  # noqa: PLC0415

    config = load_machine(machine, "get")
    if axis is not None and name is None and axis.upper() not in config.axis_names \
            and len(axis) > 1:
        axis, name = None, axis
    letters = _axes(config, axis, "get")
    chosen = [_parameter(name, "get")] if name is not None else list(PARAMETERS)
    with opened_machine(config, "get") as opened:
        try:
            for letter in letters:
                each_axis = opened.axis(letter)
                if name is None:
                    typer.echo(f"axis {letter}: {each_axis.config.label} on {each_axis.url}")
                for each in chosen:
                    typer.echo(_row(each_axis, each, listing=name is None))
        except UsbMotionError as error:
            fail("get", str(error), EXIT_FAULT)
    if name is None:
        typer.echo(STORAGE_NOTE)


get.__doc__ = f"{get.__doc__}\n    {SIMULATED_NOTE}\n"


def set_parameter(
    axis: Annotated[str, typer.Argument(help="The axis (X, Y, Z ...).", show_default=False)],
    name: Annotated[str, typer.Argument(help="The parameter (usbmotion get lists them).",
                                        show_default=False)],
    value: Annotated[str, typer.Argument(
        help="Its new value: a number in the parameter's unit, a mode word (position,"
        " velocity, curve), or the device name as text.", show_default=False)],
    machine: MachineOption = None,
) -> None:
    """Set one device parameter by name, checked against its allowed range first.

    Prints the value the device then answers with, and whether it is kept in flash or RAM.

    A value outside the parameter's range is refused before anything is sent, naming
    the parameter, the value and what is allowed; so is a value the machine file would
    refuse (a watchdog_ms shorter than a full motion queue lasts, say), with the file's
    reason.

    Exit status: 0 set; 1 a port could not be opened or a device refused or did not
    answer; 2 an unknown axis or parameter, a value that is refused, or a bad machine
    file.
    """
    from usbmotion.host.parameters import Storage, machine_file_problem  # noqa: PLC0415
    from usbmotion.sim.urls import URL_CHECKS  # noqa: PLC0415 - the sim:// checks alone

    config = load_machine(machine, "set")
    (letter,) = _axes(config, axis, "set")
    each = _parameter(name, "set")

    def refused(message: str) -> NoReturn:
        if "allowed" not in message:
            message += f"; allowed {each.allowed}"
        fail("set", f"axis {letter} {name} {value!r} refused: {message}", EXIT_BAD_INPUT)

    try:
        each.check(value)
    except (ArgumentError, OutOfRangeError) as error:
        refused(str(error))
    with opened_machine(config, "set") as opened:
        target = opened.axis(letter)
        try:
            problem = machine_file_problem(config, target.config, target.client, each, value,
                                           url_checks=URL_CHECKS)
        except UsbMotionError as error:
            fail("set", str(error), EXIT_FAULT)
        if problem is not None:
            fail("set", f"axis {letter} {name} {value!r} refused as the machine file would"
                 f" refuse it: {problem}", EXIT_BAD_INPUT)
        try:
            each.write(target.client, value)
        except (ArgumentError, OutOfRangeError) as error:
            refused(str(error))
        except UsbMotionError as error:
            fail("set", str(error), EXIT_FAULT)
        try:
            row = _row(target, each)
        except UsbMotionError as error:
            fail("set", f"set, but reading it back failed: {error}", EXIT_FAULT)
    kept = ("kept in flash" if each.storage is Storage.FLASH else
            "RAM: lost at power-off, and set again from the machine file when usbmotion run,"
            " home, jog or console takes the machine over")
    typer.echo(f"{row} ({kept})")


set_parameter.__doc__ = f"{set_parameter.__doc__}\n    {SIMULATED_NOTE}\n"
