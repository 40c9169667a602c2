"""Re-planning the rest of a program from a point of its path (overrides, joins, resumes):
from any point, at the speed the machine has there, the rest is a finite plan of the same
path that starts at that speed."""

from __future__ import annotations

import math

import numpy as np
import pytest

from usbmotion.cli.run import default_machine
from usbmotion.errors import PlanningError
from usbmotion.host.config import load_config
from usbmotion.motion.replanning import PathPoint, locate, plan_rest, whole_program
from usbmotion.session.planning import plan_gcode, planner_inputs

ANGLES = [2 * math.pi * k / 72 for k in range(1, 73)]
CIRCLE = "G21 G90\nG0 X0 Y0\nG1 X10 F3000\n" + "".join(
    f"G1 X{5 + 5 * math.cos(a):.3f} Y{5 + 5 * math.sin(a):.3f}\n" for a in ANGLES
) + "G2 X10 Y5 I-2.5 J0\nM2\n"


@pytest.mark.parametrize("feed_scale", [1.0, 0.5, 1.5])
def test_the_rest_from_every_point_is_finite_and_starts_at_its_speed(feed_scale: float) -> None:
    """Every 5 ms along a program of short segments and an arc: the rest is a plan with
    finite times and speeds (a point where the new speed equals the speed there to the
    last bit gets no ramp piece of zero length), starting where and as fast as the point."""
    config = load_config(default_machine())
    _, plan = plan_gcode(config, CIRCLE)
    limits, planner, _ = planner_inputs(config)
    leg = whole_program(plan)
    checked = 0
    for time_s in np.arange(0.0, plan.duration_s, 0.005):
        point = locate(plan, leg, float(time_s))
        try:
            rest = plan_rest(plan, point, limits, planner, feed_scale=feed_scale)
        except PlanningError:  # too little of the segment left to slow down: a later point
            continue
        if rest is None:
            continue
        rest_plan = rest.plan
        assert math.isfinite(rest_plan.duration_s), (time_s, point)
        assert np.isfinite(rest_plan.segment_duration_s).all()
        assert np.isfinite(rest_plan.v_entry_mm_s).all()
        assert np.allclose(rest_plan.vertices_mm[0], point.position_mm)
        assert rest_plan.v_entry_mm_s[0] == pytest.approx(point.speed_mm_s, rel=1e-5, abs=1e-9)
        assert np.allclose(rest_plan.vertices_mm[-1], plan.vertices_mm[-1])
        checked += 1
    assert checked > 100


def test_the_rest_from_mid_cruise_needs_no_ramp_of_zero_length() -> None:
    """From the middle of every cruise, at exactly the cruise speed (a join or an override
    at the same speed): the speed the rest allows there is the same to the last bit or so,
    and the rest is finite (a ramp of zero length would divide by zero)."""
    config = load_config(default_machine())
    _, plan = plan_gcode(config, CIRCLE)
    limits, planner, _ = planner_inputs(config)
    leg = whole_program(plan)
    cruising = np.flatnonzero(plan.t_cruise_s > 0)
    planned = 0
    for index in cruising:
        time_s = float(plan.start_time_s[index] + plan.t_accel_s[index]
                       + plan.t_cruise_s[index] / 2)
        point = locate(plan, leg, time_s)
        assert point.speed_mm_s == plan.v_cruise_mm_s[index]
        try:
            rest = plan_rest(plan, point, limits, planner)
        except PlanningError:  # a later point, as its callers do
            continue
        assert rest is not None and math.isfinite(rest.plan.duration_s), index
        planned += 1
    assert planned > 20


def test_a_speed_above_the_new_one_by_a_rounding_error_gets_no_ramp() -> None:
    """A point whose speed is the segment's new speed plus one ulp (a planner's own
    arithmetic against the re-planner's): no ramp piece of zero length (whose
    acceleration would be 0 / 0), the rest finite and starting at the point."""
    config = load_config(default_machine())
    _, plan = plan_gcode(config, "G21 G90\nG1 X30 Y9 F3000\nG1 X40\nM2\n")
    limits, planner, _ = planner_inputs(config)
    segment = int(np.flatnonzero(plan.kind == 1)[0])
    unit = plan.unit[segment]
    axis_speed = 1.0 / float(np.max(np.abs(unit) / np.array([a.velocity_mm_s for a in limits])))
    middle = plan.vertices_mm[segment] + unit * plan.length_mm[segment] / 2
    point = PathPoint(segment, float(plan.length_mm[segment] / 2), 0.0,
                      tuple(float(c) for c in middle), float(np.nextafter(axis_speed, 99.0)),
                      0.5)
    rest = plan_rest(plan, point, limits, planner)
    assert rest is not None and math.isfinite(rest.plan.duration_s)
    assert np.isfinite(rest.plan.accel_mm_s2).all()
    assert np.allclose(rest.plan.vertices_mm[0], point.position_mm)
