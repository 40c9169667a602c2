"""The one serving module (``usbmotion.serving``): a pseudo-terminal or a TCP port served to
one client at a time, in real time.

What Linux does with a second client on a served terminal is tested as it happens, for
root (as CI runs) and, through ``setpriv``, for user ``nobody``: a client that locks its
port, as pyserial's ``exclusive=True`` does, is refused by the first one's lock whoever
runs it; a program that opens it regardless gets in and is reported; an exclusive mode a
client set (``TIOCEXCL``) keeps others out while it holds the terminal, except root, and
ends when it leaves; a client that closes and opens again at once is never refused.
"""

from __future__ import annotations

import errno
import os
import shutil
import socket
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
import serial

from usbmotion.errors import ArgumentError
from usbmotion.serving import (
    Event,
    EventKind,
    Outbox,
    PtyEndpoint,
    SecondClient,
    Serving,
    TcpEndpoint,
    link_problem,
    make_link,
)

pytestmark = pytest.mark.realtime

NOBODY = 65534


def events_until(serving: Serving, wanted: Callable[[list[Event]], bool], *,
                 timeout_s: float = 3.0) -> list[Event]:
    """Every event :meth:`Serving.wait` gives until ``wanted`` holds of them."""
    seen: list[Event] = []
    deadline = time.monotonic() + timeout_s
    while not wanted(seen):
        assert time.monotonic() < deadline, f"only {[e.kind for e in seen]}"
        seen += serving.wait(0.01)
        serving.flush()
    return seen


def kinds(events: list[Event]) -> list[EventKind]:
    return [event.kind for event in events]


@pytest.fixture
def pty() -> Iterator[tuple[Serving, PtyEndpoint]]:
    endpoint = PtyEndpoint(label="test")
    with Serving([endpoint]) as serving:
        yield serving, endpoint


# --- the outbox ---------------------------------------------------------------------------


def test_an_outbox_keeps_at_most_its_bound_and_counts_what_it_drops() -> None:
    box = Outbox(max_bytes=10)
    box.add(b"0123456")
    box.add(b"789abc")
    assert len(box) == 10 and box.dropped_bytes == 3
    taken: list[bytes] = []

    def write(data: bytearray) -> int:
        taken.append(bytes(data[:4]))
        return 4

    box.write_to(write)
    assert taken == [b"0123"] and len(box) == 6
    box.clear()
    assert len(box) == 0 and box.dropped_bytes == 9
    with pytest.raises(ArgumentError, match="max_bytes 0 must be >= 1"):
        Outbox(0)


# --- a pseudo-terminal ----------------------------------------------------------------------


def test_a_terminal_reports_its_client_coming_its_bytes_and_its_leaving(
        pty: tuple[Serving, PtyEndpoint]) -> None:
    serving, endpoint = pty
    endpoint.send(b"nobody hears this\n")
    assert endpoint.dropped_bytes == 18, "output while no client is there is dropped"
    with serial.Serial(endpoint.path, timeout=1, exclusive=True) as client:
        events = events_until(serving, lambda seen: EventKind.CONNECTED in kinds(seen))
        assert kinds(events) == [EventKind.CONNECTED] and endpoint.connected
        client.write(b"18 -1\n")
        events = events_until(serving, lambda seen: EventKind.DATA in kinds(seen))
        assert b"".join(e.data for e in events) == b"18 -1\n"
        endpoint.send(b"DEVICE_NAME X\n")
        serving.flush()
        assert client.readline() == b"DEVICE_NAME X\n"
    events = events_until(serving, lambda seen: EventKind.DISCONNECTED in kinds(seen))
    assert kinds(events) == [EventKind.DISCONNECTED] and not endpoint.connected
    with serial.Serial(endpoint.path, timeout=0.2) as again:
        events_until(serving, lambda seen: EventKind.CONNECTED in kinds(seen))
        assert endpoint.connections == 2
        endpoint.send(b"hello\n")
        serving.flush()
        assert again.readline() == b"hello\n", "nothing the first client left unread"


def _as_nobody(code: str) -> subprocess.Popen[str]:
    """``python -c CODE`` as a process without CAP_SYS_ADMIN (user ``nobody`` when the tests
    run as root)."""
    prefix = ([] if os.geteuid() != 0 else
              ["setpriv", f"--reuid={NOBODY}", f"--regid={NOBODY}", "--clear-groups"])
    return subprocess.Popen([*prefix, sys.executable, "-c", code], stdout=subprocess.PIPE,
                            text=True)


