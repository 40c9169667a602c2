"""The dashboard's Measure tool button at a program's tool change, in Debian's Chromium
(playwright-core, ``dashboard_tool_change.js``), against ``usbmotion web``'s application on
the simulated machine in real time with a tool setter: the program waits at its ``M6``, the
button measures the new tool, and the program goes on from the next line to its end, its
``G43`` reading the measured length."""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import pytest
from tests.senders.helpers import START_MM, fast_homing_machine, need, node_package, wait_for
from tests.web.test_dashboard_browser import CHROMIUM, served_page

from usbmotion.motion.tools import load_tool_table
from usbmotion.web.app import page_built

pytestmark = pytest.mark.realtime

HERE = Path(__file__).resolve().parent
SETTER = """
[tool_setter]
position_mm = [150.0, 150.0]
start_z_mm = -18.0
lowest_z_mm = -30.0
feed_mm_min = 120.0
reference_z_mm = -25.0
"""
PROGRAM = "G21 G90\nG0 X10 Y10\nT1 M6\nG43 H1\nG0 X20 Z-10\nM2\n"


def _machine(folder: Path) -> Path:
    """The default machine homing fast, its Z over a surface at -20 mm (the setter's
    button for the simulated tool), a tool table and the setter."""
    path = fast_homing_machine(folder)
    text = path.read_text()
    start = f"sim = {{ start_mm = {-START_MM},"
    assert start in text, "the default machine file's Z sim table changed"
    text = text.replace(start, f"sim = {{ start_mm = {-START_MM}, probe_below_mm = -20.0,", 1)
    text = text.replace('name = "simulated XYZ"',
                        'name = "simulated XYZ"\ntool_table = "tool.tbl"', 1)
    path.write_text(text + SETTER)
    (folder / "tool.tbl").write_text("T1 P1 Z0 D6 ;a 6 mm end mill\n")
    return path


def test_the_page_measures_the_new_tool_at_a_tool_change(tmp_path: Path) -> None:
    need(node_package("playwright-core") and Path(CHROMIUM).exists() and
         shutil.which("node") is not None,
         "playwright-core (npm) with Chromium (Debian package chromium)")
    need(page_built(), "the dashboard's page (make web)")
    with served_page(tmp_path, machine=_machine(tmp_path)) as (url, dashboard, operator):
        session = operator.session
        session.home()
        dashboard.upload("change.ngc", PROGRAM.encode())
        dashboard.run()
        wait_for(lambda: session.held, timeout_s=60, what="the tool change's pause")
        done = subprocess.run(["node", str(HERE / "dashboard_tool_change.js"), url, CHROMIUM],
                              check=False, capture_output=True, text=True, timeout=180)
        assert done.returncode == 0, f"{done.stderr}\n{done.stdout}"
        result = json.loads(done.stdout.strip().splitlines()[-1])
        wait_for(lambda: not operator.busy, timeout_s=30, what="the machine at rest")
        end = session.live.read().machine_mm(measured=False)
        report = operator.last_report
    assert result["console_errors"] == []
    assert result["state"] == "Idle"
    said = "\n".join(result["messages"])
    assert "measuring T1 on the tool setter; the program then goes on from line 4" in said
    assert "T1 touched the setter at machine Z -20.0" in said and "length 5.0" in said, said
    assert report is not None and report.completed, report
    assert load_tool_table(tmp_path / "tool.tbl").tools[1].offset_mm[2] == pytest.approx(
        5.0, abs=0.01)
    assert end["Z"] == pytest.approx(-10.0 + 5.0, abs=0.01), "G43 H1 read the new length"
