"""cncjs (npm) against the grbl server on a pseudo-terminal, with the fake machine: its
server runs headless on 127.0.0.1 and opens the terminal as a Grbl controller; once through
its Socket.IO API (unlock, home, jog, upload and run a program, hold and resume it) and once
through its web page in headless Chromium (the DRO shows where the program ended)."""

from __future__ import annotations

import json
import os
import shutil
import socket
import subprocess
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
from tests.grbl.conformance import path_problems
from tests.senders.helpers import (
    HERE,
    NODE_MODULES,
    PROGRAM,
    PROGRAM_LINES,
    PROGRAM_PATH,
    need,
    node_package,
    record,
    served_fake,
)

pytestmark = pytest.mark.realtime

ROOT = HERE.parents[1]
CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
SCREENSHOT = ROOT / "build" / "senders" / "cncjs-page.png"
PAGE_PROGRAM = "G21 G90\nG1 X12.5 Y7.25 F3000\nG0 Z1\n"
PAGE_PATH = [(12.5, 7.25, 0.0), (12.5, 7.25, 1.0)]


@dataclass(frozen=True, slots=True)
class Cncjs:
    """A cncjs server running for the module's tests."""

    url: str
    link: Path
    """Where each test's pseudo-terminal is linked: the port listed in cncjs's config."""
    folder: Path


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port: int = probe.getsockname()[1]
        return port


@pytest.fixture(scope="module")
def cncjs(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Cncjs]:
    need(node_package("cncjs") and node_package("socket.io-client"), "cncjs (npm)")
    if shutil.which("udevadm") is None:
        need(False, "udevadm (Debian package udev: cncjs lists serial ports with it)")
    folder = tmp_path_factory.mktemp("cncjs")
    link = folder / "ttyGRBL"
    config = folder / "cncrc"
    config.write_text(json.dumps({
        "secret": "usbmotion-grbl-tests",
        "state": {"checkForUpdates": False, "allowAnonymousUsageDataCollection": False},
        "ports": [{"path": str(link), "manufacturer": "usbmotion grbl"}],
    }))
    port = _free_port()
    log = (folder / "cncjs.log").open("w")
    process = subprocess.Popen(
        ["node", str(NODE_MODULES / "cncjs" / "bin" / "cncjs"), "--host", "127.0.0.1",
         "--port", str(port), "--config", str(config)],
        stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
        env={**os.environ, "HOME": str(folder)})
    try:
        deadline = time.monotonic() + 60
        while True:
            try:
                socket.create_connection(("127.0.0.1", port), timeout=1).close()
                break
            except OSError:
                if process.poll() is not None or time.monotonic() > deadline:
                    raise AssertionError("cncjs did not start: "
                                         + (folder / "cncjs.log").read_text()[-2000:]) from None
                time.sleep(0.05)
        yield Cncjs(f"http://127.0.0.1:{port}", link, folder)
    finally:
        process.terminate()
        try:
            process.wait(timeout=10)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()
        log.close()


def _node(script: str, *args: str, env: dict[str, str] | None = None) -> dict[str, object]:
    result = subprocess.run(["node", str(HERE / script), *args], check=False, capture_output=True,
                            text=True, timeout=90, cwd=HERE, stdin=subprocess.DEVNULL,
                            env={**os.environ, **(env or {})})
    assert result.returncode == 0, f"{script} failed:\n{result.stderr[-3000:]}"
    outcome: dict[str, object] = json.loads(result.stdout.strip().splitlines()[-1])
    return outcome


def test_cncjs_socket_api_homes_jogs_runs_holds_and_resumes(cncjs: Cncjs) -> None:
    program = cncjs.folder / "square.nc"
    program.write_text(PROGRAM)
    with served_fake(link=str(cncjs.link)) as (server, machine):
        seen = _node("cncjs_session.js", cncjs.url, str(cncjs.link), str(program))
    assert seen["alarms"] == [] and seen["errors"] == []
    states = seen["states"]
    assert isinstance(states, list)
    for state in ("Alarm", "Home", "Jog", "Run", "Hold", "Idle"):
        assert state in states
    lines = PROGRAM_LINES + 1  # and cncjs's %wait
    assert seen["sender"] == {"total": lines, "sent": lines, "received": lines}
    assert seen["afterJog"] == {"x": "20.000", "y": "-10.000", "z": "0.000"}
    assert seen["held"] == seen["stillHeld"]  # held means at rest
    assert seen["final"] == {"x": "0.000", "y": "0.000", "z": "1.000"}
    assert "feed_hold" in machine.calls and "cycle_start" in machine.calls
    statistics = server.protocol.statistics
    problems = path_problems([done.target_mm for done in machine.done],
                             [(20.0, -10.0, 0.0), *PROGRAM_PATH])  # the jog, the program
    record("cncjs", statistics, path_problems=problems)
    assert statistics.dropped_rx_bytes == 0
    assert 0 < statistics.max_rx_bytes <= 128
    assert problems == []


def test_cncjs_web_page_runs_a_program_and_its_dro_shows_the_end(cncjs: Cncjs) -> None:
    need(node_package("playwright-core") and Path(CHROMIUM).exists(),
         "playwright-core (npm) with Chromium (Debian package chromium)")
    program = cncjs.folder / "page.nc"
    program.write_text(PAGE_PROGRAM)
    SCREENSHOT.parent.mkdir(parents=True, exist_ok=True)
    wanted = ["12.500", "7.250", "1.000"]
    with served_fake(link=str(cncjs.link)) as (server, machine):
        seen = _node("cncjs_page.js", f"{cncjs.url}/", str(cncjs.link), str(program),
                     str(SCREENSHOT), CHROMIUM, env={"DRO_EXPECTED": json.dumps(wanted)})
    problems = path_problems([done.target_mm for done in machine.done], PAGE_PATH)
    record("cncjs-page", server.protocol.statistics, path_problems=problems)
    assert seen["machinePosition"] == wanted
    assert server.protocol.statistics.dropped_rx_bytes == 0
    assert problems == []
