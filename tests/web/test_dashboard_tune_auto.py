"""The dashboard's automatic tuning (``POST /api/tune/auto``, ``usbmotion tune --auto``'s) on
the default simulated machine in real time: the axis identified to within a percent of the
motor it simulates, its gains placed with the stated margins and checked, the machine file
written when asked (and the machine taking the gains at once), the file's gains back on the
axis when not."""

from __future__ import annotations

from pathlib import Path

import pytest
from tests.web.test_dashboard_api import Served, served

from usbmotion.autotune.model import simulated_model
from usbmotion.host.config import load_config

pytestmark = pytest.mark.realtime


def _device_kp(web: Served, axis: str) -> float:
    devices = {d["axis"]: d for d in web.get("/api/devices")["devices"]}
    return float({p["name"]: p for p in devices[axis]["parameters"]}["kp"]["value"])


def test_identify_place_and_write_from_the_dashboard(tmp_path: Path,
                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    with served(tmp_path) as web:
        path = web.dashboard.config.path
        for body, words in (({"axis": "Q", "travel_mm": 20}, "allowed X, Y, Z"),
                            ({"axis": "X", "travel_mm": 0}, "travel_mm 0"),
                            ({"axis": "X", "travel_mm": 500}, "within 200"),
                            ({"axis": "X", "travel_mm": "far"}, "travel_mm 'far'"),
                            ({"axis": "X", "travel_mm": 20, "write": "yes"}, "write 'yes'")):
            error = web.post("/api/tune/auto", body, status=400)["error"]
            assert words in error, (body, error)
        monkeypatch.setattr("usbmotion.web.dashboard.builtin_machine_file", lambda: path)
        refused = web.post("/api/tune/auto", {"axis": "X", "travel_mm": 20, "write": True},
                           status=409)["error"]
        assert "built-in machine's file" in refused
        monkeypatch.undo()

        before = path.read_text()
        file_kp = web.dashboard.config.axis("X").gains.kp
        truth = simulated_model(web.dashboard.config.axis("X"))
        found = web.post("/api/tune/auto", {"axis": "X", "travel_mm": 20})
        model = found["model"]
        assert model["time_constant_s"] == pytest.approx(truth.time_constant_s, rel=0.01)
        assert model["speed_per_volt_counts_s"] == pytest.approx(
            truth.speed_per_volt_counts_s, rel=0.01)
        assert model["coulomb_v"] == pytest.approx(truth.coulomb_v, rel=0.02)
        assert found["loop"]["phase_margin_deg"] >= 45 and found["loop"]["gain_margin_db"] >= 6
        step = found["checks"]["step"]
        assert step["overshoot_pct"]["measured"] <= 5.0 + 0.5, step
        assert step["peak_following_error_counts"]["measured"] > 0
        assert set(found["checks"]) == {"step", "move"}
        assert found["written_to"] is None and path.read_text() == before
        assert _device_kp(web, "X") == pytest.approx(file_kp), "the file's gains back"
        assert found["gains"]["kp"] != pytest.approx(file_kp), "other gains were placed"

        written = web.post("/api/tune/auto", {"axis": "X", "travel_mm": 20, "write": True})
        assert written["written_to"] == str(path)
        kept = load_config(path).axis("X")
        assert kept.model is not None
        assert kept.model.time_constant_s == pytest.approx(truth.time_constant_s, rel=0.01)
        gains = written["gains"]
        assert (kept.gains.kp, kept.gains.ki, kept.gains.kd) == (
            gains["kp"], gains["ki"], gains["kd"])
        assert web.dashboard.config.axis("X").gains == kept.gains, "the machine took them"
        assert _device_kp(web, "X") == pytest.approx(gains["kp"])
        assert "# tune --auto axis X: identified" in path.read_text()
        assert any("tune X automatically" in m["text"] for m in web.get("/api/messages")[
            "messages"]), "the message log says so"
