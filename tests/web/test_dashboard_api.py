"""The dashboard's API (``docs/dashboard.md``) on the simulated machine in real time: the
token gate, the checks of every control's input, uploads, and a whole program driven
through it (home, open, run, hold, resume, jog, MDI, overrides, work offsets) with the
WebSocket's pushes read all along: at least 50 a second, the peak following error of every
servo tick kept (the largest pushed equals the run's report to the count), the line
executing climbing through the program, the position at the end the report's."""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest
from starlette.testclient import TestClient
from starlette.websockets import WebSocketDisconnect
from tests.senders.helpers import fast_homing_machine, wait_for

from usbmotion.cli.web import model_predictor
from usbmotion.demos import demo_path
from usbmotion.host.config import load_config
from usbmotion.session.operator import Operator
from usbmotion.sim.machine import connect_session
from usbmotion.sim.world import SimWorld
from usbmotion.web.app import create_app
from usbmotion.web.dashboard import UPLOAD_LIMIT_BYTES, Dashboard

pytestmark = pytest.mark.realtime

TOKEN = "test-token-0123456789"
AUTH = {"Authorization": f"Bearer {TOKEN}"}


@dataclass
class Served:
    client: TestClient
    dashboard: Dashboard
    operator: Operator
    folder: Path

    def get(self, path: str, *, status: int = 200) -> Any:
        response = self.client.get(path, headers=AUTH)
        assert response.status_code == status, f"{path}: {response.status_code} {response.text}"
        return response.json()

    def post(self, path: str, body: object = None, *, status: int = 200) -> Any:
        response = self.client.post(path, headers=AUTH,
                                    content=None if body is None else json.dumps(body))
        assert response.status_code == status, f"{path}: {response.status_code} {response.text}"
        return response.json()

    def state(self) -> dict[str, Any]:
        return self.get("/api/state")  # type: ignore[no-any-return]

    def wait_state(self, wanted: str, *, timeout_s: float = 30.0, idle: bool = False) -> None:
        wait_for(lambda: self.state()["state"] == wanted
                 and (not idle or not self.state()["busy"]),
                 timeout_s=timeout_s, what=f"the state {wanted}",
                 seen=lambda: (self.state()["state"], self.dashboard.messages()[-3:]))


@contextmanager
def served(folder: Path, *, programs: Path | None = None) -> Iterator[Served]:
    """The default simulated machine (homing fast) in real time behind the dashboard's
    application, as ``usbmotion web`` serves it (its predictor too)."""
    config = load_config(fast_homing_machine(folder))
    world = SimWorld(realtime=True)
    with connect_session(config, world=world) as session:
        operator = Operator(session, file="<web>")
        operator.on_idle = world.keep_pace
        dashboard = Dashboard(operator, programs=programs,
                              predictor=model_predictor(session.config))
        dashboard.start()
        try:
            with TestClient(create_app(dashboard, token=TOKEN)) as client:
                yield Served(client, dashboard, operator, folder)
        finally:
            dashboard.close()
            operator.close()
            session.shutdown()


@pytest.fixture
def web(tmp_path: Path) -> Iterator[Served]:
    with served(tmp_path) as machine:
        yield machine


def test_every_api_call_needs_the_token(web: Served) -> None:
    for method, path in (("GET", "/api/state"), ("GET", "/api/program"),
                         ("POST", "/api/run"), ("POST", "/api/home"),
                         ("POST", "/api/program/upload?name=a.ngc")):
        for headers in ({}, {"Authorization": "Bearer wrong-token-000000"},
                        {"Authorization": f"Basic {TOKEN}"}):
            response = web.client.request(method, path, headers=headers)
            assert response.status_code == 401, (method, path, headers)
            assert "token" in response.json()["error"]
    assert web.client.get(f"/api/state?token={TOKEN}").status_code == 200
    assert web.state()["state"] == "Idle"
    for address in ("/api/live", "/api/live?token=wrong"):
        with pytest.raises(WebSocketDisconnect) as closed, \
                web.client.websocket_connect(address) as socket:
            socket.receive_text()
        assert closed.value.code == 1008
    assert web.dashboard.messages() == []  # nothing was done
    # The page itself holds nothing of the machine: it needs no token.
    assert web.client.get("/").status_code in (200, 404)


