"""``usbmotion sim`` as a process: it prints a device's address only once the device answers
(a plain client's first exchanges are right, even on a cold numba cache), and SIGTERM or
SIGINT ends it within a second or two, every terminal closed."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest
import serial

EXIT_WITHIN_S = 5.0
"""How soon a signal must end the server: it stops serving within a round of its loop
(milliseconds) and exits once Python has shut down, 0.3 to 0.4 s on an idle machine, about
1 s with both cores busy and up to 2.2 s measured with the cores overloaded; a server that
ignored the signal would never exit."""
EXCHANGES = (
    (b"3 1\n3 -1\n", b"SERVO_ENABLE 1\n"),
    (b"20 -1\n", b"STATUS "),
    (b"3 0\n3 -1\n", b"SERVO_ENABLE 0\n"),
    (b"18 -1\n", b"DEVICE_NAME GENERIC USB MOTION DEVICE\n"),
)
"""Requests (a write answers nothing: each write is followed by its read), and the reply (or
its start) they must get."""


@contextmanager
def sim_process(tmp_path: Path, *args: str, env: dict[str, str] | None = None,
                ) -> Iterator[subprocess.Popen[str]]:
    """``usbmotion sim ARGS`` with its flash in ``tmp_path``; killed and waited for on the
    way out, whatever happened."""
    process = subprocess.Popen(
        [sys.executable, "-m", "usbmotion", "sim", *args, "--flash-dir", str(tmp_path)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    try:
        yield process
    finally:
        if process.poll() is None:
            process.kill()
        process.communicate()


def _paths(process: subprocess.Popen[str], devices: int) -> list[str]:
    assert process.stdout is not None
    lines = [process.stdout.readline() for _ in range(devices)]
    assert all(line.count(" /dev/pts/") == 1 for line in lines), lines
    return [line.rsplit(" ", 1)[1].strip() for line in lines]


def _family(pid: int) -> set[int]:
    """``pid`` and every process descended from it."""
    family, todo = {pid}, [pid]
    while todo:
        for children in Path(f"/proc/{todo.pop()}/task").glob("*/children"):
            try:
                found = {int(child) for child in children.read_text().split()}
            except OSError:
                continue
            todo.extend(found - family)
            family |= found
    return family


def _holders(path: str) -> list[int]:
    """Every process that has ``path`` open."""
    holders = []
    for fd_dir in Path("/proc").glob("[0-9]*/fd"):
        try:
            if any(os.readlink(fd) == path for fd in fd_dir.iterdir()):
                holders.append(int(fd_dir.parent.name))
        except OSError:  # gone meanwhile, or not ours to read
            continue
    return holders


@pytest.mark.realtime
@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT], ids=["SIGTERM", "SIGINT"])
def test_a_signal_ends_the_server_promptly_and_closes_its_terminals(
    tmp_path: Path, signum: signal.Signals
) -> None:
    with sim_process(tmp_path, "--pty", "2") as process:
        paths = _paths(process, 2)
        with serial.Serial(paths[0], timeout=1) as port:
            port.write(b"18 -1\n")
            assert port.readline().startswith(b"DEVICE_NAME ")
        assert all(_holders(path) == [process.pid] for path in paths)
        family = _family(process.pid)
        sent = time.monotonic()
        process.send_signal(signum)
        code = process.wait(timeout=10)
        took_s = time.monotonic() - sent
        out, err = process.communicate()
    assert code == 0, err
    assert out == "stopped\n"
    assert took_s < EXIT_WITHIN_S, f"{signum.name}: {took_s:.2f} s to exit"
    # a terminal's number is free once it is closed, and another program may open a new
    # terminal of that number at once: what must be gone is the server and its children
    assert all(not set(_holders(path)) & family for path in paths)
    assert all(not Path(f"/proc/{pid}").exists() for pid in family), (
        "the server and its children exited")


def test_a_signal_while_starting_up_ends_it_at_once(tmp_path: Path) -> None:
    with sim_process(tmp_path, "--pty", "1") as process:
        time.sleep(0.3)  # importing, the devices not served yet
        assert process.poll() is None
        sent = time.monotonic()
        process.send_signal(signal.SIGTERM)
        code = process.wait(timeout=10)
        took_s = time.monotonic() - sent
    assert code == -signal.SIGTERM
    assert took_s < EXIT_WITHIN_S


@pytest.mark.realtime
def test_a_plain_client_asking_at_once_on_a_cold_numba_cache_gets_every_answer(
    tmp_path: Path,
) -> None:
    cache = tmp_path / "numba-cache"
    cache.mkdir()
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache)}
    with sim_process(tmp_path, "--pty", "1", env=env) as process:
        (path,) = _paths(process, 1)
        replies = []
        with serial.Serial(path, timeout=1) as port:
            for index in range(20):
                request, _ = EXCHANGES[index % len(EXCHANGES)]
                port.write(request)
                replies.append(port.readline())
        process.send_signal(signal.SIGTERM)
        assert process.wait(timeout=10) == 0
    wanted = [EXCHANGES[index % len(EXCHANGES)] for index in range(20)]
    wrong = [(request, reply) for (request, start), reply in zip(wanted, replies, strict=True)
             if not (reply.startswith(start) and reply.endswith(b"\n"))]
    assert not wrong, f"{20 - len(wrong)} of 20 exchanges right; wrong: {wrong}"
    assert any(cache.rglob("*.nbi")), "the kernel was compiled into the fresh cache"
