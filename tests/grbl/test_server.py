"""The grbl server on a pseudo-terminal and on TCP, in real time with the fake machine."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
import serial
from tests.grbl.fake_machine import FakeMachine

from usbmotion.errors import ArgumentError
from usbmotion.grbl.server import GrblServer
from usbmotion.serving import TcpEndpoint

pytestmark = pytest.mark.realtime

BANNER = b"\r\nGrbl 1.1h ['$' for help]\r\n"
UNLOCK = b"[MSG:'$H'|'$X' to unlock]\r\n"
ROOT = Path(__file__).resolve().parents[2]


def read_until(read: object, marker: bytes, *, timeout_s: float = 3.0) -> bytes:
    """Bytes from ``read(n)`` until ``marker`` came (or the time is up)."""
    data = b""
    deadline = time.monotonic() + timeout_s
    while marker not in data and time.monotonic() < deadline:
        data += read(4096)  # type: ignore[operator]
    return data


@pytest.fixture
def pty_server() -> Iterator[GrblServer]:
    with GrblServer(FakeMachine(time.monotonic), pty=True) as server:
        server.start()
        yield server


def test_pty_banner_on_open_and_again_on_reopen(pty_server: GrblServer) -> None:
    for connection, hello in ((1, BANNER + UNLOCK), (2, BANNER)):  # unlocked the first time
        with serial.Serial(pty_server.path, 115200, timeout=0.05) as port:
            assert read_until(port.read, hello[-10:]) == hello
            port.write(b"$X\n")
            assert read_until(port.read, b"ok\r\n").endswith(b"ok\r\n")
        assert pty_server.connections == connection
        time.sleep(0.05)  # long enough for the server to see the terminal closed
    assert pty_server.error is None


def test_pty_streams_a_program_in_real_time(pty_server: GrblServer) -> None:
    with serial.Serial(pty_server.path, 115200, timeout=0.05) as port:
        read_until(port.read, UNLOCK)
        port.write(b"$X\nG1X2F1200\nG4P0.01\n")
        assert read_until(port.read, b"ok\r\nok\r\nok\r\n", timeout_s=2.0).endswith(
            b"ok\r\nok\r\nok\r\n")
        port.write(b"?")
        assert read_until(port.read, b">\r\n").startswith(b"<Idle|MPos:2.000,0.000,0.000|")


def test_pty_link_made_and_removed(tmp_path: Path) -> None:
    link = tmp_path / "grbl"
    with GrblServer(FakeMachine(time.monotonic), pty=True, link=str(link)) as server:
        assert os.readlink(link) == server.path
    assert not link.exists() and not link.is_symlink()


def test_a_live_link_is_refused_in_one_line_and_a_stale_one_replaced(tmp_path: Path) -> None:
    link = tmp_path / "ttyGRBL"
    with GrblServer(FakeMachine(time.monotonic), pty=True, link=str(link)) as live:
        done = subprocess.run([sys.executable, "-m", "usbmotion", "grbl", "--link", str(link)],
                              capture_output=True, text=True, timeout=120, check=False)
        name = Path("/proc/self/comm").read_text().strip()
        assert (done.returncode, done.stdout) == (2, "")
        assert done.stderr == (
            f"usbmotion grbl: link {link} points at {live.path}, a terminal another server"
            f" still serves (process {os.getpid()} ({name})); stop that server or give"
            " another link\n")
        assert os.readlink(link) == live.path
    link.symlink_to("/dev/pts/999999")  # what a server killed with SIGKILL leaves
    with GrblServer(FakeMachine(time.monotonic), pty=True, link=str(link)) as server:
        assert os.readlink(link) == server.path


def test_one_sender_at_a_time_on_the_terminal() -> None:
    notices: list[str] = []
    with GrblServer(FakeMachine(time.monotonic), pty=True, on_notice=notices.append) as server:
        server.start()
        with serial.Serial(server.path, 115200, timeout=0.05, exclusive=True) as port:
            assert read_until(port.read, UNLOCK) == BANNER + UNLOCK
            with pytest.raises(serial.SerialException):
                serial.Serial(server.path, exclusive=True)  # refused by the sender's lock
            descriptor = os.open(server.path, os.O_RDWR | os.O_NOCTTY)  # no lock asked
            os.close(descriptor)
            deadline = time.monotonic() + 3
            while len(notices) < 2 and time.monotonic() < deadline:
                time.sleep(0.01)
            # the locking client opened before its lock was refused; the plain one got in
            assert len(notices) == 2 and all(notice.startswith(
                f"a second program opened {server.path} while a sender has it")
                for notice in notices)
            port.write(b"$I\n")
            assert read_until(port.read, b"ok\r\n").startswith(b"[VER:1.1h.")
        assert server.connections == 1


def test_tcp_banner_per_connection_the_newest_wins() -> None:
    with GrblServer(FakeMachine(time.monotonic, homing=False), pty=False) as server:
        server.start()
        with socket.create_connection(("127.0.0.1", server.port)) as first:
            first.settimeout(0.05)
            assert read_until(_recv(first), BANNER) == BANNER
            with socket.create_connection(("127.0.0.1", server.port)) as second:
                second.settimeout(0.05)
                assert read_until(_recv(second), BANNER) == BANNER
                first.settimeout(2.0)
                assert first.recv(100) == b""  # closed by the server: end of file
                second.sendall(b"$I\n")
                assert read_until(_recv(second), b"ok\r\n").startswith(b"[VER:1.1h.")
        assert server.connections == 2


def _recv(sock: socket.socket) -> object:
    def read(size: int) -> bytes:
        try:
            return sock.recv(size)
        except TimeoutError:
            return b""
        except OSError:
            return b""
    return read


def test_a_long_line_of_comment_is_drained_as_it_comes_not_dropped() -> None:
    line = b"G1 X1 F600 (" + b"a long comment, " * 20 + b")\n"  # 333 bytes
    with GrblServer(FakeMachine(time.monotonic, homing=False), pty=False) as server:
        server.start()
        with socket.create_connection(("127.0.0.1", server.port)) as client:
            client.settimeout(0.05)
            read_until(_recv(client), BANNER)
            client.sendall(line)
            assert read_until(_recv(client), b"ok\r\n") == b"ok\r\n"
        assert server.protocol.statistics.dropped_rx_bytes == 0


def test_tcp_binds_loopback_by_default() -> None:
    with GrblServer(FakeMachine(time.monotonic), pty=False) as server:
        assert isinstance(server.endpoint, TcpEndpoint)
        assert server.endpoint.listener.getsockname()[0] == "127.0.0.1"


@pytest.mark.parametrize(("options", "message"), [
    ({"pty": False, "tcp_port": 70000}, "tcp_port 70000 is not a TCP port number 0..65535"),
    ({"pty": False, "link": "/tmp/x"}, "link '/tmp/x' needs a pseudo-terminal"),
    ({"poll_s": 1.0}, "poll_s 1.0 s is out of range 0.001..0.05 s"),
])
def test_bad_options_say_what_is_allowed(options: dict[str, object], message: str) -> None:
    with pytest.raises(ArgumentError, match=message.replace(".", r"\.")):
        GrblServer(FakeMachine(time.monotonic), **options)  # type: ignore[arg-type]


def test_close_twice_is_safe() -> None:
    server = GrblServer(FakeMachine(time.monotonic), pty=True).start()
    server.close()
    server.close()


SERVE = """
import sys, time
sys.path.insert(0, {root!r})
from tests.grbl.fake_machine import FakeMachine
from usbmotion.grbl.server import serve
sys.exit(serve(FakeMachine(time.monotonic), pty=True, link={link!r}, tcp_port=None))
"""


@pytest.mark.parametrize("signal_number", [signal.SIGTERM, signal.SIGINT])
def test_serve_announces_and_exits_cleanly_on_a_signal(tmp_path: Path,
                                                      signal_number: int) -> None:
    link = tmp_path / "grbl"
    process = subprocess.Popen(
        [sys.executable, "-c", SERVE.format(root=str(ROOT), link=str(link))],
        stdout=subprocess.PIPE, text=True, cwd=ROOT)
    try:
        assert process.stdout is not None
        line = process.stdout.readline()
        assert line.startswith("grbl 1.1h serving on /dev/pts/")
        assert f"(link {link})" in line
        with serial.Serial(str(link), 115200, timeout=0.05) as port:
            assert read_until(port.read, UNLOCK) == BANNER + UNLOCK
        process.send_signal(signal_number)
        assert process.wait(timeout=5) == 0
        assert not link.is_symlink()
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
        if process.stdout is not None:
            process.stdout.close()
