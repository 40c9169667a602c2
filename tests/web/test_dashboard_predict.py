"""The dashboard's prediction (``POST /api/predict``, ``docs/dashboard.md``) on the default
simulated machine in real time: its axes have ``sim`` tables, so the prediction plays the
program on the very motors the run then drives, and a run of the predicted program reports
the prediction beside what it measured. Measured with demo 1: every axis's predicted peak
equal to the run's to the count, its RMS within a thousandth of a count; each line's peak
within a few counts (a line's figure is the peak of the diagnostics periods it overlaps,
and the periods fall differently)."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import pytest
from tests.senders.helpers import wait_for
from tests.web.test_dashboard_api import AUTH, served

from usbmotion.cli.web import model_predictor

pytestmark = pytest.mark.realtime

PEAK_COUNTS = 1
"""How far a run's peak following error on an axis may be from the predicted, counts."""
RMS_COUNTS = 0.05
"""How far a run's RMS following error may be from the predicted, counts."""


def _peaks(data: dict[str, Any]) -> dict[str, int]:
    """Each axis's peak following error in a report or a prediction, counts."""
    return {axis["name"]: axis["max_error_counts"] for axis in data["axes"]}


def test_predict_before_a_run_then_predicted_beside_measured(tmp_path: Path) -> None:
    with served(tmp_path) as web:
        assert "no program is open" in web.post("/api/predict", {}, status=409)["error"]
        web.post("/api/program/open", {"demo": 1})
        for body, words in (({"tolerance_mm": -0.01}, "tolerance_mm -0.01"),
                            ({"tolerance_mm": "small"}, "tolerance_mm 'small'"),
                            ({"tolerance_mm": True}, "tolerance_mm True"),
                            ({"from_line": 999}, "from_line 999: allowed 1..18"),
                            ({"tolerence_mm": 0.01}, "unknown key 'tolerence_mm'")):
            error = web.post("/api/predict", body, status=422)["error"]
            assert words in error, (body, error)
        assert "positive number of mm" in web.post(
            "/api/predict", {"tolerance_mm": 0}, status=422)["error"]

        # Not homed: from where homing leaves the machine.
        unhomed = web.post("/api/predict", {"tolerance_mm": None})
        assert unhomed["standing_mm"] is None and unhomed["over_tolerance"] == []
        assert set(unhomed["motors"]) == {"X", "Y", "Z"}
        assert all("sim table" in source for source in unhomed["motors"].values())

        web.post("/api/home")
        web.wait_state("Idle", idle=True)
        generous = web.post("/api/predict", {"tolerance_mm": 1.0})
        assert generous["over_tolerance"] == [] and generous["completed"]
        predicted = _peaks(generous)
        assert all(peak > 0 for peak in predicted.values()), predicted
        # A tolerance below the largest peak names the lines beyond it, and only those.
        scales = generous["counts_per_mm"]
        worst_mm = max(a["max_error_mm"] for a in generous["axes"])
        tolerance = round(worst_mm * 0.6, 4)
        tight = web.post("/api/predict", {"tolerance_mm": tolerance})
        named = {row["line"] for row in tight["over_tolerance"]}
        expected = {peak["line"] for peak in tight["line_peaks"]
                    if max(counts / scales[axis] for axis, counts
                           in peak["peak_error_counts"].items()) > tolerance}
        assert named == expected and named, (tolerance, tight["over_tolerance"])
        assert all(row["peak_mm"] > tolerance for row in tight["over_tolerance"])
        worst_line = max(generous["axes"], key=lambda a: a["max_error_mm"])["max_error_line"]
        assert worst_line in named
        assert tight["wall_s"] > 0 and tight["speed_ratio"] > 1, tight["speed_ratio"]
        assert tight["planned_time_s"] == pytest.approx(
            web.get("/api/program")["duration_s"], rel=1e-6)
        messages = [m.text for m in web.dashboard.messages()]
        assert any(t.startswith("predicted 1-rounded-square.ngc") and "beyond" in t
                   for t in messages), messages

        web.post("/api/run")
        wait_for(lambda: web.operator.last_report is not None and not web.state()["busy"],
                 timeout_s=120, what="the run of demo 1")
        report = web.get("/api/report")
        assert report["completed"], report
        measured = _peaks(report)
        beside = report["prediction"]
        assert _peaks(beside) == predicted
        for axis in report["axes"]:
            forecast = next(a for a in beside["axes"] if a["name"] == axis["name"])
            assert abs(axis["max_error_counts"] - forecast["max_error_counts"]) <= PEAK_COUNTS, \
                (axis, forecast)
            assert axis["rms_error_counts"] == pytest.approx(forecast["rms_error_counts"],
                                                             abs=RMS_COUNTS)
        print(f"demo 1 peak counts predicted {predicted}, measured {measured}")
        assert ({p["line"] for p in beside["line_peaks"]}
                == {p["line"] for p in report["line_peaks"]})

        # Another program's run carries no prediction.
        web.client.post("/api/program/upload", params={"name": "short.ngc"},
                        content=b"G21 G90\nG0 X10 Y10\nG1 X20 F600\nM2\n", headers=AUTH)
        web.post("/api/run")
        wait_for(lambda: web.operator.last_report is not None
                 and web.operator.last_report.program == "short.ngc"
                 and not web.state()["busy"], timeout_s=60, what="the run of short.ngc")
        assert "prediction" not in web.get("/api/report")


def test_a_prediction_that_cannot_be_made(tmp_path: Path) -> None:
    with served(tmp_path) as web:
        web.client.post("/api/program/upload", params={"name": "far.ngc"},
                        content=b"G21 G90\nG0 X5000\nM2\n", headers=AUTH)
        error = web.post("/api/predict", {}, status=422)["error"]
        assert "X" in error and "5000" in error, error
        web.post("/api/program/open", {"demo": 1})
        config = web.dashboard.config
        bare = dataclasses.replace(config, axes=tuple(
            dataclasses.replace(axis, sim=None) for axis in config.axes))
        web.dashboard.predictor = model_predictor(bare)
        error = web.post("/api/predict", {"tolerance_mm": 0.01}, status=422)["error"]
        assert "axis X has no identified model" in error and "--auto" in error, error