def test_uploads_are_checked(web: Served) -> None:
    def upload(name: str, body: bytes) -> tuple[int, str]:
        response = web.client.post("/api/program/upload", params={"name": name},
                                   content=body, headers=AUTH)
        return response.status_code, response.json().get("error", "")

    assert upload("job.exe", b"G0 X1\n") == (400, upload("job.exe", b"")[1])
    assert "not a G-code file" in upload("job.exe", b"G0 X1\n")[1]
    for name in ("../job.ngc", "dir/job.ngc", "..\\job.ngc", "/etc/job.ngc"):
        status, error = upload(name, b"G0 X1\n")
        assert status == 400 and "path" in error, name
    assert upload("", b"G0 X1\n")[0] == 400
    status, error = upload("big.ngc", b"G0 X1\n" * (UPLOAD_LIMIT_BYTES // 6 + 1))
    assert status == 413 and f"{UPLOAD_LIMIT_BYTES:,}" in error
    status, error = upload("binary.ngc", b"G0 X1\n\xff\xfe\x00\x01")
    assert status == 400 and "not text" in error
    status, error = upload("bad.ngc", b"G21\nG1 X10 F600\nG0 X1 Q\n")
    assert status == 400 and error.startswith("bad.ngc:3:"), error
    assert web.client.get("/api/program", headers=AUTH).status_code == 404  # none opened
    status, error = upload("good.ngc", b"G21 G90\nG0 X10 Y10\nG1 X20 F600\nM2\n")
    assert status == 200 and not error
    program = web.get("/api/program")
    assert program["name"] == "good.ngc" and program["lines"][1] == "G0 X10 Y10"


def test_controls_refuse_bad_input_naming_it(web: Served) -> None:
    cases: list[tuple[str, object, int, str]] = [
        ("/api/run", None, 409, "no program"),
        ("/api/resume", None, 409, "nothing to resume"),
        ("/api/home", {"axes": ["Q"]}, 400, "allowed X, Y, Z"),
        ("/api/home", {"axes": "X"}, 400, "list of axis letters"),
        ("/api/jog", {"moves": {"X": 1}, "feed_mm_min": 600}, 409, "homed"),
        ("/api/jog", {"moves": {"Q": 1}, "feed_mm_min": 600}, 400, "allowed X, Y, Z"),
        ("/api/jog", {"moves": {"X": "far"}, "feed_mm_min": 600}, 400, "not a number"),
        ("/api/jog", {"moves": {"X": 1}, "feed_mm_min": -5}, 400, "feed"),
        ("/api/mdi", {"line": ""}, 400, "G-code"),
        ("/api/mdi", {"line": "G0 X1\nG0 X2"}, 400, "one line"),
        ("/api/overrides", {"feed": 500}, 400, "500"),
        ("/api/overrides", {"rapid": 70}, 400, "70"),
        ("/api/overrides", {}, 400, "feed (10..200)"),
        ("/api/offsets/zero", {"axes": ["X"], "system": 12}, 400, "G59"),
        ("/api/offsets/zero", {"axes": ["X"]}, 409, "not homed"),
        ("/api/program/open", {"demo": 9}, 400, "allowed 1, 2, 3"),
        ("/api/program/open", {"file": "a.ngc"}, 400, "--programs"),
        ("/api/program/open", {}, 400, "demo"),
    ]
    for path, body, status, words in cases:
        error = web.post(path, body, status=status)["error"]
        assert words in error, (path, body, error)
    response = web.client.post("/api/mdi", headers=AUTH, content=b"{not json")
    assert response.status_code == 400 and "JSON" in response.json()["error"]
    assert web.state()["state"] == "Idle"
    web.post("/api/program/open", {"demo": 2})
    for line in (0, 17, "9", True):
        error = web.post("/api/run", {"from_line": line}, status=400)["error"]
        assert "allowed 1..16" in error, (line, error)
    assert web.state()["state"] == "Idle" and not web.state()["busy"]


def test_a_run_from_a_line(web: Served) -> None:
    """Demo 2 from line 12: homed first, joined there, run to its end; the report says so."""
    web.post("/api/program/open", {"demo": 2})
    web.post("/api/run", {"from_line": 12})
    wait_for(lambda: web.operator.last_report is not None and not web.state()["busy"],
             timeout_s=120, what="the run from line 12")
    report = web.get("/api/report")
    assert report["completed"], report
    assert report["notes"][0].startswith("run from line 12"), report["notes"]
    texts = [m["text"] for m in web.get("/api/messages")["messages"]]
    assert any(t.startswith("cycle start: 2-star.ngc from line 12") for t in texts), texts


@dataclass
class Pushes:
    """What the WebSocket pushed, on a thread of its own."""

    states: list[tuple[float, dict[str, Any]]] = field(default_factory=list)
    messages: list[str] = field(default_factory=list)
    stop: threading.Event = field(default_factory=threading.Event)


@contextmanager
def listening(web: Served) -> Iterator[Pushes]:
    pushes = Pushes()

    def listen() -> None:
        with web.client.websocket_connect(f"/api/live?token={TOKEN}") as socket:
            while not pushes.stop.is_set():
                data = json.loads(socket.receive_text())
                if data["type"] == "state":
                    pushes.states.append((time.monotonic(), data))
                else:
                    pushes.messages.append(data["text"])

    thread = threading.Thread(target=listen, name="test-web-listen")
    thread.start()
    try:
        yield pushes
    finally:
        pushes.stop.set()
        thread.join(timeout=10)


def test_a_program_driven_through_the_api_and_watched_on_the_websocket(web: Served) -> None:
    assert "no program has run" in web.get("/api/report", status=404)["error"]
    with listening(web) as pushes:
        web.post("/api/home")
        web.wait_state("Idle", idle=True)
        assert web.state()["homed"]
        web.post("/api/program/open", {"demo": 1})
        program = web.get("/api/program")
        assert program["lines"] == demo_path(1).read_text().splitlines()
        wait_for(lambda: web.get("/api/program")["toolpath"] is not None, timeout_s=10,
                 what="the toolpath")
        toolpath = web.get("/api/program")["toolpath"]
        assert toolpath["axes"] == "XYZ"
        assert len(toolpath["points"]) == len(toolpath["line"]) + 1
        web.post("/api/run")
        web.post("/api/run", status=409)  # busy
        web.wait_state("Run")
        time.sleep(1.0)
        web.post("/api/hold")
        wait_for(lambda: web.state()["state"] == "Hold" and web.state()["at_rest"],
                 timeout_s=10, what="Hold at rest")
        held = web.state()["axes"]
        time.sleep(0.3)
        assert web.state()["axes"]["X"]["machine_mm"] == pytest.approx(
            held["X"]["machine_mm"], abs=0.01)
        web.post("/api/resume")
        web.wait_state("Run")
        run_started = web.state()["program"]["revision"]
        web.wait_state("Idle", idle=True, timeout_s=60)
        time.sleep(0.2)  # the last pushes
    report = web.operator.last_report
    assert report is not None and report.completed, web.dashboard.messages()
    # At least 50 pushes a second while it ran, every whole second.
    run_times = [t for t, s in pushes.states if s["state"] in ("Run", "Hold")]
    seconds: dict[int, int] = {}
    for t in run_times:
        seconds[int(t - run_times[0])] = seconds.get(int(t - run_times[0]), 0) + 1
    whole = [count for second, count in seconds.items()
             if 0 < second < max(seconds)]
    assert whole and min(whole) >= 50, seconds
    # The peak of every servo tick survives: the largest pushed equals the report's.
    counts_per_mm = {axis.name: axis.counts_per_mm for axis in web.dashboard.config.axes}
    for result in report.axes:
        pushed = max(abs(s["axes"][result.name]["peak_error_mm"])
                     for t, s in pushes.states if s["program"]
                     and s["program"]["revision"] >= run_started)
        assert round(pushed * counts_per_mm[result.name]) == abs(result.max_error_counts), \
            (result.name, pushed, result.max_error_counts)
    # The line executing only climbs, through the program, and ends on its last line.
    lines = [s["program"]["line"] for t, s in pushes.states
             if s["program"] and s["program"]["revision"] == run_started and
             s["program"]["line"]]
    assert lines == sorted(lines) and len(set(lines)) >= 8, lines
    last = max(n for n, text in enumerate(program["lines"], 1)
               if text.strip().upper().startswith(("G1", "G2", "G3", "G0")))
    assert lines[-1] == last
    end = [s["program"] for t, s in pushes.states if s["program"]][-1]
    assert end["lines_done"] == end["lines_total"] == 18, end  # M2's line: the program's end
    # The DRO at rest is what the devices' encoders read, and the run's report
    # (GET /api/report) ends there, to the count.
    time.sleep(0.5)
    devices = web.dashboard._call(web.dashboard.session.machine.status)
    end = web.state()["axes"]
    reported = web.get("/api/report")
    assert reported["completed"] and reported["program"] == report.program, reported
    assert [a["max_error_counts"] for a in reported["axes"]] == [
        a.max_error_counts for a in report.axes]
    for name, status in devices.items():
        shown = round(end[name]["machine_mm"] * counts_per_mm[name])
        assert shown == status.actual_counts, name
        assert round(reported["end_position_mm"][name] * counts_per_mm[name]) == shown, name
    assert any("cycle start" in text for text in pushes.messages)


def test_jog_mdi_overrides_and_offsets(web: Served) -> None:
    web.post("/api/home", {"axes": ["X", "Y", "Z"]})
    web.wait_state("Idle", idle=True)
    before = web.state()["axes"]["X"]["machine_mm"]
    web.post("/api/jog", {"moves": {"X": 2.5}, "feed_mm_min": 1200})
    wait_for(lambda: not web.state()["busy"], timeout_s=20, what="the jog's end")
    after = web.state()["axes"]["X"]["machine_mm"]
    assert after - before == pytest.approx(2.5, abs=0.01)
    web.post("/api/jog", {"moves": {"Y": 1}, "feed_mm_min": 600, "continuous": True})
    web.wait_state("Jog")
    time.sleep(0.3)
    web.post("/api/jog/cancel")
    wait_for(lambda: not web.state()["busy"], timeout_s=20, what="the cancelled jog's end")
    assert web.state()["state"] == "Idle"
    web.post("/api/mdi", {"line": "G0 X20 Y30"})
    wait_for(lambda: not web.state()["busy"] and abs(
        web.state()["axes"]["Y"]["machine_mm"] - 30) < 0.01, timeout_s=20, what="the MDI move")
    assert "Q word" in web.post("/api/mdi", {"line": "G1 X10 Q5 F100"}, status=400)["error"]
    web.post("/api/overrides", {"feed": 150, "rapid": 50})
    wait_for(lambda: (web.state()["feed_override"], web.state()["rapid_override"]) == (150, 50),
             timeout_s=5, what="the overrides in the live model")
    origin = web.post("/api/offsets/zero", {"axes": ["X", "Y"], "system": 2})["origin_mm"]
    assert origin["X"] == pytest.approx(20.0, abs=0.01)
    web.post("/api/offsets/select", {"system": 2})
    wait_for(lambda: web.state()["coordinate_system"] == "G55", timeout_s=5,
             what="G55 in the live model")
    assert web.state()["axes"]["X"]["work_mm"] == pytest.approx(0.0, abs=0.01)
    assert "allowed 1 (G54)" in web.post("/api/offsets/select", {"system": 0},
                                         status=400)["error"]
    web.post("/api/mdi", {"line": "G0 X2"})  # in G55: 2 mm from its origin
    wait_for(lambda: not web.state()["busy"] and abs(
        web.state()["axes"]["X"]["machine_mm"] - 22) < 0.01, timeout_s=20, what="G0 X2 in G55")
    # A line of modes alone (no motion) changes what the live model shows at once.
    web.post("/api/mdi", {"line": "G54"})
    wait_for(lambda: web.state()["coordinate_system"] == "G54", timeout_s=5,
             what="G54 from an MDI line in the live model")
    assert web.state()["axes"]["X"]["work_mm"] == pytest.approx(22.0, abs=0.01)
    web.post("/api/mdi", {"line": "G55"})
    wait_for(lambda: web.state()["coordinate_system"] == "G55", timeout_s=5,
             what="G55 from an MDI line in the live model")
    assert web.state()["axes"]["X"]["work_mm"] == pytest.approx(2.0, abs=0.01)
    offsets_file = web.dashboard.config.parameter_path
    assert offsets_file is not None and offsets_file.is_file()


def test_device_parameters_and_a_step_response(web: Served) -> None:
    web.post("/api/tune", {"axis": "X", "step_mm": 1.0}, status=409)  # not homed
    devices = web.get("/api/devices")["devices"]
    assert [d["axis"] for d in devices] == ["X", "Y", "Z"]
    kp = {p["name"]: p for p in devices[0]["parameters"]}["kp"]
    assert kp["storage"] == "RAM" and float(kp["value"]) > 0
    for body, words in (({"name": "kp", "value": -1}, "refused"),
                        ({"name": "kq", "value": 1}, "no parameter 'kq'"),
                        ({"name": "kp", "value": 2, "flash": True}, "RAM"),
                        ({"name": "watchdog_ms", "value": 1}, "refused")):
        error = web.post("/api/devices/X/parameters", body, status=400)["error"]
        assert words in error, (body, error)
    assert "allowed X, Y, Z" in web.post("/api/devices/Q/parameters",
                                         {"name": "kp", "value": 1}, status=400)["error"]
    for _ in range(20):  # a call on the worker's heels is not refused as busy
        web.get("/api/devices")
        taken = web.post("/api/devices/Y/parameters", {"name": "kp", "value": kp["value"]})
        assert taken["storage"] == "RAM" and float(taken["value"]) == float(kp["value"])
    web.post("/api/home")
    web.wait_state("Idle", idle=True)
    before = web.state()["axes"]["X"]["machine_mm"]
    step = web.post("/api/tune", {"axis": "X", "step_mm": 1.0})
    assert len(step["time_s"]) == len(step["measured_mm"]) > 100
    assert step["overshoot_percent"] is not None and step["settling_s"] is not None
    assert max(step["measured_mm"]) - min(step["measured_mm"]) == pytest.approx(1.0, abs=0.1)
    assert web.state()["axes"]["X"]["machine_mm"] == pytest.approx(before, abs=0.02)
    assert "step_mm" in web.post("/api/tune", {"axis": "X", "step_mm": 0}, status=400)["error"]
    web.post("/api/mdi", {"line": "G0 X30"})  # the feed knows where X stands after the steps
    wait_for(lambda: not web.state()["busy"] and abs(
        web.state()["axes"]["X"]["machine_mm"] - 30) < 0.01, timeout_s=20, what="the MDI move")


def test_two_pages_one_machine_and_a_page_that_goes_away(web: Served) -> None:
    web.post("/api/home")
    web.wait_state("Idle", idle=True)
    web.post("/api/program/open", {"demo": 1})
    with listening(web) as first:
        with listening(web) as second:
            web.post("/api/run")
            web.wait_state("Run")
            time.sleep(1.0)
        # The second page closed mid-run: the machine goes on.
        time.sleep(0.5)
        assert web.state()["state"] == "Run"
        seen = [s["program"]["line"] for _, s in second.states if s["program"]]
        assert max(seen) > 0
        # A page that comes back gets the state at once, the program where it stands.
        with web.client.websocket_connect(f"/api/live?token={TOKEN}") as socket:
            messages = [json.loads(socket.receive_text()) for _ in range(10)]
        states = [m for m in messages if m["type"] == "state"]
        assert states and states[0]["state"] == "Run" and states[0]["program"]["line"] > 0
        assert any(m["type"] == "message" and "cycle start" in m["text"] for m in messages)
        web.post("/api/hold")
        wait_for(lambda: web.state()["state"] == "Hold" and web.state()["at_rest"],
                 timeout_s=10, what="Hold at rest")
        time.sleep(0.3)
    # Both pages saw the same machine: the first page's pushes followed the hold too.
    assert first.states[-1][1]["state"] == "Hold"
    first_lines = {s["program"]["line"] for _, s in first.states if s["program"]}
    assert set(seen) <= first_lines | {0}
    web.post("/api/stop")
    wait_for(lambda: not web.state()["busy"], timeout_s=20, what="the stop")
    assert web.state()["state"] == "Idle"


def test_a_programs_folder(tmp_path: Path) -> None:
    folder = tmp_path / "programs"
    folder.mkdir()
    (folder / "square.ngc").write_text("G21 G90\nG0 X10 Y10\nM2\n")
    (folder / "notes.pdf").write_bytes(b"%PDF")
    (folder / "huge.ngc").write_bytes(b"G0 X1\n" * (UPLOAD_LIMIT_BYTES // 6 + 1))
    (tmp_path / "machine").mkdir()
    with served(tmp_path / "machine", programs=folder) as web:
        catalogue = web.get("/api/programs")
        assert catalogue["files"] == ["huge.ngc", "square.ngc"]
        assert web.post("/api/program/open", {"file": "square.ngc"})["name"] == "square.ngc"
        assert "no program 'gone.ngc'" in web.post("/api/program/open", {"file": "gone.ngc"},
                                                   status=404)["error"]
        assert "not a G-code file" in web.post("/api/program/open", {"file": "notes.pdf"},
                                               status=400)["error"]
        assert "path" in web.post("/api/program/open", {"file": "../square.ngc"},
                                  status=400)["error"]
        assert f"{UPLOAD_LIMIT_BYTES:,}" in web.post("/api/program/open", {"file": "huge.ngc"},
                                                     status=413)["error"]
