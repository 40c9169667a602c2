"""Fixtures shared by the test modules, and the check that no test leaves anything behind."""

from __future__ import annotations

import os
import sys
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from usbmotion.sim import drop_world

pytest_plugins = ("pytester",)

LEAK_GRACE_S = 2.0
"""How long a thread or a child process may take to finish exiting after its test."""

ROOT = Path(__file__).resolve().parents[1]
NOT_FOR_WRITING = (ROOT / "src" / "usbmotion" / "data", ROOT / "examples")
"""The package's own machine file and the examples: no test may leave a file there (a
parameter file beside a machine file, say)."""


@dataclass(frozen=True, slots=True)
class Resources:
    """What a test could leave behind: live threads, pty and socket descriptors of this
    process, child processes and registered simulated worlds."""

    threads: frozenset[threading.Thread]
    descriptors: frozenset[tuple[int, str]]
    children: frozenset[int]
    worlds: frozenset[str]

    @classmethod
    def now(cls) -> Resources:
        """The resources held at this moment."""
        return cls(
            threads=frozenset(threading.enumerate()),
            descriptors=frozenset(_terminal_and_socket_descriptors()),
            children=frozenset(_children()),
            worlds=frozenset(_worlds()),
        )

    def left_since(self, before: Resources) -> list[str]:
        """Each resource held now and not ``before``, in words."""
        left = [f"thread {t.name!r}{' (daemon)' if t.daemon else ''}"
                for t in sorted(self.threads - before.threads, key=lambda t: t.name)]
        left += [f"file descriptor {fd} -> {target}"
                 for fd, target in sorted(self.descriptors - before.descriptors)]
        left += [f"child process {pid}: {_command_line(pid)}"
                 for pid in sorted(self.children - before.children)]
        left += [f"simulated world {name!r} (drop_world it)"
                 for name in sorted(self.worlds - before.worlds)]
        return left


def _terminal_and_socket_descriptors() -> Iterator[tuple[int, str]]:
    """(descriptor, what it is open on) for this process's ptys and sockets."""
    for entry in Path("/proc/self/fd").iterdir():
        try:
            target = os.readlink(entry)
        except OSError:  # closed meanwhile, or the listing's own descriptor
            continue
        if target.startswith(("/dev/pts/", "/dev/ptmx", "socket:[")):
            yield int(entry.name), target


def _children() -> Iterator[int]:
    """The ids of this process's child processes, zombies included (not reaped yet)."""
    for task in Path("/proc/self/task").iterdir():
        try:
            yield from (int(pid) for pid in (task / "children").read_text().split())
        except OSError:  # a thread that ended meanwhile
            continue


def _worlds() -> tuple[str, ...]:
    """The names of the registered simulated worlds (none before the registry is imported)."""
    registry = sys.modules.get("usbmotion.sim.registry")
    return () if registry is None else tuple(registry.registered_worlds())


def _command_line(pid: int) -> str:
    try:
        status = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
        argv = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")
    except OSError:
        return "(gone)"
    words = " ".join(a.decode(errors="replace") for a in argv if a)
    return f"{words or '?'}{' (zombie: exited, never waited for)' if status == 'Z' else ''}"


@pytest.fixture(autouse=True)
def _nothing_left_behind(request: pytest.FixtureRequest) -> Iterator[None]:
    """Fail the test if it leaves a thread, pty, socket, child process or world behind.

    Function-scoped: it runs after the test's own fixtures are torn down (it is set up
    first, being autouse and requested by none), so a fixture that cleans up is fine.
    """
    before = Resources.now()
    yield
    deadline = time.monotonic() + LEAK_GRACE_S
    while True:
        left = Resources.now().left_since(before)
        if not left or time.monotonic() >= deadline:
            break
        time.sleep(0.02)
    if left:
        pytest.fail(f"{request.node.nodeid} left behind:\n  " + "\n  ".join(left),
                    pytrace=False)


@pytest.fixture(autouse=True)
def own_state(tmp_path_factory: pytest.TempPathFactory,
               monkeypatch: pytest.MonkeyPatch) -> Iterator[Path]:
    """Give the test, and every process it starts, state folders of its own: the
    built-in machine's parameter file and lock (``USBMOTION_STATE_DIR``), ``usbmotion
    sim``'s flash (``XDG_STATE_HOME``), the announced pseudo-terminals
    (``USBMOTION_PTY_DIR``); so a test never reads or writes the user's, and never sees
    another test's. (``HOME`` stays: usbmotion falls back to it only when these are
    unset, and other tools keep their caches there.) Fail the test if it left a file
    among the package's data or the examples."""
    folder = tmp_path_factory.mktemp("state")
    monkeypatch.setenv("USBMOTION_STATE_DIR", str(folder / "usbmotion"))
    monkeypatch.setenv("XDG_STATE_HOME", str(folder / "xdg-state"))
    monkeypatch.setenv("USBMOTION_PTY_DIR", str(folder / "ptys"))
    before = {path: sorted(path.rglob("*")) for path in NOT_FOR_WRITING}
    yield folder
    left = [str(each) for path, files in before.items()
            for each in sorted(set(path.rglob("*")) - set(files))]
    if left:
        pytest.fail(f"left files in the project's own folders: {', '.join(left)}",
                    pytrace=False)


@pytest.fixture
def world_name() -> Iterator[str]:
    """A registered world name, unique to the test, dropped afterwards."""
    name = f"test-{threading.get_ident()}-{id(object())}"
    yield name
    drop_world(name)


@pytest.fixture
def default_world() -> Iterator[str]:
    """The name of the world ``sim://`` URLs without ``?world=`` open (made on first use),
    dropped afterwards: the next test starts without its devices."""
    yield "default"
    drop_world("default")


@pytest.fixture(scope="session", autouse=True)
def _child_processes_compile_once(tmp_path_factory: pytest.TempPathFactory) -> Iterator[None]:
    """Python processes the tests start keep the modules they compile in a folder of this
    run (``PYTHONPYCACHEPREFIX``), even where ``PYTHONDONTWRITEBYTECODE`` is set: each
    ``usbmotion`` command started would otherwise compile the package's sources anew
    (a fifth of its start-up), and nothing is written beside the sources."""
    patch = pytest.MonkeyPatch()
    patch.setenv("PYTHONPYCACHEPREFIX", str(tmp_path_factory.mktemp("pycache")))
    patch.delenv("PYTHONDONTWRITEBYTECODE", raising=False)
    yield
    patch.undo()
