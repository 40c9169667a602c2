"""The autouse check of ``conftest.py``: a test that leaves a thread, a pty, a socket, a
child process or a registered world behind fails, naming each."""

from __future__ import annotations

from pathlib import Path

import pytest

LEAKY_TESTS = '''
import os
import socket
import subprocess
import sys
import threading

from usbmotion.sim import SimWorld, set_world

_kept = []


def test_clean():
    thread = threading.Thread(target=lambda: None, name="finished")
    thread.start()
    thread.join()
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))


def test_thread():
    stop = threading.Event()
    _kept.append(stop)
    threading.Thread(target=stop.wait, name="leaky-thread", daemon=True).start()


def test_pty():
    _kept.append(os.openpty())


def test_socket():
    _kept.append(socket.socket())


def test_child():
    # reads its stdin: ends when this pytest process does
    _kept.append(subprocess.Popen([sys.executable, "-c", "import sys; sys.stdin.read()"],
                                  stdin=subprocess.PIPE))


def test_zombie():
    child = subprocess.Popen(["true"])
    _kept.append(child)
    os.waitid(os.P_PID, child.pid, os.WEXITED | os.WNOWAIT)


def test_world():
    set_world("leaky-world", SimWorld())


def test_thread_that_ends_within_the_grace_period():
    threading.Timer(0.3, lambda: None).start()
'''


def test_each_leftover_fails_its_test_and_is_named(pytester: pytest.Pytester) -> None:
    conftest = (Path(__file__).parent / "conftest.py").read_text(encoding="utf-8")
    assert "\nLEAK_GRACE_S = 2.0\n" in conftest
    pytester.makeconftest(conftest.replace("\nLEAK_GRACE_S = 2.0\n", "\nLEAK_GRACE_S = 0.5\n"))
    pytester.makepyfile(test_leaky=LEAKY_TESTS)
    result = pytester.runpytest_subprocess("-p", "no:cacheprovider", "-q")
    result.assert_outcomes(passed=8, errors=6)
    errors = {line.split(" - ", 1)[0].removeprefix("ERROR test_leaky.py::")
              for line in result.outlines if line.startswith("ERROR ")}
    assert errors == {"test_thread", "test_pty", "test_socket", "test_child", "test_zombie",
                      "test_world"}
    text = result.stdout.str()
    assert "thread 'leaky-thread' (daemon)" in text
    assert "-> /dev/ptmx" in text and "-> /dev/pts/" in text
    assert "-> socket:[" in text
    assert "import sys; sys.stdin.read()" in text
    assert "(zombie: exited, never waited for)" in text
    assert "simulated world 'leaky-world' (drop_world it)" in text