def _open_as_nobody(path: str, *, exclusive: bool = False,
                    hold_s: float = 0.0) -> subprocess.Popen[str]:
    """Open ``path`` without CAP_SYS_ADMIN (and make it exclusive): prints ``opened`` or
    the errno."""
    return _as_nobody(
        "import fcntl, os, sys, termios, time\n"
        "try:\n"
        f"    fd = os.open({path!r}, os.O_RDWR | os.O_NOCTTY)\n"
        "except OSError as error:\n"
        "    print(error.errno, flush=True); sys.exit(0)\n"
        f"if {exclusive}: fcntl.ioctl(fd, termios.TIOCEXCL)\n"
        f"print('opened', flush=True); time.sleep({hold_s})\n")


NOT_AS_ANOTHER_USER = pytest.mark.skipif(
    os.geteuid() == 0 and shutil.which("setpriv") is None,
    reason="running as root, and no setpriv to open as another user")


@NOT_AS_ANOTHER_USER
def test_an_exclusive_mode_a_client_set_ends_when_it_leaves(
        pty: tuple[Serving, PtyEndpoint]) -> None:
    serving, endpoint = pty
    if os.geteuid() == 0:
        os.chmod(endpoint.path, 0o666)  # the other user may open it
    first = _open_as_nobody(endpoint.path, exclusive=True, hold_s=1.5)
    try:
        assert first.stdout is not None
        assert first.stdout.readline().strip() == "opened"
        events_until(serving, lambda seen: EventKind.CONNECTED in kinds(seen))
        second = _open_as_nobody(endpoint.path)
        assert second.communicate(timeout=30)[0].strip() == str(errno.EBUSY)
    finally:
        first.communicate(timeout=30)
    events_until(serving, lambda seen: EventKind.DISCONNECTED in kinds(seen))
    third = _open_as_nobody(endpoint.path)
    assert third.communicate(timeout=30)[0].strip() == "opened", "as a port at its last close"


@NOT_AS_ANOTHER_USER
def test_a_client_that_closes_and_opens_again_at_once_is_never_refused(
        pty: tuple[Serving, PtyEndpoint]) -> None:
    """As discovery's probe, then the connection: 100 times, 3 ms apart."""
    serving, endpoint = pty
    if os.geteuid() == 0:
        os.chmod(endpoint.path, 0o666)
    client = _as_nobody(
        "import os, time\n"
        "refused = 0\n"
        "for _ in range(100):\n"
        "    try:\n"
        f"        fd = os.open({endpoint.path!r}, os.O_RDWR | os.O_NOCTTY)\n"
        "    except OSError:\n"
        "        refused += 1; continue\n"
        "    time.sleep(0.003); os.close(fd)\n"
        "print(refused, flush=True)\n")
    while client.poll() is None:
        serving.wait(0.001)
    assert client.communicate(timeout=30)[0].strip() == "0"


def test_a_second_program_that_opens_the_terminal_is_reported(
        pty: tuple[Serving, PtyEndpoint]) -> None:
    serving, endpoint = pty
    with serial.Serial(endpoint.path, timeout=0.2):
        events_until(serving, lambda seen: EventKind.CONNECTED in kinds(seen))
        descriptor = os.open(endpoint.path, os.O_RDWR | os.O_NOCTTY)  # no lock asked
        try:
            events = events_until(
                serving, lambda seen: EventKind.SECOND_CLIENT in kinds(seen))
            assert [e.detail for e in events if e.kind is EventKind.SECOND_CLIENT] == [
                endpoint.path]
        finally:
            os.close(descriptor)
        assert endpoint.connected, "the first still has it"


def test_a_client_that_locks_its_port_is_refused_while_another_holds_it(
        pty: tuple[Serving, PtyEndpoint]) -> None:
    serving, endpoint = pty
    with serial.Serial(endpoint.path, timeout=0.2, exclusive=True):
        events_until(serving, lambda seen: EventKind.CONNECTED in kinds(seen))
        with pytest.raises(serial.SerialException,
                           match=r"Could not exclusively lock port|Device or resource busy"):
            serial.Serial(endpoint.path, exclusive=True)


