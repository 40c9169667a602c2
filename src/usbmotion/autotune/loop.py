"""Placing one axis's position loop from its model: the discrete loop the device runs, its
margins, gains for a stated bandwidth, and the responses it predicts.

The device (PROTOCOL.md, "The controller") computes on tick ``k``, from the count at the
end of tick ``k - 1``::

    V_k = sat( Kp e_k + Ki T sum(e_0..e_k) + Kd (e_k - e_(k-W)) / (W T) )

with conditional integration and the sum clamped at ``supply / (Ki T)``; ``W`` is the
derivative window (the last millisecond, 1 to 10 ticks). With the model's exact tick
(:func:`usbmotion.autotune.model.tick_constants`) the plant from ``V`` to the count is::

    P(z) = g (Q z + tau F^2 - e Q) / ((z - 1)(z - e))

so the loop ``L(z) = C(z) P(z)`` holds the servo period's delay exactly. Gains go to the
device as 3 significant digits (calls 9-11) and ``Ki T``, ``Kd / (W T)`` are 4-digit
numbers there: the margins and the predictions here are of the gains so rounded. The
linear margins ignore the supply's ceiling and the Coulomb torque; the predicted step and
move (:func:`simulate_closed_loop`) include both.

Everything here is pure.
"""

from __future__ import annotations

import cmath
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from usbmotion.autotune.model import AxisModel, FloatArray, motor_tick, tick_constants
from usbmotion.errors import ArgumentError
from usbmotion.host.config import PidGains
from usbmotion.host.device import from_sci, to_sci

HISTORY_SLOTS = 10
"""The longest derivative window the device keeps, ticks (PROTOCOL.md)."""
MIN_PHASE_MARGIN_DEG = 45.0
MIN_GAIN_MARGIN_DB = 6.0
MAX_OVERSHOOT_PCT = 5.0


