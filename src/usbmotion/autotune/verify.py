"""Placing the loop on a connected axis and checking it: the gains from the identified
model, then a step and a move on the axis, each beside what the model predicted."""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np

from usbmotion.autotune.identify import MARGIN_SHARE, Identification, trapezoid
from usbmotion.autotune.loop import (
    ClosedLoopRun,
    Design,
    design,
    simulate_closed_loop,
)
from usbmotion.autotune.model import FloatArray
from usbmotion.errors import DeviceError, DeviceFaultError
from usbmotion.host.config import AxisConfig
from usbmotion.host.device import ControlMode, Diagnostics
from usbmotion.host.machine import Machine
from usbmotion.tuning import wait_feeding

STEP_MAX_MM = 1.0
"""The verification step: a quarter of the test's travel, at most this."""
LEAD_TICKS = 20
"""Ticks of holding before the step and the move."""
STEP_HOLD_S = 0.4
"""How long the step is held (recorded) after it is asked for."""
MOVE_HOLD_S = 0.2
"""How long the move holds at each end."""


@dataclass(frozen=True, slots=True)
class Figures:
    """How a step or a move was followed.

    Fields:
        overshoot_pct: the largest excursion past the end, percent of the distance.
        settling_time_s: from the step (the move's end) until the position stays within
            2 % of the distance (at least 2 counts) of the end; NaN if it never does.
        peak_following_error_counts: the largest ``|desired - actual|``.
        ise_counts2_s: the integrated squared following error, counts^2 s, as the device's
            statistics count it (the desired position of a tick against the count at its
            end: call 35).
        ise_aligned_counts2_s: the same against the count at the tick's start (the error
            the PID acts on: a loop that tracks with no lag has none; the device's own
            figure then carries one tick of motion, ``v T``).
    """

    overshoot_pct: float
    settling_time_s: float
    peak_following_error_counts: float
    ise_counts2_s: float
    ise_aligned_counts2_s: float


@dataclass(frozen=True, slots=True)
class Check:
    """A test on the axis and the model's prediction of it, tick by tick.

    Fields:
        what: ``"step"`` or ``"move"``.
        distance_counts: the step, or the move's length each way.
        measured, predicted: the runs.
        measured_figures, predicted_figures: their figures.
        start_tick: index of the tick the step (or the move) starts on.
    """

    what: str
    distance_counts: int
    measured: ClosedLoopRun
    predicted: ClosedLoopRun
    measured_figures: Figures
    predicted_figures: Figures
    start_tick: int


@dataclass(frozen=True, slots=True)
class Placement:
    """The gains placed from a model and their checks on the axis.

    Fields:
        design: the gains and what the model predicted of them.
        step, move: the checks (None when not run).
    """

    design: Design
    step: Check | None
    move: Check | None


def figures(run: ClosedLoopRun, *, start_tick: int, tick_s: float, distance: float,
            far_counts: float) -> Figures:
    """The figures of ``run``, a motion that starts on ``start_tick`` and reaches
    ``far_counts`` (``distance`` from where it started) at its farthest: the overshoot
    past ``far_counts``, and the settling from the tick the desired position last changes
    into 2 % of ``distance`` (at least 2 counts) of where it ends."""
    desired, actual = run.desired, run.actual
    changes = np.nonzero(np.diff(desired))[0]
    last = int(changes[-1]) + 1 if changes.size else start_tick
    sign = 1.0 if distance >= 0 else -1.0
    past = sign * (actual[start_tick:] - far_counts)
    overshoot = max(0.0, float(np.max(past))) / abs(distance) * 100.0 if past.size else 0.0
    band = max(2.0, 0.02 * abs(distance))
    outside = np.nonzero(np.abs(desired[-1] - actual[last:]) > band)[0]
    if not outside.size:
        settling = 0.0
    elif outside[-1] == actual.size - last - 1:
        settling = math.nan
    else:
        settling = float(outside[-1] + 1) * tick_s
    error = desired[start_tick:] - actual[start_tick:]
    aligned = desired[start_tick + 1:] - actual[start_tick:-1]
    return Figures(overshoot, settling, float(np.max(np.abs(error))) if error.size else 0.0,
                   float(error @ error) * tick_s, float(aligned @ aligned) * tick_s)


