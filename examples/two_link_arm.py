"""A two-link planar arm drawing a square with its tip, on simulated devices.

The arm's geometry and its inverse kinematics live here, in the example, not in the
library: usbmotion moves joints; what the joints mean is the robot's. The shoulder sits at
the origin, the elbow at the end of a 120 mm upper arm, the tip at the end of a 100 mm
forearm. The tip goes around a 60 mm square, its corners joined by straight lines sampled
every 20 ms; each sample's joint angles come from the inverse kinematics (elbow down), and
the joints play them as one trajectory: every device starts on the same tick.

Run: python examples/two_link_arm.py [--machine examples/robot-arm.toml]
"""

from __future__ import annotations

import argparse
import itertools
import math
from pathlib import Path

from usbmotion.host.config import load_config
from usbmotion.robot import JointTrajectory, Robot
from usbmotion.sim.machine import connect_session

UPPER_MM = 120.0
FORE_MM = 100.0
HERE = Path(__file__).resolve().parent


def joint_angles(x: float, y: float) -> tuple[float, float]:
    """Shoulder and elbow angles (degrees) that put the tip at (x, y) mm, elbow down.

    Raises:
        ValueError: the point is out of the arm's reach.
    """
    reach_sq = x * x + y * y
    cos_elbow = (reach_sq - UPPER_MM**2 - FORE_MM**2) / (2 * UPPER_MM * FORE_MM)
    if not -1.0 <= cos_elbow <= 1.0:
        raise ValueError(f"({x:.1f}, {y:.1f}) mm is out of the arm's reach")
    elbow = -math.acos(cos_elbow)
    shoulder = math.atan2(y, x) - math.atan2(FORE_MM * math.sin(elbow),
                                             UPPER_MM + FORE_MM * math.cos(elbow))
    return math.degrees(shoulder), math.degrees(elbow)


def tip(shoulder_deg: float, elbow_deg: float) -> tuple[float, float]:
    """Where the tip is (mm) for these joint angles: the forward kinematics."""
    s, e = math.radians(shoulder_deg), math.radians(elbow_deg)
    return (UPPER_MM * math.cos(s) + FORE_MM * math.cos(s + e),
            UPPER_MM * math.sin(s) + FORE_MM * math.sin(s + e))


def square_path(centre: tuple[float, float], side: float, speed_mm_s: float,
                step_s: float = 0.02) -> tuple[list[float], list[tuple[float, float]]]:
    """Times and tip points around a square, at rest at its first corner at both ends."""
    cx, cy = centre
    h = side / 2
    corners = [(cx - h, cy - h), (cx + h, cy - h), (cx + h, cy + h), (cx - h, cy + h),
               (cx - h, cy - h)]
    times = [0.0]
    points = [corners[0]]
    for (x0, y0), (x1, y1) in itertools.pairwise(corners):
        steps = max(1, round(math.hypot(x1 - x0, y1 - y0) / speed_mm_s / step_s))
        for k in range(1, steps + 1):
            f = k / steps
            ease = 0.5 - 0.5 * math.cos(math.pi * f)  # each side starts and ends at rest
            points.append((x0 + (x1 - x0) * ease, y0 + (y1 - y0) * ease))
            times.append(times[-1] + step_s)
    return times, points


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--machine", type=Path, default=HERE / "robot-arm.toml")
    args = parser.parse_args()
    times, points = square_path((150.0, 40.0), 60.0, speed_mm_s=40.0)
    angles = [joint_angles(x, y) for x, y in points]
    trajectory = JointTrajectory.from_points(["shoulder", "elbow"], times, angles)
    with connect_session(load_config(args.machine)) as session:
        session.home()
        robot = Robot(session.machine)
        first = dict(zip(trajectory.joints, trajectory.positions[0].tolist(), strict=True))
        robot.move_to(first)
        report = robot.play(trajectory)
        x, y = tip(report.end["shoulder"], report.end["elbow"])
        print(f"square of {len(points)} points in {trajectory.duration_s:.2f} s, every device"
              f" from tick {report.start_tick}")
        for name, peak in report.peak_error_counts.items():
            print(f"  {name:<9} peak following error {peak} counts")
        print(f"tip ended at ({x:.2f}, {y:.2f}) mm; the square's corner is"
              f" ({points[-1][0]:.2f}, {points[-1][1]:.2f}) mm")
        session.shutdown()


if __name__ == "__main__":
    main()
