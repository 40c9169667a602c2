"""Live control on the default machine: hold latency, stop distance against v^2/2a, and
override latency, in virtual time.

    python benchmarks/live_control.py [--runs 5] [--json]

A straight line at 20 mm/s (``G1 X150 F1200``, X's fastest) runs on the default simulated
machine in virtual time, and an operator's request comes on a servo tick that moves from
run to run (3.000 s, then 3.137 s, 3.274 s, ... into the program: requests do not line up
with the host's polling). The devices' own clocks time each figure:

- hold latency: from the tick of the request to the tick of the first decelerating
  setpoint the devices executed (goal: at most 20 ms);
- hold distance and stop distance: how far the axes went from where the deceleration
  began to rest, against the planned v^2/2a (0.400 mm at 20 mm/s and 500 mm/s^2);
- override latency: from the request (feed override 50 %) to the tick of the first
  setpoint planned at the new speed that the devices executed.

Virtual time is deterministic: a run repeated gives the same figures; the runs differ only
in when the request comes. Each figure is the median of ``--runs`` runs (and the worst).
"""

from __future__ import annotations

import statistics
import sys
from collections.abc import Callable
from typing import Any

from _common import argument_parser, emit, parse_arguments
from usbmotion.cli.run import default_machine
from usbmotion.host.config import MachineConfig, load_config
from usbmotion.session import MachineSession
from usbmotion.sim.machine import connect_session
from usbmotion.sim.recording import ExecutedRecorder

LINE = "G21 G90\nG1 X150 F1200\nM2\n"
FIRST_REQUEST_TICK = 3000
REQUEST_STEP_TICKS = 137


def _one(config: MachineConfig, request_tick: int,
         act: Callable[[MachineSession], None]) -> tuple[MachineSession, int]:
    """Run the line with ``act`` on the request tick; the session and the device clock
    of the request."""
    asked = [0]
    with connect_session(config) as session:
        session.live_control = True
        session.home()
        world = session.machine.world
        assert world is not None
        count = [0]

        def on_tick(clock: int) -> None:
            count[0] += 1
            if count[0] == request_tick:
                asked[0] = clock
                act(session)
            if count[0] == request_tick + 500 and session.hold_requested:
                session.request_resume()

        with ExecutedRecorder(world, ["X", "Y", "Z"], on_tick=on_tick):
            report, _ = session.run(session.prepare("line.ngc", text=LINE))
        session.report = report  # type: ignore[attr-defined]
        session.shutdown()
        return session, asked[0]


def measure(*, runs: int) -> dict[str, Any]:
    """The figures: medians and worst of ``runs`` runs each."""
    config = load_config(default_machine())
    tick_s = config.servo_period_s
    hold_ms: list[float] = []
    hold_mm: list[float] = []
    planned_mm: list[float] = []
    stop_mm: list[float] = []
    stop_planned: list[float] = []
    override_ms: list[float] = []
    for run in range(runs):
        tick = FIRST_REQUEST_TICK + run * REQUEST_STEP_TICKS
        session, asked = _one(config, tick, MachineSession.request_hold)
        assert session.last_run is not None
        ((_, began, planned, distance),) = session.last_run.holds
        hold_ms.append((began - asked) * tick_s * 1000)
        hold_mm.append(distance)
        planned_mm.append(planned)
        session, asked = _one(config, tick, MachineSession.request_stop)
        report = session.report  # type: ignore[attr-defined]
        stop_mm.append(report.stop_distance_mm)
        stop_planned.append(report.stop_planned_mm)
        session, asked = _one(config, tick, lambda s: s.set_feed_override(50))
        assert session.last_run is not None
        ((_, seam),) = session.last_run.seams
        override_ms.append((seam - asked) * tick_s * 1000)
    return {
        "runs": runs,
        "hold_latency_ms": {"median": statistics.median(hold_ms), "worst": max(hold_ms)},
        "hold_distance_mm": statistics.median(hold_mm),
        "planned_v2_2a_mm": statistics.median(planned_mm),
        "stop_distance_mm": statistics.median(stop_mm),
        "stop_planned_v2_2a_mm": statistics.median(stop_planned),
        "override_latency_ms": {"median": statistics.median(override_ms),
                                "worst": max(override_ms)},
    }


def report(figures: dict[str, Any]) -> str:
    """The figures as text."""
    hold, override = figures["hold_latency_ms"], figures["override_latency_ms"]
    return "\n".join([
        f"live control on the default machine, a line at 20 mm/s, virtual time"
        f" (deterministic), median of {figures['runs']} request times",
        f"  hold latency      {hold['median']:6.1f} ms (worst {hold['worst']:.1f} ms;"
        " goal <= 20 ms), request to the first decelerating setpoint executed",
        f"  hold distance     {figures['hold_distance_mm']:6.3f} mm against v^2/2a"
        f" {figures['planned_v2_2a_mm']:.3f} mm",
        f"  stop distance     {figures['stop_distance_mm']:6.3f} mm against v^2/2a"
        f" {figures['stop_planned_v2_2a_mm']:.3f} mm",
        f"  override latency  {override['median']:6.1f} ms (worst {override['worst']:.1f} ms),"
        " request to the first setpoint at the new speed executed",
    ])


def main(argv: list[str] | None = None) -> dict[str, Any]:
    """Run the benchmark, print the figures (or JSON with ``--json``) and return them."""
    args = parse_arguments(argument_parser(__doc__, runs=5), argv)
    return emit(measure(runs=args.runs), report, as_json=args.json)


if __name__ == "__main__":
    main(sys.argv[1:])