def derivative_window(tick_s: float) -> int:
    """The device's derivative window at a servo period: the ticks in 1 ms, 1 to 10."""
    tick_us = round(tick_s * 1e6)
    return min(HISTORY_SLOTS, max(1, 1000 // tick_us))


def quantise(gains: PidGains) -> PidGains:
    """``gains`` as the device holds them: each to 3 significant digits (calls 9-11)."""
    def three(value: float, label: str) -> float:
        coefficient, exponent = to_sci(value, digits=3, parameter=label)
        return float(f"{coefficient}e{exponent}") if coefficient else 0.0
    return PidGains(three(gains.kp, "kp"), three(gains.ki, "ki"), three(gains.kd, "kd"))


def _four(value: float) -> float:
    return from_sci(*to_sci(value, digits=4, parameter="gain")) if value else 0.0


def plant_response(model: AxisModel, z: complex | FloatArray | np.ndarray, *,
                   tick_s: float) -> complex | np.ndarray:
    """``P(z)``, counts per volt, of the model with the tick's exact solution."""
    keep, decay, lag = tick_constants(model.time_constant_s, tick_s)
    g = model.speed_per_volt_counts_s
    spread = model.time_constant_s * decay * decay - keep * lag
    return g * (lag * z + spread) / ((z - 1) * (z - keep))


def controller_response(gains: PidGains, z: complex | np.ndarray, *, tick_s: float
                        ) -> complex | np.ndarray:
    """``C(z)``, volts per count, of the device's PID."""
    window = derivative_window(tick_s)
    ki_t = _four(gains.ki * tick_s)
    kd_w = _four(gains.kd / (window * tick_s))
    return gains.kp + ki_t * z / (z - 1) + kd_w * (1 - z ** (-window))


def _polynomials(model: AxisModel, gains: PidGains, tick_s: float
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Numerator and denominator (highest power first) of the loop ``L(z)``."""
    window = derivative_window(tick_s)
    keep, decay, lag = tick_constants(model.time_constant_s, tick_s)
    g = model.speed_per_volt_counts_s
    spread = model.time_constant_s * decay * decay - keep * lag
    ki_t = _four(gains.ki * tick_s)
    kd_w = _four(gains.kd / (window * tick_s))
    z_w = np.zeros(window + 1)
    z_w[0] = 1.0                                        # z^W
    zm1 = np.array([1.0, -1.0])                         # z - 1
    if ki_t:
        num_c = (gains.kp * np.polymul(z_w, zm1)
                 + ki_t * np.polymul(z_w, np.array([1.0, 0.0]))
                 + kd_w * np.polymul(np.polysub(z_w, np.array([1.0])), zm1))
        den_c = np.polymul(z_w, zm1)
    else:  # no integrator: no pole at 1 to cancel against the numerator
        num_c = gains.kp * z_w + kd_w * np.polysub(z_w, np.array([1.0]))
        den_c = z_w
    num_p = g * np.array([lag, spread])
    den_p = np.polymul(zm1, np.array([1.0, -keep]))
    return np.polymul(num_c, num_p), np.polymul(den_c, den_p)


def is_stable(model: AxisModel, gains: PidGains, *, tick_s: float, scale: float = 1.0) -> bool:
    """Whether the linear closed loop (loop gain times ``scale``) has every pole inside the
    unit circle."""
    num, den = _polynomials(model, gains, tick_s)
    characteristic = np.polyadd(den, scale * num)
    return bool(np.all(np.abs(np.roots(characteristic)) < 1.0 - 1e-9))


@dataclass(frozen=True, slots=True)
class Margins:
    """The discrete loop's stability margins.

    Fields:
        stable: every closed-loop pole inside the unit circle.
        crossover_hz: the (first) frequency where ``|L| = 1``.
        phase_margin_deg: ``180 + arg L`` there (the least over every crossover).
        gain_margin_db: how much the loop gain may grow before the loop is unstable, dB.
        gain_reduction_db: how much it may shrink (a loop with an integrator and a plant
            integrator is unstable at too low a gain), dB; inf when any reduction is safe.
    """

    stable: bool
    crossover_hz: float
    phase_margin_deg: float
    gain_margin_db: float
    gain_reduction_db: float


def margins(model: AxisModel, gains: PidGains, *, tick_s: float) -> Margins:
    """The margins of the loop the device runs with ``gains`` (as it holds them)."""
    omega = np.geomspace(1e-1, math.pi / tick_s * 0.9999, 2000)
    z = np.exp(1j * omega * tick_s)
    loop = np.asarray(controller_response(gains, z, tick_s=tick_s)) * np.asarray(
        plant_response(model, z, tick_s=tick_s))
    magnitude = np.abs(loop)
    phase = np.unwrap(np.angle(loop))
    crossings = np.nonzero(np.diff(np.sign(magnitude - 1.0)))[0]
    if crossings.size:
        pms = []
        for index in crossings:
            pm = math.degrees(phase[index]) + 180.0
            pms.append((pm + 180.0) % 360.0 - 180.0)
        crossover = float(omega[crossings[0]]) / (2 * math.pi)
        phase_margin = min(pms)
    else:
        crossover, phase_margin = math.nan, math.nan
    stable = is_stable(model, gains, tick_s=tick_s)

    def boundary(low: float, high: float) -> float:
        for _ in range(25):
            middle = math.sqrt(low * high)
            if is_stable(model, gains, tick_s=tick_s, scale=middle):
                low = middle
            else:
                high = middle
        return low

    if not stable:
        return Margins(False, crossover, phase_margin, 0.0, 0.0)
    up = 1e6
    gain_margin = (math.inf if is_stable(model, gains, tick_s=tick_s, scale=up)
                   else 20 * math.log10(boundary(1.0, up)))
    down = 1e-6
    if is_stable(model, gains, tick_s=tick_s, scale=down):
        reduction = math.inf
    else:
        low, high = down, 1.0
        for _ in range(25):
            middle = math.sqrt(low * high)
            if is_stable(model, gains, tick_s=tick_s, scale=middle):
                high = middle
            else:
                low = middle
        reduction = -20 * math.log10(high)
    return Margins(stable, crossover, phase_margin, gain_margin, reduction)


# --- the closed loop with the ceiling and the Coulomb torque ---------------------------------


@dataclass(frozen=True, slots=True)
class ClosedLoopRun:
    """A predicted (or measured) run: per tick the desired and actual counts and the output.

    Fields:
        desired: the position asked for on each tick, counts.
        actual: the count at the end of each tick.
        output_v: the drive's output on each tick, V.
    """

    desired: FloatArray
    actual: FloatArray
    output_v: FloatArray


def simulate_closed_loop(model: AxisModel, gains: PidGains, desired: Sequence[float] | FloatArray,
                         *, tick_s: float, start_counts: float = 0.0) -> ClosedLoopRun:
    """The device's PID (as :mod:`usbmotion.autotune.loop` describes it) on the model, from
    rest at ``start_counts`` with the PID fresh (as enabling leaves it), one desired
    position per tick. The count is the floor of the shaft's position, which starts in the
    middle of its count."""
    window = derivative_window(tick_s)
    ki_t = _four(gains.ki * tick_s)
    kd_w = _four(gains.kd / (window * tick_s))
    kp = gains.kp
    supply = model.supply_v
    limit = max(1, int(supply / ki_t)) if ki_t else 0
    keep, decay, lag = tick_constants(model.time_constant_s, tick_s)
    spread = model.time_constant_s * decay
    g, coulomb = model.speed_per_volt_counts_s, model.coulomb_v
    x = math.floor(start_counts) + 0.5
    w = 0.0
    count = math.floor(x)
    integral = 0
    history: list[int] = []
    slot = 0
    targets = np.asarray(desired, dtype=np.float64)
    actual = np.empty(targets.size)
    output = np.empty(targets.size)
    for k, want in enumerate(targets.tolist()):
        error = int(want) - count
        if not history:
            history = [error] * window
        change = error - history[slot]
        history[slot] = error
        slot = (slot + 1) % window
        candidate = 0
        if limit:
            candidate = max(-limit, min(limit, integral + error))
        volts = kp * error + ki_t * candidate + kd_w * change
        if volts > supply:
            volts = supply
            if error <= 0:
                integral = candidate
        elif volts < -supply:
            volts = -supply
            if error >= 0:
                integral = candidate
        else:
            integral = candidate
        if w > 0:
            direction = 1.0
        elif w < 0:
            direction = -1.0
        elif abs(volts) <= coulomb:
            direction = 0.0
        else:
            direction = 1.0 if volts > 0 else -1.0
        if direction:
            w, travel = motor_tick(w, g * (volts - direction * coulomb), direction,
                                   keep=keep, decay=decay, spread=spread, lag=lag)
            x += travel
        count = math.floor(x)
        actual[k] = count
        output[k] = volts
    return ClosedLoopRun(targets, actual, output)


# --- choosing the gains -------------------------------------------------------------------


def gains_for(model: AxisModel, *, crossover_hz: float, phase_margin_deg: float,
              integral_ratio: float, tick_s: float) -> PidGains | None:
    """The PID that puts the loop's gain crossover at ``crossover_hz`` with the phase
    margin ``phase_margin_deg`` there, its integral corner at ``integral_ratio`` times the
    crossover (``Ki = Kp 2 pi f_i``); None when that needs a negative gain."""
    omega = 2 * math.pi * crossover_hz
    z = cmath.exp(1j * omega * tick_s)
    window = derivative_window(tick_s)
    wanted = cmath.exp(1j * math.radians(-180.0 + phase_margin_deg))
    needed = wanted / complex(plant_response(model, z, tick_s=tick_s))
    a = 1 + integral_ratio * omega * tick_s * z / (z - 1)
    b = (1 - z ** (-window)) / (window * tick_s)
    matrix = np.array([[a.real, b.real], [a.imag, b.imag]])
    try:
        kp, kd = np.linalg.solve(matrix, np.array([needed.real, needed.imag]))
    except np.linalg.LinAlgError:
        return None
    if kp <= 0 or kd < 0:
        return None
    return PidGains(float(kp), float(kp * integral_ratio * omega), float(kd))


@dataclass(frozen=True, slots=True)
class Design:
    """Gains placed for a model, and what the model predicts of them.

    Fields:
        gains: the gains, as the device holds them (3 significant digits).
        crossover_hz: the bandwidth asked for (the loop's gain crossover).
        margins: the margins of the discrete loop with these gains.
        step: the predicted step response.
        move: the predicted move.
        move_ise_counts2_s: the move's integrated squared following error, counts^2 s.
    """

    gains: PidGains
    crossover_hz: float
    margins: Margins
    step: ClosedLoopRun
    move: ClosedLoopRun
    move_ise_counts2_s: float


OBJECTIVES = ("aligned", "device")
"""What the design minimises: the following error against the count at the tick's start
(``aligned``: the error the PID acts on, zero for a loop that tracks without lag) or
against the count at its end, as the device's statistics count it (``device``: call 35,
what ``usbmotion run`` reports). They differ by one tick of motion, ``v T``: a loop with
integral action drives the first to zero and leaves ``v T`` in the second; a loop without
one that lags a tick (``kp`` near ``1 / (g T)``) zeroes the second instead."""


def following_ise(run: ClosedLoopRun, *, tick_s: float, objective: str = "aligned") -> float:
    """The integrated squared following error of ``run``, counts^2 s (:data:`OBJECTIVES`)."""
    device = objective == "device"
    error = run.desired - run.actual if device else run.desired[1:] - run.actual[:-1]
    return float(error @ error) * tick_s


PHASE_MARGINS_DEG = (48.0, 52.0, 56.0, 60.0, 65.0)
INTEGRAL_RATIOS = (0.0, 0.03, 0.1, 0.2, 0.3, 0.45)
BANDWIDTHS_HZ = (5.0, 7.0, 10.0, 14.0, 20.0, 28.0, 40.0, 56.0, 80.0)
"""The bandwidths tried when none is asked for."""


def overshoot_pct(run: ClosedLoopRun, start: float, step: float) -> float:
    """The largest excursion past the target, percent of the step."""
    progress = (run.actual - start) / step
    return max(0.0, float(np.max(progress)) - 1.0) * 100.0


def design(model: AxisModel, *, tick_s: float, step_desired: FloatArray,
           move_desired: FloatArray, crossover_hz: float | None = None,
           max_overshoot_pct: float = MAX_OVERSHOOT_PCT - 1.0,
           objective: str = "aligned") -> Design:
    """The gains for ``crossover_hz`` (or for the best of :data:`BANDWIDTHS_HZ`) that keep
    :data:`MIN_PHASE_MARGIN_DEG` and :data:`MIN_GAIN_MARGIN_DB` on the discrete loop (the
    gains rounded as the device holds them) and a predicted overshoot of ``step_desired``
    of at most ``max_overshoot_pct``; of those, the one whose predicted ``move_desired``
    has the least integrated squared following error (:func:`following_ise` of
    ``objective``; both predictions with the supply's ceiling, the Coulomb torque and the
    encoder's counts, so a derivative gain that chatters on the counts pays for it).
    ``step_desired`` and ``move_desired`` hold one desired position per tick.

    Raises:
        ArgumentError: no gains meet the margins and the overshoot at that bandwidth, or an
            unknown ``objective``.
    """
    if objective not in OBJECTIVES:
        raise ArgumentError(f"objective {objective!r} is not one of {', '.join(OBJECTIVES)}",
                            reason="objective")
    bandwidths = BANDWIDTHS_HZ if crossover_hz is None else (crossover_hz,)
    step_size = float(step_desired[-1] - step_desired[0])
    if step_size == 0:
        raise ArgumentError("the design step must move", reason="step_desired")
    best: Design | None = None
    for bandwidth in bandwidths:
        for phase_margin in PHASE_MARGINS_DEG:
            for ratio in INTEGRAL_RATIOS:
                raw = gains_for(model, crossover_hz=bandwidth, phase_margin_deg=phase_margin,
                                integral_ratio=ratio, tick_s=tick_s)
                if raw is None:
                    continue
                gains = quantise(raw)
                found = margins(model, gains, tick_s=tick_s)
                if not (found.stable and found.phase_margin_deg >= MIN_PHASE_MARGIN_DEG
                        and found.gain_margin_db >= MIN_GAIN_MARGIN_DB
                        and found.gain_reduction_db >= MIN_GAIN_MARGIN_DB):
                    continue
                step = simulate_closed_loop(model, gains, step_desired, tick_s=tick_s,
                                            start_counts=float(step_desired[0]))
                if overshoot_pct(step, float(step_desired[0]), step_size) > max_overshoot_pct:
                    continue
                move = simulate_closed_loop(model, gains, move_desired, tick_s=tick_s,
                                            start_counts=float(move_desired[0]))
                ise = following_ise(move, tick_s=tick_s, objective=objective)
                if best is None or ise < best.move_ise_counts2_s:
                    best = Design(gains, bandwidth, found, step, move, ise)
    if best is None:
        asked = (f"{crossover_hz:g} Hz" if crossover_hz is not None
                 else f"any of {', '.join(f'{b:g}' for b in BANDWIDTHS_HZ)} Hz")
        raise ArgumentError(
            f"no PID gains at a bandwidth of {asked} keep {MIN_PHASE_MARGIN_DEG:g} degrees of"
            f" phase margin, {MIN_GAIN_MARGIN_DB:g} dB of gain margin, a step overshoot of at"
            f" most {max_overshoot_pct:g} % on this model; try a lower bandwidth",
            reason="bandwidth_hz")
    return best


__all__ = ["ClosedLoopRun", "Design", "Margins", "derivative_window", "design",
           "following_ise", "gains_for", "margins", "overshoot_pct", "quantise",
           "simulate_closed_loop"]
