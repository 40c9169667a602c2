"""``usbmotion sim``: serve simulated devices in real time on pseudo-terminals or TCP."""

from __future__ import annotations

import contextlib
import re
import signal
import sys
import threading
from collections.abc import Iterator
from pathlib import Path
from types import FrameType
from typing import TYPE_CHECKING, Annotated

import typer

from usbmotion.cli.exits import EXIT_BAD_INPUT, EXIT_FAULT, fail, os_problem
from usbmotion.cli.machines import hold, state_dir

if TYPE_CHECKING:
    from usbmotion.sim.world import SimWorld


def default_flash_dir() -> Path:
    """Where simulated devices keep their flash: ``flash`` in the state folder
    (:func:`usbmotion.cli.machines.state_dir`)."""
    return state_dir() / "flash"


def _slug(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9]+", "-", name).strip("-").lower() or "device"


def build_world(names: list[str], count: int, flash_dir: Path) -> SimWorld:
    """A world of ``count`` devices; the first ones take ``names`` (written to their flash)."""
    from usbmotion.device import Device, FileFlash  # noqa: PLC0415 - keeps start-up light
    from usbmotion.protocol import encode_device_name  # noqa: PLC0415
    from usbmotion.sim.world import SimWorld  # noqa: PLC0415

    flash_dir.mkdir(parents=True, exist_ok=True)
    world = SimWorld()
    for index in range(count):
        wanted = names[index] if index < len(names) else None
        stem = _slug(wanted) if wanted else f"device-{index + 1}"
        device = Device(flash=FileFlash(flash_dir / f"{stem}.json"))
        if wanted and device.name != wanted:
            device.feed(encode_device_name(wanted))
            device.take_output()
        world.add(device, key=str(index))
    return world


def sim(
    pty: Annotated[int, typer.Option("--pty", help="Serve N devices on pseudo-terminals.",
                                     show_default=False)] = 0,
    tcp: Annotated[int | None, typer.Option(
        "--tcp", metavar="PORT",
        help="Serve on TCP from this port up, one port per device (0: free ports).",
        show_default=False)] = None,
    count: Annotated[int, typer.Option(
        "--count", help="Number of devices with --tcp (default: one per --name, at least 1).",
        show_default=False)] = 0,
    name: Annotated[
        list[str] | None,
        typer.Option("--name", metavar="NAME",
                     help="Device name (repeat for several devices), max 25 chars.",
                     show_default=False),
    ] = None,
    flash_dir: Annotated[
        Path | None, typer.Option(
            "--flash-dir", metavar="DIR", help="Folder of the devices' flash files (default:"
            " flash in the state folder, ~/.local/state/usbmotion/flash; one server uses a"
            " folder at a time).", show_default=False)
    ] = None,
    firmware: Annotated[
        Path | None,
        typer.Option(
            "--firmware", metavar="IMAGE",
            help="Serve emulated RP2040s running this firmware image (.uf2, its .elf beside "
            "it) instead of the Python devices.", show_default=False,
        ),
    ] = None,
    bootrom: Annotated[
        Path | None,
        typer.Option(
            "--bootrom", metavar="PATH",
            help="With --firmware: the RP2040 boot ROM the emulator runs (B1, 16384 bytes;"
            " default: $USBMOTION_BOOTROM, else ../shared/rp2040/bootrom/b1.bin beside the"
            " project).", show_default=False,
        ),
    ] = None,
    record: Annotated[
        Path | None,
        typer.Option(
            "--record", metavar="DIR",
            help="With --firmware: write the bytes each device receives, with the servo tick "
            "they arrived at, to DEVICE.rec in this folder (for a deterministic replay).",
            show_default=False,
        ),
    ] = None,
) -> None:
    """Serve simulated devices in real time until SIGINT or SIGTERM.

    Prints one line per device, once it answers: its name and its pseudo-terminal path
    (--pty) or its socket:// URL (--tcp); usbmotion devices lists the terminals too.
    SIGINT (Ctrl-C) or SIGTERM closes every terminal and port, prints "stopped" and exits
    with status 0 (the way a server ends); a second signal meanwhile, or one before the
    devices answer, ends it at once (status 130 or 143 in a shell). Status 1: the serving
    failed (a TCP port already in use, say); 2: bad arguments.

    With --firmware, each device is the device firmware running on an emulated RP2040
    (make firmware builds build/firmware/usbmotion.uf2; the emulator needs Node.js 20 and
    npm ci in firmware/emulator), its flash kept in --flash-dir (default:
    ~/.local/state/usbmotion/flash/rp2040).

    The flash folder is this server's while it serves: a second server on the same
    folder (two usbmotion sim at once) is refused in one line naming the first one's
    process, as a port another program holds; give it another --flash-dir.
    """
    from usbmotion.protocol import device_name_problem  # noqa: PLC0415 - quick --help

    names = list(name or [])
    for each in names:
        problem = device_name_problem(each, allow_empty=False)
        if problem is not None:
            raise typer.BadParameter(problem, param_hint="--name")
    if (pty > 0) == (tcp is not None):
        raise typer.BadParameter("give exactly one of --pty N or --tcp PORT")
    if pty < 0 or pty > 64:
        raise typer.BadParameter(f"--pty {pty!r} must be 1..64")
    if tcp is not None and not 0 <= tcp <= 65535:
        raise typer.BadParameter(f"--tcp {tcp!r} must be a port number 0..65535")
    devices = pty if pty > 0 else (count or max(1, len(names)))
    if not 1 <= devices <= 64:
        raise typer.BadParameter(f"--count {devices!r} must be 1..64")
    if record is not None and firmware is None:
        raise typer.BadParameter("--record needs --firmware")
    if bootrom is not None and firmware is None:
        raise typer.BadParameter("--bootrom needs --firmware")
    folder = flash_dir or (default_flash_dir() / "rp2040" if firmware is not None
                           else default_flash_dir())
    with _signals_end_start_up():
        hold(folder / ".lock", what=f"the flash folder {folder}",
             advice="give this server another --flash-dir")
        if firmware is not None:
            _serve_firmware(firmware, devices, names, pty=pty > 0, tcp_port=tcp or 0,
                            flash_dir=folder, record=record, bootrom=bootrom)
        else:
            _serve(build_world(names, devices, folder), pty=pty > 0, tcp_port=tcp or 0)
    sys.stdout.write("stopped\n")
    sys.stdout.flush()


