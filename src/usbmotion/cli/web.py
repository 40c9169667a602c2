"""``usbmotion web``: the machine in a browser (the dashboard, ``docs/dashboard.md``)."""

from __future__ import annotations

import socket
import threading
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from usbmotion.cli.connect import connect_live
from usbmotion.cli.exits import EXIT_BAD_INPUT, EXIT_FAULT, fail, os_problem
from usbmotion.cli.machines import MachineOption, load_machine
from usbmotion.cli.signals import stop_on_signals
from usbmotion.errors import UsbMotionError

if TYPE_CHECKING:
    from usbmotion.host.config import MachineConfig
    from usbmotion.session import MachineSession
    from usbmotion.web.dashboard import Predicted, Predictor

LOOPBACK = ("127.0.0.1", "localhost", "::1")
STARTED_TIMEOUT_S = 30.0
"""How long the server has to answer before the command gives up."""


def web(
    machine: MachineOption = None,
    host: Annotated[str, typer.Option(
        "--host", help="The address to bind: 127.0.0.1 keeps the page on this computer;"
        " 0.0.0.0 offers it to the network (the token still guards it).")] = "127.0.0.1",
    port: Annotated[int, typer.Option(
        "--port", help="The TCP port (0: any free port).")] = 8000,
    programs: Annotated[Path | None, typer.Option(
        "--programs", help="A folder whose G-code files the page can open (else it"
        " uploads them).", show_default=False)] = None,
    token: Annotated[str | None, typer.Option(
        "--token", help="The token every API call must carry (default: a new random one"
        " each start; at least 16 characters).", show_default=False)] = None,
) -> None:
    """Serve the machine to a web browser: DRO, following-error charts, toolpath, program.

    One machine session, shown live from the devices: each axis's measured and
    commanded position and its following error (the peak of every servo tick), the
    program line the devices execute, the executed path over the planned one; and
    driven from the page: open a program, run, hold, resume, stop, overrides, homing,
    jogging, MDI and work offsets. The built-in simulated machine runs in real time.

    Prints the page's address, with its token, once the server answers. Every API call
    needs the token (a browser can move the machine). Ctrl-C or SIGTERM brings every
    axis to rest along its deceleration and leaves with status 0.

    Exit status: 0 served until a signal; 1 the machine could not be connected; 2 a bad
    option or machine file, or the port in use.
    """
    from usbmotion.web.app import new_token, page_built  # noqa: PLC0415

    config = load_machine(machine, "web")
    if not 0 <= port <= 65535:
        fail("web", f"--port {port}: a port within 0..65535", EXIT_BAD_INPUT)
    if programs is not None and not programs.is_dir():
        fail("web", f"--programs {programs}: not a folder", EXIT_BAD_INPUT)
    if token is not None and (len(token) < 16 or not token.isascii() or not all(
            c.isalnum() or c in "-_." for c in token)):
        fail("web", "--token: at least 16 letters, digits, '-', '_' or '.'", EXIT_BAD_INPUT)
    from usbmotion.serving import listening_socket  # noqa: PLC0415

    try:
        listener = listening_socket(host, port)
    except OSError as error:
        fail("web", f"cannot listen on {host}:{port}: {os_problem(error)}", EXIT_BAD_INPUT)
    bound_port = listener.getsockname()[1]
    if not page_built():
        typer.echo("usbmotion web: the page's bundle is not built (make web builds it with"
                   " npm); the API answers, the page will not work", err=True)
    try:
        session, keep_pace = connect_live(config)
    except (UsbMotionError, OSError) as error:
        listener.close()
        fail("web", str(error), EXIT_FAULT)
    secret = token or new_token()
    with session:
        for notice in session.notices:
            typer.echo(f"notice: {notice}", err=True)
        status = _serve(session, keep_pace, listener, host=host, port=bound_port,
                        programs=programs, token=secret)
    raise typer.Exit(status)


def _serve(session: MachineSession, keep_pace: Callable[[], None] | None,
           listener: socket.socket, *, host: str, port: int, programs: Path | None,
           token: str) -> int:
    """Serve until a signal, then bring the machine to rest; the exit status."""
    import uvicorn  # noqa: PLC0415 - keeps --help fast

    from usbmotion.session.operator import Operator  # noqa: PLC0415
    from usbmotion.web.app import create_app  # noqa: PLC0415
    from usbmotion.web.dashboard import Dashboard  # noqa: PLC0415

    operator = Operator(session, file="<web>")
    operator.on_idle = keep_pace
    from usbmotion.sim.urls import URL_CHECKS  # noqa: PLC0415 - the sim:// checks alone

    dashboard = Dashboard(operator, programs=programs, url_checks=URL_CHECKS,
                          predictor=model_predictor(session.config))
    dashboard.start()
    app = create_app(dashboard, token=token)
    server = uvicorn.Server(uvicorn.Config(app, log_level="warning", lifespan="off",
                                           timeout_graceful_shutdown=2, ws="websockets-sansio"))
    shown = "127.0.0.1" if host in ("0.0.0.0", "") else (f"[{host}]" if ":" in host else host)
    where = f"http://{shown}:{port}/?token={token}"

    def announce() -> None:
        deadline = time.monotonic() + STARTED_TIMEOUT_S
        while not server.started and not server.should_exit:
            if time.monotonic() > deadline:
                typer.echo("usbmotion web: the server did not start", err=True)
                server.should_exit = True
                return
            time.sleep(0.02)
        if server.started:
            beyond = "" if host in LOOPBACK else (
                f" (bound to {host}: other computers reach it too, with the token)")
            typer.echo(f"usbmotion web: {dashboard.machine_name} at {where}{beyond}")

    threading.Thread(target=announce, name="usbmotion-web-announce", daemon=True).start()
    status = 0
    try:
        # The server takes SIGINT and SIGTERM while it serves and raises them again as it
        # ends: this handler (a stop along the deceleration) then takes them, not the
        # default one that would end the process with the machine moving.
        with stop_on_signals(session):
            server.run(sockets=[listener])
    finally:
        typer.echo("usbmotion web: stopping the machine", err=True)
        dashboard.close()
        operator.close()
        try:
            session.shutdown()
        except UsbMotionError as error:
            typer.echo(f"usbmotion web: stopping the machine: {error}", err=True)
            status = EXIT_FAULT
        listener.close()
    return status


def model_predictor(config: MachineConfig) -> Predictor:
    """What plays a program on the models of ``config``'s axes for the dashboard: ``usbmotion
    run --predict``'s simulator (:func:`usbmotion.sim.predict.predict`), which the web
    package may not import itself."""

    def play(name: str, text: str, *, from_line: int | None,
             standing_mm: Mapping[str, float] | None) -> Predicted:
        from usbmotion.sim.predict import predict  # noqa: PLC0415 - loaded on first use
        from usbmotion.web.dashboard import Predicted  # noqa: PLC0415

        made = predict(config, Path(name), text, from_line=from_line, standing_mm=standing_mm)
        return Predicted(made.report, made.motors, made.wall_s)

    return play
