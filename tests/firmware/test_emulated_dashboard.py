"""The dashboard on a machine of three emulated RP2040s: ``usbmotion sim --firmware`` serves
the chips on pseudo-terminals, ``usbmotion web -m`` serves the machine that finds them, and
the page in Chromium (``tests/web/dashboard_page.js``) homes, runs demo 1 with a hold and a
resume, stops a second run, jogs and sends an MDI line, as on the simulated machine. The
highlighted line climbs through the program to its last motion line, the charts redraw at
least 50 times a second, the DRO shows what the API's state holds (within the two counts
an axis at rest may still creep), no console error."""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
import urllib.request
import warnings
from pathlib import Path

import pytest

from usbmotion.demos import demo_path
from usbmotion.sim.firmware import default_uf2
from usbmotion.web.app import page_built

from .emulated import require_emulator
from .jobs import machine_text, served
from .native import ROOT

pytestmark = pytest.mark.realtime

PAGE_SCRIPT = ROOT / "tests" / "web" / "dashboard_page.js"
PLAYWRIGHT = ROOT / "tests" / "senders" / "node_modules" / "playwright-core" / "package.json"
CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
SCREENSHOTS = ROOT / "build" / "web" / "emulated"
START_TIMEOUT_S = 120.0
_LATE_ANSWER = re.compile(r"no answer to call \d+ within [\d.]+ s")
"""A reply later than the machine file's reply_timeout_s, as the server's alarm says it."""


def _need_the_page() -> None:
    why = None
    if not page_built():
        why = "the dashboard's page is not built (make web)"
    elif not PLAYWRIGHT.is_file() or not Path(CHROMIUM).exists():
        why = "playwright-core and Chromium are not installed (tests/senders/install.sh)"
    if why is not None:
        if os.environ.get("CI"):
            pytest.fail(why)
        pytest.skip(why)


def test_the_dashboard_drives_emulated_rp2040s(tmp_path: Path) -> None:
    require_emulator()
    _need_the_page()
    firmware = default_uf2()
    SCREENSHOTS.mkdir(parents=True, exist_ok=True)
    with served(tmp_path / "flash", firmware=firmware) as sim:
        machine = tmp_path / "emulated.toml"
        machine.write_text(machine_text(sim.paths), encoding="utf-8")
        web = subprocess.Popen(
            [sys.executable, "-m", "usbmotion", "web", "--port", "0", "--machine",
             str(machine)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            assert web.stdout is not None
            deadline = time.monotonic() + START_TIMEOUT_S
            address = ""
            while not address and time.monotonic() < deadline:
                line = web.stdout.readline()
                if " at http://" in line:
                    address = line.split(" at ", 1)[1].split()[0]
                elif not line:
                    break
            assert address, f"usbmotion web did not start: {web.poll()}"
            done = subprocess.run(["node", str(PAGE_SCRIPT), address, str(SCREENSHOTS),
                                   CHROMIUM], check=False, capture_output=True, text=True,
                                  timeout=400)
            base, _, token = address.partition("/?token=")
            request = urllib.request.Request(base + "/api/state",
                                             headers={"Authorization": f"Bearer {token}"})
            with urllib.request.urlopen(request, timeout=10) as answer:
                state = json.loads(answer.read())
            request = urllib.request.Request(base + "/api/messages",
                                             headers={"Authorization": f"Bearer {token}"})
            with urllib.request.urlopen(request, timeout=10) as answer:
                said = [m["text"] for m in json.loads(answer.read())["messages"]]
        finally:
            web.send_signal(signal.SIGTERM)
            try:
                _, errors = web.communicate(timeout=30)
            except subprocess.TimeoutExpired:
                web.kill()
                _, errors = web.communicate()
        assert web.returncode == 0, errors
    if done.returncode != 0 and "fell behind" in sim.messages:
        # Emulators that fell behind the wall clock (a loaded machine) let a device's queue
        # run dry or its watchdog expire: the machine faults, as real devices on a host that
        # stalls would; the flow is not the page's to finish then.
        warnings.warn(f"the emulated chips did not keep real time here ({sim.messages.strip()}):"
                      f" the page's flow stopped at {done.stderr.strip()[-300:]}", stacklevel=1)
        return
    held_up = next((text for text in (state["alarm"] or "", *said)
                    if "the host fell behind" in text or _LATE_ANSWER.search(text)), None)
    if done.returncode != 0 and held_up is not None:
        # The host's side held up instead (the chips kept time): on a machine this loaded the
        # pseudo-terminals' bytes can come a second or more late both ways (a wire log of
        # both processes saw neither the web server's call reach the relay nor anything pass
        # for 1.3 s, the emulators on their sockets keeping time). The machine stops safely,
        # saying so: a reply later than the machine file's reply_timeout_s, or a queue that
        # ran dry ("the host fell behind"), every axis held where it stood.
        warnings.warn(f"the host was held up here ({held_up}): the page's flow stopped at"
                      f" {done.stderr.strip()[-300:]}", stacklevel=1)
        return
    faults = {name: axis["fault"] for name, axis in state["axes"].items()}
    assert done.returncode == 0, (
        f"{done.stderr}\n{done.stdout}\n{sim.messages}\nthe server at the end: state"
        f" {state['state']}, alarm {state['alarm']!r}, faults {faults}; its last messages:"
        f"\n" + "\n".join(said[-15:]) + f"\nits standard error:\n{errors[-3000:]}")
    result = json.loads(done.stdout.strip().splitlines()[-1])
    assert result["console_errors"] == []
    assert result["chart_updates_per_s"] >= 50
    lines = result["highlighted"]
    assert lines == sorted(lines) and len(lines) >= 8, lines
    program = demo_path(1).read_text().splitlines()
    assert result["last_highlighted"] == max(
        n for n, text in enumerate(program, 1)
        if text.strip().upper().startswith(("G0", "G1", "G2", "G3")))
    assert state["state"] == "Idle" and not state["busy"]
    # The run's report ends where the DRO showed it at rest, within the counts an emulated
    # chip's integrator may still creep against its load's friction (on the simulated
    # machine, to the count: tests/web/test_dashboard_browser.py).
    run_end = result["run_end"]
    assert run_end["completed"], run_end
    for axis, text in run_end["dro"].items():
        assert abs(float(text) - run_end["report_end_mm"][axis]) <= 2 / 240 + 5e-4, (axis, run_end)
    # At rest a chip's integrator may still wind up against the load's friction, a count at
    # a time after the page read its DRO (tests/firmware/test_emulated_machine.py): within
    # two counts of the state read after it.
    for axis, text in result["dro"].items():
        assert abs(float(text) - state["axes"][axis]["machine_mm"]) <= 2 / 240 + 5e-4, (
            axis, text, state["axes"][axis])
