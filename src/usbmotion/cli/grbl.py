"""``usbmotion grbl``: the machine as a grbl 1.1h controller, for the G-code senders people
already use (cncjs, Universal G-code Sender, Candle, grbl-streamer)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from usbmotion.cli.connect import connect_live
from usbmotion.cli.exits import EXIT_BAD_INPUT, EXIT_FAULT, fail, os_problem
from usbmotion.cli.machines import MachineOption, load_machine
from usbmotion.errors import ArgumentError, UsbMotionError


def grbl(
    pty: Annotated[bool, typer.Option(
        "--pty", help="Serve on a pseudo-terminal (its path is printed); the default.")] = True,
    link: Annotated[str | None, typer.Option(
        "--link", help="With --pty, also make a symbolic link to it at this path (such as"
        " /tmp/ttyGRBL, for a sender's port list); a link to a terminal another server"
        " still serves is refused, a stale one replaced.", show_default=False)] = None,
    tcp: Annotated[int | None, typer.Option(
        "--tcp", help="Serve on this TCP port instead of a pseudo-terminal (0: any free"
        " port).", show_default=False)] = None,
    host: Annotated[str, typer.Option(
        "--host", help="The TCP address to bind (with --tcp).")] = "127.0.0.1",
    machine: MachineOption = None,
) -> None:
    """Serve the machine as a grbl 1.1h controller on a pseudo-terminal or a TCP port.

    One machine session, driven by a sender as it would drive a grbl board: the start-up
    banner, ok / error:N, ALARM:N and its lock, the real-time bytes (? ! ~ Ctrl-X, jog
    cancel, overrides), the status report with encoder positions and an FE: field of each
    axis's following error, $$ $# $G $I $N $C $H $X $J= $SLP, and character-counting
    streaming on a 128-byte buffer. G-code lines are planned with look-ahead as they come.
    The built-in simulated machine runs in real time. SIGTERM or Ctrl-C brings every axis
    to rest and leaves.

    One sender at a time: on the pseudo-terminal a second sender that locks its port (as
    cncjs and pyserial's exclusive open do) is refused by the first one's lock, and a
    program that opens it regardless is said on standard error; on TCP a new connection
    replaces the one before (closed), so a sender that reconnects after its link died gets
    through.

    $N=value changes the settings that map onto the machine file (counts per mm as steps
    per mm, max rate, acceleration, travel, homing, junction deviation, arc tolerance),
    checked as the file is when it loads (the motors' reach); they are written to the
    file given with --machine, and hold for the session only on the built-in machine.

    Exit status: 0 served until a signal; 1 the machine could not be connected; 2 a bad
    option or machine file, a TCP port in use, or a --link that another server's terminal
    holds.
    """
    from usbmotion.grbl.interface import GrblMachine  # noqa: PLC0415 - keep --help fast
    from usbmotion.grbl.server import serve  # noqa: PLC0415
    from usbmotion.grbl.session_machine import SessionMachine  # noqa: PLC0415
    from usbmotion.session.operator import Operator  # noqa: PLC0415

    config = load_machine(machine, "grbl")
    if tcp is not None and not 0 <= tcp <= 65535:
        fail("grbl", f"--tcp {tcp}: a port within 0..65535", EXIT_BAD_INPUT)
    if link is not None and tcp is not None:
        fail("grbl", "--link names a pseudo-terminal's link: it does not go with --tcp",
             EXIT_BAD_INPUT)
    if link is not None:
        from usbmotion.serving import link_problem  # noqa: PLC0415

        problem = link_problem(Path(link))
        if problem is not None:
            fail("grbl", problem, EXIT_BAD_INPUT)
    try:
        session, keep_pace = connect_live(config)
    except UsbMotionError as error:
        fail("grbl", str(error), EXIT_FAULT)
    status = 0
    with session:
        for notice in session.notices:
            typer.echo(f"notice: {notice}", err=True)
        operator = Operator(session, on_message=lambda text: typer.echo(text, err=True),
                            file="<grbl>")
        operator.on_idle = keep_pace
        front = SessionMachine(operator, keep_settings=machine is not None)
        served: GrblMachine = front
        front.start()
        try:
            status = serve(served, pty=tcp is None and pty, link=link, tcp_port=tcp, host=host,
                           on_notice=lambda text: typer.echo(f"usbmotion grbl: {text}",
                                                             err=True))
        except ArgumentError as error:
            fail("grbl", str(error), EXIT_BAD_INPUT)
        except OSError as error:
            where = f"{error.filename}: " if error.filename else ""
            fail("grbl", f"{where}{os_problem(error)}", EXIT_BAD_INPUT)
        finally:
            front.close()
            operator.close()
            try:
                session.shutdown()
            except UsbMotionError as error:
                typer.echo(f"usbmotion grbl: stopping the machine: {error}", err=True)
    raise typer.Exit(status)