_SIGNALS = (signal.SIGINT, signal.SIGTERM)


def _say(notice: str) -> None:
    """A server's notice, one line on standard error."""
    sys.stderr.write(f"usbmotion sim: {notice}\n")
    sys.stderr.flush()


def _first_line(text: str) -> str:
    """An emulator's failure in one line: what failed, and the error it printed (a Node.js
    process that dies prints its stack too)."""
    lines = [line.strip() for line in text.splitlines() if line.strip()]
    if not lines:
        return text
    error = next((line.removeprefix("Error: ") for line in lines
                  if line.startswith("Error: ")), None)
    if error is None:
        return lines[0]
    return f"{lines[0].split(': ', 1)[0]}: {error}"


@contextlib.contextmanager
def _signals_end_start_up() -> Iterator[None]:
    """While inside, SIGINT and SIGTERM end the process at once (their default action, for
    SIGINT too), until :func:`_signals_stop_serving` takes them over.

    Starting up imports numba and loads or compiles the servo kernel for seconds; an
    exception raised there by a handler (``KeyboardInterrupt``) may be caught on the way
    and serving start all the same. Nothing is served yet: the kernel closes what is open.
    """
    previous = {each: signal.signal(each, signal.SIG_DFL) for each in _SIGNALS}
    try:
        yield
    finally:
        for each, handler in previous.items():
            signal.signal(each, handler)


@contextlib.contextmanager
def _signals_stop_serving() -> Iterator[threading.Event]:
    """While inside, the first SIGINT or SIGTERM sets the event it yields (nothing more: the
    serving ends between two waits) and gives the signals back their default action, so a
    second one ends the process at once."""
    stop = threading.Event()

    def on_signal(signum: int, frame: FrameType | None) -> None:
        for each in _SIGNALS:
            signal.signal(each, signal.SIG_DFL)
        stop.set()

    previous = {each: signal.signal(each, on_signal) for each in _SIGNALS}
    try:
        yield stop
    finally:
        for each, handler in previous.items():
            signal.signal(each, handler)


def _serve(world: SimWorld, *, pty: bool, tcp_port: int) -> None:
    """Serve ``world``'s devices until a signal; print each one's address once it answers
    (and announce its terminal to ``usbmotion devices``)."""
    from usbmotion.sim.pty_dir import announced  # noqa: PLC0415 - keeps start-up light
    from usbmotion.sim.server import DeviceServer  # noqa: PLC0415

    try:
        server = DeviceServer(world, pty=pty, tcp_port=tcp_port, on_notice=_say)
    except OSError as error:
        fail("sim", os_problem(error), EXIT_FAULT)
    with server:
        server.warm_up()
        paths = [endpoint.path for endpoint in server.endpoints] if pty else []
        with _signals_stop_serving() as stop, announced(paths):
            for endpoint in server.endpoints:
                where = endpoint.path if pty else f"socket://127.0.0.1:{endpoint.port}"
                sys.stdout.write(f"{endpoint.name} {where}\n")
            sys.stdout.flush()
            server.start()
            while not stop.wait(0.2):
                if not server.serving:
                    sys.stderr.write(
                        f"usbmotion sim: the serving loop failed: {server.error!r}\n")
                    raise typer.Exit(1)


def _serve_firmware(
    image: Path,
    devices: int,
    names: list[str],
    *,
    pty: bool,
    tcp_port: int,
    flash_dir: Path,
    record: Path | None,
    bootrom: Path | None,
) -> None:
    """``sim --firmware``: ``devices`` emulated RP2040s, served until a signal."""
    from usbmotion.errors import DeviceError  # noqa: PLC0415 - keeps start-up light
    from usbmotion.sim.firmware import FirmwareServer  # noqa: PLC0415
    from usbmotion.sim.pty_dir import announced  # noqa: PLC0415

    try:
        server = FirmwareServer(image, devices, pty=pty, tcp_port=tcp_port,
                                flash_dir=flash_dir, names=names, record_dir=record,
                                bootrom=bootrom, on_notice=_say)
    except FileNotFoundError as error:
        fail("sim", str(error), EXIT_BAD_INPUT)
    try:
        server.start()
    except (FileNotFoundError, DeviceError) as error:
        server.close()
        fail("sim", _first_line(str(error)), EXIT_BAD_INPUT)
    paths = [endpoint.url for endpoint in server.endpoints] if pty else []
    try:
        with _signals_stop_serving() as stop, announced(paths):
            for endpoint in server.endpoints:
                sys.stdout.write(f"{endpoint.name} {endpoint.url}\n")
            sys.stdout.flush()
            while not stop.wait(0.2):
                if server.stopped():
                    sys.stderr.write(f"usbmotion sim: {server.stopped()}\n")
                    raise typer.Exit(1)
    finally:
        server.close()
        if server.messages():
            sys.stderr.write(f"{server.messages()}\n")
