"""A pan-tilt head: look at a few points, then scan, held halfway by another thread.

Each look is the time-optimal jerk-limited move of both joints together (both arrive on the
same tick); the scan is a trajectory (a figure of eight) played through the devices' curve
mode. Halfway through, a second thread holds it (the head decelerates along the figure and
waits), then resumes it: what a "pause" button or a safety sensor would do.

Run: python examples/pan_tilt.py [--machine examples/pan-tilt.toml]
"""

from __future__ import annotations

import argparse
import math
import threading
from pathlib import Path

from usbmotion.host.config import load_config
from usbmotion.robot import JointTrajectory, Robot
from usbmotion.sim.machine import connect_session

HERE = Path(__file__).resolve().parent
LOOKS = [{"pan": 0.0, "tilt": 0.0}, {"pan": 45.0, "tilt": 20.0}, {"pan": -60.0, "tilt": -10.0},
         {"pan": 0.0, "tilt": 0.0}]


def figure_of_eight(seconds: float = 4.0, step_s: float = 0.05) -> JointTrajectory:
    """Pan 40 degrees either way while tilt goes twice as often: a figure of eight."""
    count = round(seconds / step_s)
    times = [k * step_s for k in range(count + 1)]
    points = []
    for t in times:
        phase = 2 * math.pi * t / seconds
        fade = math.sin(math.pi * t / seconds) ** 2  # from rest and back to rest
        points.append((40.0 * fade * math.sin(phase), 15.0 * fade * math.sin(2 * phase)))
    return JointTrajectory.from_points(["pan", "tilt"], times, points)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--machine", type=Path, default=HERE / "pan-tilt.toml")
    args = parser.parse_args()
    with connect_session(load_config(args.machine)) as session:
        session.home()
        robot = Robot(session.machine)
        for look in LOOKS:
            report = robot.move_to(look)
            shown = ", ".join(f"{name} {value:.2f}" for name, value in report.end.items())
            print(f"look at {look}: {report.duration_s:.3f} s, ended at {shown} degrees")

        def hold_halfway(reached_s: float) -> None:
            if reached_s >= 2.0 and not asked.is_set():
                asked.set()
                robot.hold()
                threading.Thread(target=resume_when_held, daemon=True).start()

        def resume_when_held() -> None:
            robot.held.wait(timeout=30)
            held = ", ".join(f"{name} {value:.2f}" for name, value in robot.positions().items())
            print(f"held at rest on the figure: {held} degrees")
            robot.resume()

        asked = threading.Event()
        report = robot.play(figure_of_eight(), on_progress=hold_halfway)
        peaks = ", ".join(f"{n} {p}" for n, p in report.peak_error_counts.items())
        print(f"scan: {report.holds} hold, every device from tick {report.start_tick}, peak"
              f" following error {peaks} counts")
        session.shutdown()


if __name__ == "__main__":
    main()
