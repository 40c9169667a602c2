"""``usbmotion name``: give a device the name a machine file gives its axis, so the file
finds it from then on (a fresh board answers the default name until it is named)."""

from __future__ import annotations

from typing import TYPE_CHECKING, Annotated

import typer

from usbmotion.cli.exits import EXIT_BAD_INPUT, EXIT_FAULT, fail
from usbmotion.cli.machines import MachineOption, load_machine
from usbmotion.errors import UsbMotionError

if TYPE_CHECKING:
    from usbmotion.host.config import MachineConfig
    from usbmotion.host.discovery import PortAnswer


def name(
    axis: Annotated[str, typer.Argument(
        help="The axis (X, Y, Z ...) whose device name the machine file gives.",
        show_default=False)],
    port: Annotated[str | None, typer.Argument(
        help="The device's port or URL (a /dev/ttyACM port, a terminal usbmotion sim"
        " printed, socket://HOST:PORT); default: the one device found that answers the"
        " default name.", show_default=False)] = None,
    machine: MachineOption = None,
    timeout_s: Annotated[float, typer.Option(
        "--timeout-s", help="How long each port has to answer, seconds.")] = 0.5,
) -> None:
    """Name a device after its axis in the machine file: the name goes into its flash
    (call 18), and the file finds the device by it on whatever port it is.

    A fresh board answers the default name (GENERIC USB MOTION DEVICE). Without PORT the
    command looks for it on the ports the file lists, the terminals of running usbmotion
    sim servers and the serial ports, and names the one fresh device it finds; with
    several, give PORT to say which one is AXIS (or plug the boards in one at a time).
    A name another device already answers is refused: each device needs its own.

    Exit status: 0 named (or named so already); 1 no such device, several fresh ones, or
    a port that could not be opened; 2 an unknown axis, an axis with no device name or a
    simulated one, or a bad machine file.
    """
    from usbmotion.host.discovery import announced_ptys, scan, serial_ports  # noqa: PLC0415
    from usbmotion.protocol import DEFAULT_DEVICE_NAME  # noqa: PLC0415

    config = load_machine(machine, "name")
    letter = axis.upper()
    if letter not in config.axis_names:
        fail("name", f"no axis {axis!r}; {config.path} has {', '.join(config.axis_names)}",
             EXIT_BAD_INPUT)
    settings = config.axis(letter)
    wanted = settings.device
    if settings.is_simulated or wanted is None:
        why = (f"its device is simulated in the command ({settings.url}): nothing to name"
               if settings.is_simulated else "the file gives it no device name (device = ...)")
        fail("name", f"axis {letter} of {config.path}: {why}", EXIT_BAD_INPUT)
    if not timeout_s > 0:
        fail("name", f"--timeout-s {timeout_s!r} must be > 0", EXIT_BAD_INPUT)
    searched = [*_file_ports(config), *announced_ptys(), *serial_ports()]
    answers = scan([*([port] if port is not None else []), *searched], timeout_s=timeout_s)
    holder = next((a for a in answers if a.name == wanted and a.url != port), None)
    if holder is not None and port is None:
        typer.echo(f"{holder.url}: {wanted!r} already (axis {letter} of {config.path})")
        return
    if holder is not None:
        fail("name", f"{wanted!r} is the name of the device on {holder.url} already; a"
             " machine's devices each need their own", EXIT_FAULT)
    target = _target(answers, port, DEFAULT_DEVICE_NAME, letter)
    if target.name == wanted:
        typer.echo(f"{target.url}: {wanted!r} already (axis {letter} of {config.path})")
        return
    from usbmotion.host.device import DeviceClient  # noqa: PLC0415

    try:
        with DeviceClient.open(target.url, timeout_s=max(timeout_s, 1.0)) as client:
            client.resynchronise(stop_diagnostics=True)
            client.set_name(wanted)
            now = client.device_name()
    except UsbMotionError as error:
        fail("name", f"{target.url}: {error}", EXIT_FAULT)
    typer.echo(f"{target.url}: {target.name!r} -> {now!r} (axis {letter} of {config.path}),"
               " kept in the device's flash")


def _file_ports(config: MachineConfig) -> list[str]:
    """The ports and URLs the machine file names (its ``ports``, its axes' ``url``)."""
    urls = [axis.url for axis in config.axes if axis.url is not None and not axis.is_simulated]
    return [*config.ports, *urls]


def _target(answers: list[PortAnswer], port: str | None, default: str,
            letter: str) -> PortAnswer:
    """The device to name: the one on ``port``, else the one fresh device found."""
    if port is not None:
        given = answers[0]
        if given.name is None:
            fail("name", f"{port}: {given.problem}", EXIT_FAULT)
        return given
    fresh = [answer for answer in answers if answer.name == default]
    if len(fresh) == 1:
        return fresh[0]
    if not fresh:
        seen = "; ".join(answer.describe() for answer in answers) or "no ports to probe"
        fail("name", f"no device answers the default name {default!r} (a fresh board);"
             f" probed: {seen}; give PORT to name another", EXIT_FAULT)
    ports = ", ".join(answer.url for answer in fresh)
    fail("name", f"{len(fresh)} devices answer the default name ({ports}): give PORT to say"
         f" which one is axis {letter} (usbmotion name {letter} PORT), or connect one at a"
         " time", EXIT_FAULT)
