"""The machine a command acts on: the one :func:`load_machine` every command uses, the
built-in simulated machine, and the folders whose state one command holds at a time.

The built-in machine (``usbmotion/data/machine.toml``, the same as
``examples/machine.toml``) keeps its parameter file (work offsets, stored positions) in
:func:`state_dir`, never beside the package's file. A command on the built-in machine holds
it, as a port is held by the host that opened it: a second command on it at the same time
(two ``usbmotion run``, ``run`` and ``zero``) is refused in one line naming the first
one's process, so no two commands read and write the same parameter file under each
other. ``usbmotion sim`` holds its flash folder the same way.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
from collections.abc import Iterator
from contextvars import ContextVar
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from usbmotion.cli.exits import EXIT_BAD_INPUT, EXIT_FAULT, fail, os_problem
from usbmotion.errors import ConfigError

if TYPE_CHECKING:
    from usbmotion.host.config import MachineConfig

MachineOption = Annotated[
    Path | None,
    typer.Option("--machine", "-m", help="Machine configuration (default: the built-in"
                 " simulated XYZ machine)."),
]
"""The ``--machine`` option of the commands that drive a machine (``default_machine()``
when it is not given)."""

BUILT_IN_LOCK = "machine.lock"
"""The file in :func:`state_dir` a command on the built-in machine holds locked."""


def default_machine() -> Path:
    """The built-in simulated 3-axis machine (the same file as ``examples/machine.toml``)."""
    from usbmotion.host.config import builtin_machine_file  # noqa: PLC0415

    return builtin_machine_file()


def state_dir() -> Path:
    """Where the commands keep their state (the built-in machine's parameter file,
    ``usbmotion sim``'s flash): ``$USBMOTION_STATE_DIR``, else
    ``$XDG_STATE_HOME/usbmotion``, else ``~/.local/state/usbmotion`` (the package's own
    folder is not for writing)."""
    if os.environ.get("USBMOTION_STATE_DIR"):
        return Path(os.environ["USBMOTION_STATE_DIR"])
    base = os.environ.get("XDG_STATE_HOME") or str(Path.home() / ".local" / "state")
    return Path(base) / "usbmotion"


_RUNNING: ContextVar[tuple[str, list[Path]] | None] = ContextVar("usbmotion_command",
                                                                 default=None)
"""The command running now and the lock files it holds."""


@contextlib.contextmanager
def command_running(name: str) -> Iterator[None]:
    """While inside, ``name`` is the running command (:func:`command_name`); on leaving,
    whatever it held (:func:`hold`) is released."""
    held: list[Path] = []
    token = _RUNNING.set((name, held))
    try:
        yield
    finally:
        _RUNNING.reset(token)
        for lock_file in held:
            release(lock_file)


def command_name() -> str:
    """The name of the command running now (``run``, ``zero``), ``""`` outside one."""
    running = _RUNNING.get()
    return running[0] if running is not None else ""


def unreadable(path: Path) -> str | None:
    """Why the file ``path`` cannot be read (``no such file``, ``a folder, not a file``,
    ``permission denied``), or None."""
    try:
        if path.is_dir():
            return "a folder, not a file"
        with path.open("rb"):
            return None
    except OSError as error:
        return os_problem(error)


def load_machine(machine: Path | None, command: str | None = None) -> MachineConfig:
    """The configuration of the machine a command acts on: the file ``machine``, or the
    built-in simulated machine when it is None (its parameter file in :func:`state_dir`,
    and held by this command until it ends: see the module).

    A file that is missing, unreadable or invalid ends the command with status 2, the
    built-in machine held by another command with status 1: one line on standard error,
    ``usbmotion COMMAND: ...``, naming the file or the process.

    Parameters:
        machine: the ``--machine`` file, or None.
        command: the command's name in the message (default: the running command's).
    """
    from usbmotion.host.config import load_config  # noqa: PLC0415 - keeps --help fast
    from usbmotion.sim.urls import URL_CHECKS  # noqa: PLC0415 - the sim:// checks alone

    name = command_name() if command is None else command
    path = machine or default_machine()
    problem = unreadable(path)
    if problem is not None:
        fail(name, f"cannot read the machine file {path}: {problem}", EXIT_BAD_INPUT)
    try:
        config = load_config(path, url_checks=URL_CHECKS)
    except ConfigError as error:
        fail(name, str(error), EXIT_BAD_INPUT)
    if machine is None:
        hold(state_dir() / BUILT_IN_LOCK, what="the built-in machine", command=name,
             advice="wait for it to end, or give --machine FILE for another machine")
        if config.parameter_file is None:
            config = replace(config, parameter_file=state_dir() / "machine.var")
    return config


_held: dict[Path, int] = {}
"""This process's holds: lock file -> its descriptor."""


def hold(lock_file: Path, *, what: str, advice: str, command: str | None = None) -> None:
    """Hold ``lock_file`` (an exclusive ``flock``) until the running command ends (or,
    outside a command, until the process does); a process holds it once however often it
    asks. Held by another process, the command ends with status 1 and one line:
    ``WHAT is in use by usbmotion COMMAND (process PID); ADVICE``.

    The file keeps the holder's process id and command, for that line; it is never
    removed (removing a lock file races with the next holder).
    """
    name = command_name() if command is None else command
    if lock_file in _held:
        return
    try:
        lock_file.parent.mkdir(parents=True, exist_ok=True)
        descriptor = os.open(lock_file, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
    except OSError as error:
        fail(name, f"cannot hold {what}: {lock_file}: {os_problem(error)}", EXIT_FAULT)
    try:
        fcntl.flock(descriptor, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        holder = _holder(descriptor)
        os.close(descriptor)
        fail(name, f"{what} is in use by {holder}; {advice}", EXIT_FAULT)
    os.ftruncate(descriptor, 0)
    os.pwrite(descriptor, f"{os.getpid()} {name}\n".encode(), 0)
    _held[lock_file] = descriptor
    running = _RUNNING.get()
    if running is not None:
        running[1].append(lock_file)


def release(lock_file: Path) -> None:
    """Let go of ``lock_file`` if this process holds it."""
    descriptor = _held.pop(lock_file, None)
    if descriptor is not None:
        with contextlib.suppress(OSError):
            fcntl.flock(descriptor, fcntl.LOCK_UN)
        os.close(descriptor)


def _holder(descriptor: int) -> str:
    """``usbmotion run (process 1234)``, as the holder wrote itself in the lock file."""
    text = os.pread(descriptor, 200, 0).decode("utf-8", "replace").split("\n", 1)[0]
    pid, _, command = text.partition(" ")
    if not pid.isdigit():
        return "another process"
    return f"usbmotion {command} (process {pid})" if command else f"process {pid}"
