"""Child processes the benchmarks start, reaped however the benchmark ends.

A benchmark that times out, fails or is stopped with Ctrl-C must not leave a server or a
busy loop running: each child is started inside :func:`reaped`, which on the way out asks
it to end (SIGTERM), gives it a grace period and then kills it (SIGKILL), and waits for it.
Inside, SIGTERM to the benchmark (``timeout``, a harness giving up) raises ``SystemExit``
(status 143) instead of ending it on the spot, so the way out is taken; and a child
started with :func:`start` gets SIGKILL from the kernel if the benchmark dies without
taking it (SIGKILL).
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import selectors
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator, Sequence
from pathlib import Path
from types import FrameType
from typing import Any

SIM_START_TIMEOUT_S = 120.0
"""How long ``usbmotion sim`` has to print its devices' addresses (it prints them once the
devices answer: with a cold numba cache on a loaded machine, compiling the servo kernel
takes tens of seconds)."""


_PR_SET_PDEATHSIG = 1


def _die_with_parent() -> None:
    """In the child, before it runs: SIGKILL when the parent dies (Linux)."""
    ctypes.CDLL(None, use_errno=True).prctl(_PR_SET_PDEATHSIG, signal.SIGKILL)


def start(args: Sequence[str], **options: Any) -> subprocess.Popen[Any]:
    """``subprocess.Popen(args, **options)`` whose child is killed if this process dies."""
    return subprocess.Popen(args, preexec_fn=_die_with_parent, **options)  # noqa: PLW1509


def _raise_exit(signum: int, frame: FrameType | None) -> None:
    raise SystemExit(128 + signum)


@contextlib.contextmanager
def sigterm_unwinds() -> Iterator[None]:
    """While inside (in the main thread), SIGTERM raises ``SystemExit(143)``: the blocks
    being run are left through their ``finally`` clauses, children reaped on the way."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGTERM, _raise_exit)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def stop(process: subprocess.Popen[Any], *, grace_s: float,
         first_signal: signal.Signals = signal.SIGTERM) -> None:
    """End ``process``: ``first_signal``, up to ``grace_s`` to exit, then SIGKILL (``grace_s``
    0: at once); waited for, its pipes closed. A second Ctrl-C meanwhile kills it at once."""
    try:
        if process.poll() is None and grace_s > 0:
            process.send_signal(first_signal)
            with contextlib.suppress(subprocess.TimeoutExpired):
                process.wait(timeout=grace_s)
    finally:
        if process.poll() is None:
            process.kill()
        process.wait()
        for stream in (process.stdin, process.stdout, process.stderr):
            if stream is not None:
                stream.close()


@contextlib.contextmanager
def reaped(process: subprocess.Popen[Any], *, grace_s: float = 5.0,
           first_signal: signal.Signals = signal.SIGTERM) -> Iterator[subprocess.Popen[Any]]:
    """``process`` for as long as the block runs, then :func:`stop`-ped, whatever ended the
    block: its end, an exception, a timeout, Ctrl-C, SIGTERM (:func:`sigterm_unwinds`)."""
    with sigterm_unwinds():
        try:
            yield process
        finally:
            stop(process, grace_s=grace_s, first_signal=first_signal)


def run(args: Sequence[str], *, timeout_s: float, grace_s: float = 5.0,
        first_signal: signal.Signals = signal.SIGTERM, cwd: Path | None = None,
        env: dict[str, str] | None = None) -> subprocess.CompletedProcess[str]:
    """Run ``args`` to its end, its output captured as text, like ``subprocess.run`` (not
    checked); reaped if it outlasts ``timeout_s`` (``TimeoutExpired``) or the caller is
    stopped first. ``first_signal`` asks it to end (SIGINT lets pytest tear down)."""
    with reaped(start(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=cwd,
                      env=env), grace_s=grace_s, first_signal=first_signal) as process:
        out, err = process.communicate(timeout=timeout_s)
        return subprocess.CompletedProcess(args, process.returncode, out, err)


def read_lines(process: subprocess.Popen[bytes], count: int, *, timeout_s: float) -> list[str]:
    """The first ``count`` lines ``process`` prints on its stdout (a binary pipe).

    Raises:
        TimeoutError: they did not come within ``timeout_s`` (what it printed is in the
            message).
        EOFError: it closed its stdout (ended) first.
    """
    assert process.stdout is not None
    fd = process.stdout.fileno()
    data = b""
    deadline = time.monotonic() + timeout_s
    with selectors.DefaultSelector() as selector:
        selector.register(fd, selectors.EVENT_READ)
        while data.count(b"\n") < count:
            left = deadline - time.monotonic()
            if left <= 0 or not selector.select(timeout=left):
                raise TimeoutError(f"{process.args!r} printed {data!r} in {timeout_s} s;"
                                   f" {count} lines were expected")
            chunk = os.read(fd, 65536)
            if not chunk:
                raise EOFError(f"{process.args!r} ended (status {process.wait()}) after"
                               f" printing {data!r}; {count} lines were expected")
            data += chunk
    return data.decode().splitlines()[:count]


@contextlib.contextmanager
def sim_server(devices: int, flash_dir: Path, *, extra: Sequence[str] = (),
               timeout_s: float = SIM_START_TIMEOUT_S) -> Iterator[tuple[int, list[str]]]:
    """``usbmotion sim --pty DEVICES`` as a child process; yields its pid and its devices'
    terminal paths once they answer, and reaps it on the way out."""
    process = start([sys.executable, "-m", "usbmotion", "sim", "--pty", str(devices),
                     "--flash-dir", str(flash_dir), *extra], stdout=subprocess.PIPE)
    with reaped(process):
        lines = read_lines(process, devices, timeout_s=timeout_s)
        yield process.pid, [line.rsplit(" ", 1)[1] for line in lines]
