"""cncjs (npm) against the grbl server on a pseudo-terminal, with the fake machine and with
a real machine session (the simulated machine in real time, as ``usbmotion grbl`` serves
it): its server runs headless on 127.0.0.1 and opens the terminal as a Grbl controller;
once through its Socket.IO API (unlock, home, jog, upload and run a program, hold and
resume it) and once through its web page in headless Chromium (the DRO shows where the
program ended). On the simulated machine, what its devices executed is the program's path,
the hold and resume included."""

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
    MEASUREMENTS,
    NODE_MODULES,
    PROGRAM,
    PROGRAM_LINES,
    PROGRAM_PATH,
    SHORT_PROGRAM,
    SHORT_PROGRAM_PATH,
    need,
    node_package,
    path_deviation,
    record,
    served_fake,
    served_real,
    tap_received,
    wait_for,
)

pytestmark = pytest.mark.realtime

ROOT = HERE.parents[1]
CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
SCREENSHOT = ROOT / "build" / "senders" / "cncjs-page.png"
PAGE_PROGRAM = "G21 G90\nG1 X12.5 Y7.25 F3000\nG0 Z-1\n"
PAGE_PATH = [(12.5, 7.25, 0.0), (12.5, 7.25, -1.0)]
"""A move, then a rapid 1 mm down from the top of Z's travel, where homing leaves it."""
JOG = "$J=G91 G21 X20 Y10 F1200"
"""The jog on the simulated machine (within its travel from home at 0): 1.1 s, so seen in
cncjs's reports every 250 ms."""
JOG_END = (20.0, 10.0, 0.0)
AT_REST_MM = 0.02
"""How far the simulated machine's encoders may stand from where it was sent, at rest."""
SESSION_LOG = MEASUREMENTS / "cncjs-session.log"


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


ON_THE_FAKE = pytest.mark.skipif(
    os.environ.get("USBMOTION_FAKE_SENDERS") != "1",
    reason="cncjs on the fake machine: USBMOTION_FAKE_SENDERS=1 runs it (the tests on the"
    " simulated machine session below cover the same, in the suite's time budget)")


@ON_THE_FAKE
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
    assert seen["final"] == {"x": "0.000", "y": "0.000", "z": "-1.000"}
    assert "feed_hold" in machine.calls and "cycle_start" in machine.calls
    statistics = server.protocol.statistics
    problems = path_problems([done.target_mm for done in machine.done],
                             [(20.0, -10.0, 0.0), *PROGRAM_PATH])  # the jog, the program
    record("cncjs", statistics, path_problems=problems)
    assert statistics.dropped_rx_bytes == 0
    assert 0 < statistics.max_rx_bytes <= 128
    assert problems == []


@ON_THE_FAKE
def test_cncjs_web_page_runs_a_program_and_its_dro_shows_the_end(cncjs: Cncjs) -> None:
    need(node_package("playwright-core") and Path(CHROMIUM).exists(),
         "playwright-core (npm) with Chromium (Debian package chromium)")
    program = cncjs.folder / "page.nc"
    program.write_text(PAGE_PROGRAM)
    SCREENSHOT.parent.mkdir(parents=True, exist_ok=True)
    wanted = ["12.500", "7.250", "-1.000"]
    with served_fake(link=str(cncjs.link)) as (server, machine):
        seen = _node("cncjs_page.js", f"{cncjs.url}/", str(cncjs.link), str(program),
                     str(SCREENSHOT), CHROMIUM, env={"DRO_EXPECTED": json.dumps(wanted)})
    problems = path_problems([done.target_mm for done in machine.done], PAGE_PATH)
    record("cncjs-page", server.protocol.statistics, path_problems=problems)
    assert seen["machinePosition"] == wanted
    assert server.protocol.statistics.dropped_rx_bytes == 0
    assert problems == []