def step_and_move(room_counts: int, *, counts_per_mm: float, max_velocity_mm_s: float,
                  max_accel_mm_s2: float, tick_s: float) -> tuple[FloatArray, FloatArray]:
    """The design's step and move, desired counts per tick from 0: a step of a quarter of
    the room (at most :data:`STEP_MAX_MM`), and a trapezoid over half the room (less the
    margins) at the axis's limits, there and back."""
    step = max(1, round(min(STEP_MAX_MM * counts_per_mm, room_counts / 4)))
    step_run = np.concatenate([np.zeros(LEAD_TICKS), np.full(round(STEP_HOLD_S / tick_s), step)])
    length = room_counts * (0.5 - MARGIN_SHARE)
    there = trapezoid(length, max_velocity_mm_s * counts_per_mm,
                      max_accel_mm_s2 * counts_per_mm, tick_s)
    hold = round(MOVE_HOLD_S / tick_s)
    move = np.concatenate([np.zeros(LEAD_TICKS), there, np.full(hold, there[-1]),
                           there[-1] - there, np.zeros(hold)])
    return np.round(step_run), np.round(move)


OBJECTIVE_MAX_MM = 30.0
"""The design's objective move: half the axis's travel, at most this, there and back."""


def objective_move(axis: AxisConfig, *, tick_s: float) -> FloatArray:
    """The move the design minimises the predicted following error of (a prediction only:
    it never runs on the axis): a trapezoid over half the axis's travel (at most
    :data:`OBJECTIVE_MAX_MM`) at its ``max_velocity_mm_s`` and ``max_accel_mm_s2``, there
    and back, desired counts per tick from 0."""
    low, high = axis.travel_mm
    length = min(OBJECTIVE_MAX_MM, (high - low) / 2) * axis.counts_per_mm
    there = trapezoid(length, axis.max_velocity_mm_s * axis.counts_per_mm,
                      axis.max_accel_mm_s2 * axis.counts_per_mm, tick_s)
    hold = round(MOVE_HOLD_S / tick_s)
    return np.round(np.concatenate([np.zeros(LEAD_TICKS), there, np.full(hold, there[-1]),
                                    there[-1] - there, np.zeros(hold)]))


def place_loop(identification: Identification, axis: AxisConfig, *,
               bandwidth_hz: float | None = None, objective: str = "aligned") -> Design:
    """The gains for the identified model (:func:`usbmotion.autotune.loop.design`): the
    step of :func:`step_and_move` for the identification's travel bounds the overshoot,
    :func:`objective_move` is the move whose following error (``objective``:
    :data:`usbmotion.autotune.loop.OBJECTIVES`) is minimised.

    Raises:
        ArgumentError: no gains meet the margins at that bandwidth.
    """
    room = identification.high_counts - identification.low_counts
    tick_s = identification.tick_s
    step, _ = step_and_move(room, counts_per_mm=axis.counts_per_mm,
                            max_velocity_mm_s=axis.max_velocity_mm_s,
                            max_accel_mm_s2=axis.max_accel_mm_s2, tick_s=tick_s)
    return design(identification.fit.model, tick_s=tick_s, step_desired=step,
                  move_desired=objective_move(axis, tick_s=tick_s), crossover_hz=bandwidth_hz,
                  objective=objective)


