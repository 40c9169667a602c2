"""The dashboard's page in Debian's Chromium (playwright-core, ``dashboard_page.js``) against
``usbmotion web``'s application on the simulated machine in real time, driven as an
operator drives it: home, open demo 1, predict it with a tolerance (the lines beyond it
listed and marked as the prediction says), run it with a hold and a resume to its end
(predicted beside measured after it), run it again and stop it, jog, an MDI line, tune X
automatically. The
highlighted line runs through the program in order and ends on its last motion line; the
charts redraw at least 50 times a second; the DRO at the end of the run shows the run's
report (``GET /api/report``) to the count, and at the end what the live model holds; no
console error. Screenshots go to ``build/web/`` (one, at a laptop's width, is the
README's)."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest
import uvicorn
from tests.senders.helpers import fast_homing_machine, need, node_package, wait_for

from usbmotion.cli.web import model_predictor
from usbmotion.demos import demo_path
from usbmotion.host.config import load_config
from usbmotion.serving import listening_socket
from usbmotion.session.operator import Operator
from usbmotion.session.report_text import lines_over
from usbmotion.sim.machine import connect_session
from usbmotion.sim.world import SimWorld
from usbmotion.web.app import create_app, page_built
from usbmotion.web.dashboard import Dashboard

pytestmark = pytest.mark.realtime

HERE = Path(__file__).resolve().parent
SCREENSHOTS = HERE.parents[1] / "build" / "web"
CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
TOKEN = "browser-test-token-0123"
PAGE_TIMEOUT_S = 300.0


@contextmanager
def served_page(folder: Path, machine: Path | None = None
                ) -> Iterator[tuple[str, Dashboard, Operator]]:
    """``usbmotion web``'s application on the default simulated machine (homing fast; or
    ``machine``) in real time, served by uvicorn on a free port of 127.0.0.1; its address
    with the token."""
    config = load_config(machine if machine is not None else fast_homing_machine(folder))
    world = SimWorld(realtime=True)
    with connect_session(config, world=world) as session:
        operator = Operator(session, file="<web>")
        operator.on_idle = world.keep_pace
        dashboard = Dashboard(operator, predictor=model_predictor(session.config))
        dashboard.start()
        listener = listening_socket("127.0.0.1", 0)
        server = uvicorn.Server(uvicorn.Config(
            create_app(dashboard, token=TOKEN), log_level="warning", lifespan="off",
            ws="websockets-sansio", timeout_graceful_shutdown=2))
        thread = threading.Thread(target=server.run, kwargs={"sockets": [listener]},
                                  name="test-web-server")
        thread.start()
        try:
            wait_for(lambda: server.started, timeout_s=30, what="the server's start")
            port = listener.getsockname()[1]
            yield f"http://127.0.0.1:{port}/?token={TOKEN}", dashboard, operator
        finally:
            server.should_exit = True
            thread.join(timeout=10)
            listener.close()
            dashboard.close()
            operator.close()
            session.shutdown()


def test_the_page_drives_a_program_and_shows_the_machine(tmp_path: Path) -> None:
    need(node_package("playwright-core") and Path(CHROMIUM).exists(),
         "playwright-core (npm) with Chromium (Debian package chromium)")
    need(page_built(), "the dashboard's page (make web)")
    SCREENSHOTS.mkdir(parents=True, exist_ok=True)
    with served_page(tmp_path) as (url, dashboard, operator):
        counts_per_mm = {axis.name: axis.counts_per_mm for axis in operator.session.config.axes}
        started = time.monotonic()
        done = subprocess.run(["node", str(HERE / "dashboard_page.js"), url, str(SCREENSHOTS),
                               CHROMIUM], check=False, capture_output=True, text=True,
                              timeout=PAGE_TIMEOUT_S, env={**os.environ, "TUNE_AUTO": "1"})
        assert done.returncode == 0, f"{done.stderr}\n{done.stdout}"
        result = json.loads(done.stdout.strip().splitlines()[-1])
        wait_for(lambda: not operator.busy, timeout_s=20, what="the machine at rest")
        time.sleep(0.3)
        now = dashboard.state(dashboard.reader())
        kept = dashboard.prediction
        last_report = operator.last_report
    assert result["console_errors"] == []
    assert result["chart_updates_per_s"] >= 50, result["chart_updates_per_s"]
    lines = result["highlighted"]
    assert lines == sorted(lines) and len(lines) >= 8, lines
    program = demo_path(1).read_text().splitlines()
    last_motion = max(n for n, text in enumerate(program, 1)
                      if text.strip().upper().startswith(("G0", "G1", "G2", "G3")))
    assert result["last_highlighted"] == last_motion
    shown = {axis: float(text) for axis, text in result["dro"].items()}
    assert set(shown) == {"X", "Y", "Z"}
    for axis, value in shown.items():
        assert f"{value:.3f}" == f"{now['axes'][axis]['machine_mm']:.3f}", axis
    run_end = result["run_end"]
    assert run_end["completed"], run_end
    for axis in ("X", "Y", "Z"):
        half_count = 0.5 / counts_per_mm[axis]
        report_mm = run_end["report_end_mm"][axis]
        assert abs(run_end["state_machine_mm"][axis] - report_mm) < half_count, (axis, run_end)
        assert abs(float(run_end["dro"][axis]) - report_mm) <= 0.0005 + 1e-9, (axis, run_end)
    # The prediction as the page showed it: the lines beyond the tolerance listed and
    # marked are the prediction's, each axis's peak the prediction's to 0.0001 mm.
    shown_prediction = result["predicted"]
    assert kept is not None and kept.name == "1-rounded-square.ngc"
    over = [line for line, _, _ in lines_over(kept.predicted.report,
                                              shown_prediction["tolerance_mm"], counts_per_mm)]
    assert over and shown_prediction["count"] == len(over), (shown_prediction, over)
    assert shown_prediction["listed"] == over
    assert sorted(shown_prediction["marked"]) == over
    for axis in kept.predicted.report.axes:
        assert shown_prediction["peaks_mm"][axis.name] == pytest.approx(axis.max_error_mm,
                                                                        abs=0.00005), axis.name
    # After the run of the predicted program, predicted beside measured (peak predicted,
    # peak measured, RMS predicted, RMS measured, mm): the first run's (a hold and a
    # resume in it), as the page read it then.
    assert last_report is not None
    compared = run_end["compared"]
    assert set(compared) == {"X", "Y", "Z"}, compared
    for axis in kept.predicted.report.axes:
        assert compared[axis.name][0] == pytest.approx(axis.max_error_mm, abs=0.00005)
    assert all(len(cells) == 4 and all(c >= 0 for c in cells) for cells in compared.values())
    # Automatic tuning from the Tuning panel: the model, the gains with their margins, and
    # each check's figures predicted beside measured; not written (the box unticked).
    tuned = result["tuned"]
    assert "gains kp" in tuned["text"] and "phase margin" in tuned["text"], tuned
    assert "not written" in tuned["text"], tuned
    rows = [tuned["cells"][i:i + 4] for i in range(0, len(tuned["cells"]), 4)]
    assert [row[0] for row in rows] == ["step"] * 3 + ["move"] * 3, rows
    assert all(float(row[3]) >= 0 for row in rows if row[3] != "—"), rows
    assert (SCREENSHOTS / "dashboard.png").is_file()
    assert (SCREENSHOTS / "dashboard-phone.png").is_file()
    print(f"dashboard page: steps {', '.join(result['steps'])}; chart redraws"
          f" {result['chart_updates_per_s']:.0f}/s; {time.monotonic() - started:.1f} s")