def _near(shown: object, where: tuple[float, ...]) -> bool:
    """Whether cncjs's position ``{"x": "1.000", ...}`` is within :data:`AT_REST_MM` of
    ``where``."""
    assert isinstance(shown, dict), shown
    return all(abs(float(shown[axis]) - value) <= AT_REST_MM
               for axis, value in zip("xyz", where, strict=True))


def _write_session_log(received: list[tuple[float, str]], log: list[list[object]]) -> float:
    """Write what the front received and what cncjs reported, in time order, to
    :data:`SESSION_LOG`; the seconds from cncjs's gcode:start to its workflow's idle."""
    lines = [(at, f"front  received {text}") for at, text in received]
    lines += [(float(at) / 1000.0, f"cncjs  {text}") for at, text in log]  # type: ignore[arg-type]
    lines.sort(key=lambda entry: entry[0])
    origin = lines[0][0]
    SESSION_LOG.parent.mkdir(parents=True, exist_ok=True)
    SESSION_LOG.write_text(
        "# cncjs through its Socket.IO API with usbmotion grbl's front on the simulated\n"
        "# machine in real time: the lines (and real-time bytes but ?) the front received,\n"
        "# and what cncjs wrote, read and reported (each status change).\n"
        + "".join(f"{at - origin:8.3f}  {text}\n" for at, text in lines))
    start = next(at for at, text in lines if text.endswith("gcode:start"))
    end = max(at for at, text in lines if text.endswith("workflow idle"))
    return end - start


def test_cncjs_socket_api_homes_jogs_runs_holds_and_resumes_on_the_simulated_machine(
        cncjs: Cncjs, tmp_path: Path) -> None:
    assert SHORT_PROGRAM.endswith("M2\n")
    program = cncjs.folder / "short.nc"
    program.write_text(SHORT_PROGRAM)
    with served_real(tmp_path, link=str(cncjs.link)) as real:
        received = tap_received(real.server)
        seen = _node("cncjs_session.js", cncjs.url, str(cncjs.link), str(program),
                     env={"JOG": JOG})
        wait_for(real.idle, timeout_s=10, what="the machine at rest")
        executed = real.executed_mm()
    log = seen["log"]
    assert isinstance(log, list)
    run_s = _write_session_log(received, log)
    assert seen["alarms"] == [] and seen["errors"] == []
    states = seen["states"]
    assert isinstance(states, list)
    for state in ("Alarm", "Home", "Jog", "Run", "Hold", "Idle"):
        assert state in states
    lines = SHORT_PROGRAM.count("\n") + 1  # and cncjs's %wait
    assert seen["sender"] == {"total": lines, "sent": lines, "received": lines}
    assert _near(seen["afterJog"], JOG_END), seen["afterJog"]
    assert isinstance(seen["held"], dict)
    assert _near(seen["stillHeld"], tuple(float(v) for v in seen["held"].values()))
    assert _near(seen["final"], (0.0, 0.0, -1.0)), seen["final"]
    words = [text for _, text in received]
    assert "! (feed hold)" in words and "~ (cycle start)" in words
    statistics = real.server.protocol.statistics
    problems, deviation_mm = path_deviation(executed,
                                            [(0.0, 0.0, 0.0), JOG_END, *SHORT_PROGRAM_PATH])
    record("cncjs-simulated", statistics, path_problems=problems, machine="simulated",
           path_deviation_mm=deviation_mm, run_s=run_s,
           run_from="cncjs's gcode:start to its workflow idle, the hold included")
    assert statistics.dropped_rx_bytes == 0
    assert 0 < statistics.max_rx_bytes <= 128
    assert problems == [], real.messages
    assert not [m for m in real.messages if m.startswith("error")], real.messages