# --- a link to the terminal ---------------------------------------------------------------


def test_a_link_is_made_and_removed_with_its_terminal(tmp_path: Path) -> None:
    link = tmp_path / "ttyX"
    endpoint = PtyEndpoint(link=link)
    try:
        assert os.readlink(link) == endpoint.path
    finally:
        endpoint.close()
    assert not link.is_symlink()


def test_a_live_link_is_refused_naming_its_server_and_a_stale_one_replaced(
        tmp_path: Path) -> None:
    link = tmp_path / "ttyGRBL"
    with Serving([PtyEndpoint(link=link)]) as serving:
        live = serving.endpoints[0]
        assert isinstance(live, PtyEndpoint)
        with pytest.raises(ArgumentError) as refused:
            PtyEndpoint(link=link)
        assert str(refused.value).startswith(
            f"link {link} points at {live.path}, a terminal another server still serves"
            f" (process {os.getpid()} (")
        assert os.readlink(link) == live.path, "left to its server"
    link.symlink_to("/dev/pts/999999")  # a terminal gone: the link a killed server left
    assert link_problem(link) is None
    endpoint = PtyEndpoint(link=link)
    try:
        assert os.readlink(link) == endpoint.path
    finally:
        endpoint.close()
    (tmp_path / "file").write_text("mine")
    with pytest.raises(ArgumentError, match="is a file, not a link: remove it"):
        make_link(tmp_path / "file", "/dev/pts/0")
    assert (tmp_path / "file").read_text() == "mine"


# --- TCP ------------------------------------------------------------------------------------


def _recv_all(sock: socket.socket, timeout_s: float = 2.0) -> bytes:
    sock.settimeout(timeout_s)
    try:
        return sock.recv(4096)
    except OSError:
        return b""


def test_a_second_tcp_client_is_refused_and_the_first_keeps_the_port() -> None:
    endpoint = TcpEndpoint(second_client=SecondClient.REFUSE)
    with Serving([endpoint]) as serving:
        with socket.create_connection(("127.0.0.1", endpoint.port)) as first:
            events_until(serving, lambda seen: EventKind.CONNECTED in kinds(seen))
            with socket.create_connection(("127.0.0.1", endpoint.port)) as second:
                events = events_until(serving, lambda seen: EventKind.REFUSED in kinds(seen))
                assert kinds(events) == [EventKind.REFUSED]
                assert _recv_all(second) == b"", "closed at once"
            first.sendall(b"still mine\n")
            events = events_until(serving, lambda seen: EventKind.DATA in kinds(seen))
            assert events[-1].data == b"still mine\n"
        events_until(serving, lambda seen: EventKind.DISCONNECTED in kinds(seen))
        with socket.create_connection(("127.0.0.1", endpoint.port)) as third:
            events_until(serving, lambda seen: EventKind.CONNECTED in kinds(seen))
            endpoint.send(b"yours now\n")
            serving.flush()
            assert _recv_all(third) == b"yours now\n"


def test_a_second_tcp_client_replaces_the_first_where_the_endpoint_says() -> None:
    endpoint = TcpEndpoint(second_client=SecondClient.REPLACE)
    with Serving([endpoint]) as serving:
        with socket.create_connection(("127.0.0.1", endpoint.port)) as first:
            events_until(serving, lambda seen: EventKind.CONNECTED in kinds(seen))
            with socket.create_connection(("127.0.0.1", endpoint.port)) as second:
                events = events_until(
                    serving, lambda seen: kinds(seen).count(EventKind.CONNECTED) == 1)
                assert kinds(events) == [EventKind.DISCONNECTED, EventKind.CONNECTED]
                assert _recv_all(first) == b"", "the first was closed"
                endpoint.send(b"to the second\n")
                serving.flush()
                assert _recv_all(second) == b"to the second\n"
        assert endpoint.connections == 2


def test_a_taken_tcp_port_and_a_bad_one_are_said_plainly() -> None:
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        with pytest.raises(OSError, match=f"cannot listen on 127.0.0.1:{port}: Address"
                           " already in use"):
            TcpEndpoint("127.0.0.1", port)
    with pytest.raises(ArgumentError, match="tcp_port 70000 is not a TCP port number"):
        TcpEndpoint("127.0.0.1", 70000)
