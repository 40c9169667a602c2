"""Feed hold, resume and stop in real time, on devices served over pseudo-terminals
(``usbmotion sim --pty 3`` in another process): the session runs a program on a thread
while the test, as an operator, holds it, resumes it and stops it from the main thread.
"""

from __future__ import annotations

import threading
import time
from pathlib import Path

import numpy as np
import pytest

from usbmotion.host.config import load_config
from usbmotion.session import MachineSession, MachineState, StopReason
from usbmotion.session.operator import Operator

from .bench import bench_machine, served

LINE = "G21 G90\nG1 X150 F1200\nM2\n"
"""7.5 s at 20 mm/s, X's fastest."""


def _until(what: object, timeout_s: float = 30.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not what():  # type: ignore[operator]
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.005)


@pytest.mark.realtime
def test_hold_resume_and_stop_on_served_devices(tmp_path: Path) -> None:
    with served(tmp_path / "flash") as paths:
        config = load_config(bench_machine(tmp_path, paths, watchdog_ms=1250))
        with MachineSession.connect(config) as session:
            session.live_control = True
            session.home()
            prepared = session.prepare("line.ngc", text=LINE)
            result: list[object] = []
            runner = threading.Thread(target=lambda: result.append(session.run(prepared)))
            runner.start()
            try:
                _until(lambda: session.state is MachineState.RUN)
                time.sleep(1.5)
                session.request_hold()
                _until(lambda: session.last_run is not None and session.last_run.holds)
                assert session.state is MachineState.HOLD
                time.sleep(1.0)
                assert session.state is MachineState.HOLD, "it stays held"
                session.request_resume()
                _until(lambda: session.state is MachineState.RUN)
                time.sleep(1.5)
                session.request_stop()
            finally:
                runner.join(timeout=60)
            report, trace = result[0]  # type: ignore[misc]
            assert report.stop_reason == StopReason.USER.value and not report.completed
            assert session.state is MachineState.IDLE and session.is_homed
            run = session.last_run
            assert run is not None
            ((_, _, planned_mm, distance_mm),) = run.holds
            print(f"\nhold {distance_mm:.3f} mm against v^2/2a {planned_mm:.3f} mm;"
                  f" stop {report.stop_distance_mm:.3f} mm against {report.stop_planned_mm:.3f}")
            assert distance_mm <= planned_mm + 0.05 and distance_mm > 0.5 * planned_mm
            assert report.stop_distance_mm <= report.stop_planned_mm + 0.05
            times, desired, _ = trace.arrays("X")
            steps = np.abs(np.diff(desired)) / np.maximum(np.diff(times), 1e-9)
            assert steps.max() <= 20.0 * 240 * 1.05, "no jump at the hold, resume or stop"
            statuses = session.machine.status()
            assert all(s.fault == 0 for s in statuses.values()), "not faulted"
            session.shutdown()


@pytest.mark.realtime
def test_jog_and_mdi_through_the_operator_on_served_devices(tmp_path: Path) -> None:
    """A continuous jog cancelled while it moves, and MDI lines streamed while the machine
    moves, through the operator's worker thread, in real time."""
    with served(tmp_path / "flash") as paths:
        config = load_config(bench_machine(tmp_path, paths, watchdog_ms=1250))
        with MachineSession.connect(config) as session:
            session.home()
            messages: list[str] = []
            with Operator(session, on_message=messages.append) as operator:
                operator.jog({"X": 1.0}, feed_mm_min=1200, continuous=True)
                _until(lambda: session.jogging)
                time.sleep(1.0)
                operator.jog_cancel()
                assert operator.wait_idle(30)
                report = operator.last_report
                assert report is not None and report.stop_reason == "jog cancelled"
                assert report.stop_distance_mm <= report.stop_planned_mm + 0.05
                x = operator.status().machine_mm()["X"]
                assert 10.0 < x < 40.0, f"cancelled after about 1 s at 20 mm/s, at {x} mm"
                assert operator.submit("G90 G1 X50 F1200")
                _until(lambda: session.state is MachineState.RUN)
                assert operator.submit("G1 Y20")
                assert operator.submit("G1 X60")
                assert operator.wait_idle(60)
                where = operator.status().machine_mm()
                assert (where["X"], where["Y"]) == (pytest.approx(60, abs=0.01),
                                                    pytest.approx(20, abs=0.01))
                assert operator.last_report is not None and operator.last_report.completed
            assert not [m for m in messages if m.startswith("error")], messages
            assert session.state is MachineState.IDLE and session.is_homed
            session.shutdown()