def check_on_axis(machine: Machine, axis: str, identification: Identification,
                  chosen: Design) -> Placement:
    """Put ``chosen``'s gains on the axis and run the design's step and move there (within
    the identification's stretch, from where the axis stands toward its roomier side),
    each beside the model's prediction. The axis is left enabled in position mode with the
    new gains, holding.

    Raises:
        DeviceError: the device refused or lost diagnostics lines.
        DeviceFaultError: it faulted.
    """
    target = machine.axis(axis)
    client = target.client
    tick_s = machine.config.servo_period_s
    settings = target.config
    here = client.status().actual_counts
    low, high = identification.low_counts, identification.high_counts
    direction = 1 if high - here >= here - low else -1
    step, move = step_and_move(high - low, counts_per_mm=settings.counts_per_mm,
                               max_velocity_mm_s=settings.max_velocity_mm_s,
                               max_accel_mm_s2=settings.max_accel_mm_s2, tick_s=tick_s)
    gains = chosen.gains
    client.set_gains(kp=gains.kp, ki=gains.ki, kd=gains.kd)
    results = []
    for what, shape in (("step", step), ("move", move)):
        start = client.status().actual_counts
        wanted = [start + direction * int(v) for v in shape]
        records = _play(machine, axis, wanted)
        desired = np.array([r.desired for r in records], dtype=np.float64)
        actual = np.array([r.actual_counts for r in records], dtype=np.float64)
        output = np.array([r.output_mv / 1000 for r in records], dtype=np.float64)
        measured = ClosedLoopRun(desired, actual, output)
        predicted = simulate_closed_loop(identification.fit.model, gains, desired,
                                         tick_s=tick_s, start_counts=float(actual[0]))
        moving = np.nonzero(desired != desired[0])[0]
        first = int(moving[0]) if moving.size else 0
        farthest = int(np.argmax(np.abs(desired - desired[0])))
        distance = float(desired[farthest] - desired[0])
        measured_figures = figures(measured, start_tick=first, tick_s=tick_s,
                                   distance=distance, far_counts=float(desired[farthest]))
        predicted_figures = figures(predicted, start_tick=first, tick_s=tick_s,
                                    distance=distance, far_counts=float(desired[farthest]))
        results.append(Check(what, round(abs(distance)), measured, predicted,
                             measured_figures, predicted_figures, first))
    return Placement(chosen, results[0], results[1])


def _play(machine: Machine, axis: str, wanted: list[int]) -> list[Diagnostics]:
    """Run ``wanted`` (one desired position per tick, motion scalar 1) in position mode and
    return the diagnostics of exactly those ticks."""
    client = machine.axis(axis).client
    scalar = machine.config.motion_scalar
    period_s = machine.config.motion_period_s
    values = wanted[::scalar]
    records: list[Diagnostics] = []
    with client.listening(diagnostics=records.append):
        client.set_control_mode(ControlMode.POSITION)
        client.set_servo_enable(True)
        client.set_diagnostics_interval(1)
        begin = client.clock() + 2
        client.start_at(begin)
        for first in range(0, len(values), 500):
            while client.queue_status()[1] < 500:
                machine.clock.sleep(0.1)
            client.add_setpoints(values[first:first + 500])
        wait_feeding(machine, client, len(values) * period_s + 0.05)
        client.set_diagnostics_interval(0)
        client.sync()
    status = client.status()
    if status.fault:
        raise DeviceFaultError(f"axis {axis}: {status.fault_name} during the check",
                               device=client.name)
    run = [r for r in records if r.clock > begin][:len(wanted)]
    if len(run) < len(wanted):
        raise DeviceError(f"axis {axis}: the check recorded {len(run)} of {len(wanted)}"
                          " ticks", device=client.name)
    if any(b.clock - a.clock != 1 for a, b in itertools.pairwise(run)):
        raise DeviceError(f"axis {axis}: diagnostics lines were lost during the check",
                          device=client.name)
    return run


def predicted_versus_measured(check: Check) -> dict[str, tuple[float, float]]:
    """``name -> (predicted, measured)`` of a check's figures."""
    p, m = check.predicted_figures, check.measured_figures
    return {
        "overshoot_pct": (p.overshoot_pct, m.overshoot_pct),
        "settling_time_s": (p.settling_time_s, m.settling_time_s),
        "peak_following_error_counts": (p.peak_following_error_counts,
                                        m.peak_following_error_counts),
        "ise_counts2_s": (p.ise_counts2_s, m.ise_counts2_s),
        "ise_aligned_counts2_s": (p.ise_aligned_counts2_s, m.ise_aligned_counts2_s),
    }


__all__ = [
    "Check",
    "Figures",
    "Placement",
    "check_on_axis",
    "figures",
    "objective_move",
    "place_loop",
    "predicted_versus_measured",
    "step_and_move",
]