def test_cncjs_web_page_homes_runs_a_program_and_its_dro_shows_the_end_on_the_simulated_machine(
        cncjs: Cncjs, tmp_path: Path) -> None:
    need(node_package("playwright-core") and Path(CHROMIUM).exists(),
         "playwright-core (npm) with Chromium (Debian package chromium)")
    program = cncjs.folder / "page.nc"
    program.write_text(PAGE_PROGRAM)
    screenshot = SCREENSHOT.with_name("cncjs-page-simulated.png")
    screenshot.parent.mkdir(parents=True, exist_ok=True)
    wanted = ["12.500", "7.250", "-1.000"]
    with served_real(tmp_path, link=str(cncjs.link)) as real:
        started = time.monotonic()
        seen = _node("cncjs_page.js", f"{cncjs.url}/", str(cncjs.link), str(program),
                     str(screenshot), CHROMIUM,
                     env={"DRO_EXPECTED": json.dumps(wanted), "HOMING": "1",
                          "DRO_TOLERANCE_MM": str(AT_REST_MM)})
        wait_for(real.idle, timeout_s=10, what="the machine at rest")
        run_s = time.monotonic() - started
        executed = real.executed_mm()
    problems, deviation_mm = path_deviation(executed, [(0.0, 0.0, 0.0), *PAGE_PATH])
    statistics = real.server.protocol.statistics
    record("cncjs-page-simulated", statistics, path_problems=problems, machine="simulated",
           path_deviation_mm=deviation_mm, run_s=run_s,
           run_from="the browser's start to the machine at rest, homing included")
    shown = seen["machinePosition"]
    assert isinstance(shown, list)
    assert all(abs(float(a) - float(b)) <= AT_REST_MM for a, b in zip(shown, wanted, strict=True)
               ), shown
    assert statistics.dropped_rx_bytes == 0
    assert problems == [], real.messages


PLATE_MM = -12.0
"""Where the touch plate's top is under Z (machine mm) for the probe widget's test."""
TOUCH_PLATE_MM = 10.0
PROBE_LINES = ("G91", "G38.2 Z-15 F200", "G90", f"G10 L20 P1 Z{TOUCH_PLATE_MM:g}", "G91",
               "G0 Z4", "G90")
"""cncjs's probe widget's Z probe (its lines for a 15 mm probe depth at 200 mm/min, a 10 mm
touch plate and a 4 mm retraction)."""


def test_cncjs_probe_widget_zeroes_z_on_the_touch_plate(cncjs: Cncjs, tmp_path: Path) -> None:
    """The widget's lines through cncjs: the probe stops on the plate (``[PRB:...:1]`` at the
    plate's height to the count, before G38.2's ``ok``), G10 L20 makes the contact work Z =
    the plate's thickness (work Z0 on the workpiece under the plate), the retraction ends
    4 mm above the plate."""
    with served_real(tmp_path, link=str(cncjs.link), plate_mm=PLATE_MM) as real:
        seen = _node("cncjs_probe.js", cncjs.url, str(cncjs.link),
                     env={"PROBE_LINES": "\n".join(PROBE_LINES)})
        wait_for(real.idle, timeout_s=10, what="the machine at rest")
        offsets = real.session.work_offsets()
        probe = real.session.last_probe
        final_z = real.session.positions_mm()["Z"]
    assert seen["alarms"] == [] and seen["errors"] == [], seen
    reads = seen["reads"]
    assert isinstance(reads, list)
    found = [line for line in reads if line.startswith("[PRB:")]
    assert len(found) == 1 and found[0].endswith(":1]"), found
    z = float(found[0].removeprefix("[PRB:").split(":")[0].split(",")[2])
    assert abs(z - PLATE_MM) <= 1.0 / 240 + 1e-9, f"{found[0]}: the plate to the count"
    assert probe is not None and probe.position_mm["Z"] == pytest.approx(z, abs=1e-3)
    assert offsets.g5x[0][2] == pytest.approx(z - TOUCH_PLATE_MM, abs=1e-3)
    # cncjs's own last report may come before the retraction ran (a line's ok comes as it
    # reaches the planner): where the machine stands once at rest, from its encoders.
    assert final_z == pytest.approx(z + 4.0, abs=AT_REST_MM)
