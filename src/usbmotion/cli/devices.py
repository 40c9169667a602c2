"""``usbmotion devices``: the devices found on the computer's serial ports, the
pseudo-terminals ``usbmotion sim --pty`` serves, and the ports a machine file names."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from usbmotion.cli.exits import EXIT_BAD_INPUT, EXIT_FAULT, fail
from usbmotion.cli.machines import load_machine


def devices(
    port: Annotated[list[str] | None, typer.Option(
        "--port", "-p", metavar="PORT", help="Also probe this port path or URL"
        " (socket://HOST:PORT); repeat for several.", show_default=False)] = None,
    machine: Annotated[Path | None, typer.Option(
        "--machine", "-m", help="Also probe the ports and URLs this machine file names.",
        show_default=False)] = None,
    timeout_s: Annotated[float, typer.Option(
        "--timeout-s", help="How long each port has to answer, seconds.")] = 0.5,
) -> None:
    """List the USB Motion Devices found on serial ports and usbmotion sim's terminals.

    Each port probed is printed with the device name it answered with (call 18) or why
    it gave none (busy, no answer, not a device).

    Probed, in order: the --port ports, the ports and URLs of the --machine file, the
    pseudo-terminals that running usbmotion sim --pty servers announce, and the
    computer's serial ports. A port another program holds is reported busy and left
    alone.

    Exit status: 0 at least one device answered; 1 none did; 2 a bad option or machine
    file.
    """
    from usbmotion.host.discovery import (  # noqa: PLC0415
        PortAnswer,
        announced_ptys,
        scan,
        serial_ports,
    )

    if not timeout_s > 0:
        fail("devices", f"--timeout-s {timeout_s!r} must be > 0", EXIT_BAD_INPUT)
    candidates = list(port or [])
    if machine is not None:
        config = load_machine(machine, "devices")
        candidates += [axis.url for axis in config.axes
                       if axis.url is not None and not axis.is_simulated]
        candidates += list(config.ports)
    candidates += announced_ptys() + serial_ports()
    answers: list[PortAnswer] = scan(candidates, timeout_s=timeout_s)
    if not answers:
        fail("devices", "no ports to probe: no serial ports, no usbmotion sim --pty"
             " running; give --port or --machine", EXIT_FAULT)
    width = max(len(answer.url) for answer in answers)
    for answer in answers:
        said = repr(answer.name) if answer.name is not None else answer.problem
        typer.echo(f"{answer.url:<{width}}  {said}")
    found = sum(answer.name is not None for answer in answers)
    typer.echo(f"{found} device(s) on {len(answers)} port(s) probed")
    if not found:
        raise typer.Exit(EXIT_FAULT)
