"""``usbmotion sim`` as a process: it prints a device's address only once the device answers
(a plain client's first exchanges are right, even on a cold numba cache), and SIGTERM or
SIGINT ends it within a second or two, every terminal closed. The machine file that goes
with it (``examples/served-machine.toml``) finds its devices once they are named, and a
device on TCP serves one host at a time."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest
import serial
from typer.testing import CliRunner

from usbmotion.cli.main import app
from usbmotion.device import Device, MemoryFlash
from usbmotion.sim.server import DeviceServer
from usbmotion.sim.world import SimWorld

ROOT = Path(__file__).resolve().parents[1]
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
    """Signalled while it makes the kernel's machine code (an empty cache: seconds of
    start-up), the server ends at once."""
    cache = tmp_path / "numba-cache"
    cache.mkdir()
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache)}
    with sim_process(tmp_path, "--pty", "1", env=env) as process:
        time.sleep(0.3)  # importing or compiling, the devices not served yet
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
    assert any(cache.rglob("kernel-*.code")), "the kernel was compiled into the fresh cache"


PROGRAM = "G21 G90\nG1 X10 Y5 Z-3 F1200\nG1 X5 Y10\nG53 G0 Z0\nM2\n"
"""A short program for the served machine (real time: its homing takes seconds already),
ending with a CAM post's retract to the top of Z (where a servo settles a count or two
beyond the travel's end: the next run starts from there)."""


@pytest.mark.realtime
def test_the_served_machine_file_finds_sim_s_devices_once_they_are_named(
        tmp_path: Path) -> None:
    """``usbmotion sim --pty 3`` serves fresh devices; examples/served-machine.toml, which
    names its devices, says how to name them, ``usbmotion name`` names each from the file,
    and two runs in a row complete (the second on the machine the first left homed)."""
    machine = tmp_path / "served-machine.toml"
    machine.write_text((ROOT / "examples" / "served-machine.toml").read_text())
    program = tmp_path / "square.ngc"
    program.write_text(PROGRAM)

    def usbmotion(*args: str) -> tuple[int, str, str]:
        result = CliRunner().invoke(app, list(args))
        return result.exit_code, result.stdout, result.stderr

    def run() -> tuple[int, str, str]:
        return usbmotion("run", str(program), "-m", str(machine), "-q", "--no-plot")

    with sim_process(tmp_path / "flash", "--pty", "3") as process:
        paths = _paths(process, 3)
        code, _, err = run()
        assert code == 1, err
        assert err.startswith("usbmotion run: device 'X AXIS' not found; searched")
        assert err.endswith(
            "3 of them answer the default name of a device never named: give each the name"
            " its axis has in the machine file, once (usbmotion name AXIS PORT --machine"
            " FILE)\n")
        for letter, path in zip("XYZ", paths, strict=True):
            code, out, err = usbmotion("name", letter, path, "-m", str(machine))
            assert code == 0, err
            assert out == (f"{path}: 'GENERIC USB MOTION DEVICE' -> '{letter} AXIS' (axis"
                           f" {letter} of {machine}), kept in the device's flash\n")
        (first_code, first, err), (second_code, second, _) = run(), run()
        assert first_code == second_code == 0, err
        assert "result         completed" in first and "result         completed" in second
        assert "homing         0.000 s" in second, "the first left it homed"


@pytest.mark.realtime
def test_a_device_on_tcp_serves_one_host_and_refuses_a_second() -> None:
    world = SimWorld()
    world.add(Device(flash=MemoryFlash()), key="0")
    notices: list[str] = []
    with DeviceServer(world, pty=False, on_notice=notices.append) as server:
        server.warm_up()
        server.start()
        port = server.endpoints[0].port
        with socket.create_connection(("127.0.0.1", port), timeout=5) as host:
            host.sendall(b"18 -1\n")
            assert host.makefile("rb").readline() == b"DEVICE_NAME GENERIC USB MOTION DEVICE\n"
            with socket.create_connection(("127.0.0.1", port), timeout=5) as second:
                assert second.recv(100) == b"", "closed at once"
            host.sendall(b"18 -1\n")
            assert host.makefile("rb").readline() == b"DEVICE_NAME GENERIC USB MOTION DEVICE\n"
        assert len(notices) == 1 and notices[0].startswith(
            f"device 'GENERIC USB MOTION DEVICE' (port {port}): refused a second client from"
            " 127.0.0.1:")
        with socket.create_connection(("127.0.0.1", port), timeout=5) as next_host:
            next_host.sendall(b"18 -1\n")
            assert next_host.makefile("rb").readline().startswith(b"DEVICE_NAME ")


def test_sim_firmware_without_a_boot_rom_says_where_it_looked_in_one_line(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    image = tmp_path / "usbmotion.uf2"
    image.write_bytes(b"UF2")
    image.with_suffix(".elf").write_bytes(b"ELF")
    missing = tmp_path / "b1.bin"
    args = ["sim", "--firmware", str(image), "--pty", "1", "--flash-dir", str(tmp_path)]
    result = CliRunner().invoke(app, [*args, "--bootrom", str(missing)])
    assert (result.exit_code, result.stdout) == (2, "")
    assert result.stderr == (
        f"usbmotion sim: no RP2040 boot ROM at {missing} (given: no such file); the emulator"
        " runs the chip's boot ROM B1 (16384 bytes): give --bootrom PATH (or set"
        " USBMOTION_BOOTROM); it is built from github.com/raspberrypi/pico-bootrom (version"
        " B1), and wokwi/rp2040js embeds a copy in demo/bootrom.ts\n")
    missing.write_bytes(b"\0" * 100)
    monkeypatch.setenv("USBMOTION_BOOTROM", str(missing))
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 2
    assert result.stderr.startswith(f"usbmotion sim: no RP2040 boot ROM at {missing} (from"
                                    " $USBMOTION_BOOTROM: 100 bytes, not 16384); ")
    result = CliRunner().invoke(app, ["sim", "--pty", "1", "--bootrom", str(missing)])
    assert (result.exit_code, result.stderr) == (
        2, "usbmotion sim: --bootrom needs --firmware (usbmotion sim --help)\n")


def test_make_firmware_ends_saying_where_the_uf2_is_and_how_to_flash_it() -> None:
    shown = subprocess.run(["make", "-n", "-s", "firmware"], cwd=ROOT, capture_output=True,
                           text=True, timeout=60, check=False).stdout
    said = " ".join(line.removeprefix("echo ").strip('"') for line in shown.splitlines()
                    if line.startswith("echo "))
    for words in ("build/firmware/usbmotion.uf2 is built. To flash a Pico with it:",
                  "hold its BOOTSEL button while plugging it in: it shows a USB drive,"
                  " RPI-RP2;", "copy the file there",
                  "picotool load -x build/firmware/usbmotion.uf2",
                  "usbmotion sim --firmware build/firmware/usbmotion.uf2 --pty 3"):
        assert words in said, said
    last = [line for line in shown.splitlines() if line.strip()][-1]
    assert "usbmotion sim --firmware" in last, "said at the end of the target"
