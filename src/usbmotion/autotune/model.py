"""The axis as its drive sees it, and its fit to a record of volts in and counts out.

The simulated motor (PROTOCOL.md, "The simulated motor") and any brushed DC motor whose
winding inductance is below a servo tick obey, at the encoder shaft and in counts::

    tau dw/dt = g (V - C sign(w)) - w

with ``V`` the drive's output (volts, held over each servo tick), ``w`` the speed (counts/s),
``tau = J / (Kt^2/R + b)`` the mechanical time constant, ``g = (Kt/R) / (Kt^2/R + b) / k``
the speed one volt holds (``k`` radians per count) and ``C = T_load R / Kt`` the voltage the
Coulomb torque takes (the motor breaks away above it). These three are all that volts and
counts can tell: the five physical figures (``J``, ``b``, ``T_load``, ``Kt``, ``R``) enter
only through them, and a motor with ``s`` times the torque constant and ``s`` times the
inertia and load (viscous friction adjusted) moves exactly alike. Given the torque constant
and the resistance (a datasheet's, or the machine file's ``sim`` table), the other three
follow (:meth:`AxisModel.physical`).

Everything here is pure: arrays in, figures out.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from usbmotion.errors import ArgumentError
from usbmotion.host.config import AxisConfig, SimMotorConfig

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True, slots=True)
class AxisModel:
    """The identifiable model of one axis, in the drive's units.

    Fields:
        time_constant_s: ``tau``, the mechanical time constant, s.
        speed_per_volt_counts_s: ``g``, the steady speed one volt above the Coulomb voltage
            holds, counts/s per V.
        coulomb_v: ``C``, the voltage the Coulomb (load) torque takes, V.
        supply_v: the drive's ceiling, V (the device's source voltage).
    """

    time_constant_s: float
    speed_per_volt_counts_s: float
    coulomb_v: float
    supply_v: float

    @property
    def accel_per_volt_counts_s2(self) -> float:
        """``g / tau``: the acceleration one volt gives from standstill, counts/s^2 per V
        (``Kt / (R J k)``)."""
        return self.speed_per_volt_counts_s / self.time_constant_s

    def steady_speed_counts_s(self, voltage_v: float) -> float:
        """The speed a constant voltage holds, counts/s (0 below the Coulomb voltage)."""
        if abs(voltage_v) <= self.coulomb_v:
            return 0.0
        return self.speed_per_volt_counts_s * (voltage_v - math.copysign(self.coulomb_v,
                                                                          voltage_v))

    def physical(self, *, torque_constant_nm_per_a: float, resistance_ohm: float,
                 counts_per_revolution: int) -> PhysicalModel:
        """The inertia, viscous friction and load torque this model means for a motor of the
        given torque constant and resistance.

        Raises:
            ArgumentError: a torque constant, resistance or count not above 0.
        """
        kt, resistance = torque_constant_nm_per_a, resistance_ohm
        if not (kt > 0 and resistance > 0 and counts_per_revolution > 0):
            raise ArgumentError(
                f"torque constant {kt!r} N m/A, resistance {resistance!r} ohm and"
                f" {counts_per_revolution!r} counts per revolution must all be above 0",
                reason="physical")
        counts_per_rad = counts_per_revolution / (2.0 * math.pi)
        inertia = kt * counts_per_rad / (resistance * self.accel_per_volt_counts_s2)
        viscous = inertia / self.time_constant_s - kt * kt / resistance
        load = self.coulomb_v * kt / resistance
        return PhysicalModel(inertia, viscous, load, kt, resistance)


@dataclass(frozen=True, slots=True)
class PhysicalModel:
    """An :class:`AxisModel` in SI figures, for a given torque constant and resistance.

    Fields:
        inertia_kg_m2: ``J`` at the encoder shaft.
        viscous_nm_s_per_rad: ``b`` (negative when the damping measured is below what the
            given torque constant's back-EMF alone gives: the torque constant is off).
        load_torque_nm: ``T_load``, the Coulomb torque.
        torque_constant_nm_per_a: ``Kt`` as given.
        resistance_ohm: ``R`` as given.
    """

    inertia_kg_m2: float
    viscous_nm_s_per_rad: float
    load_torque_nm: float
    torque_constant_nm_per_a: float
    resistance_ohm: float


def true_model(*, torque_constant_nm_per_a: float, resistance_ohm: float,
               inertia_kg_m2: float, viscous_nm_s_per_rad: float, load_torque_nm: float,
               counts_per_revolution: int, supply_v: float) -> AxisModel:
    """The :class:`AxisModel` of a motor whose physical figures are known (a simulated one)."""
    kt, resistance = torque_constant_nm_per_a, resistance_ohm
    damping = kt * kt / resistance + viscous_nm_s_per_rad
    counts_per_rad = counts_per_revolution / (2.0 * math.pi)
    return AxisModel(
        time_constant_s=inertia_kg_m2 / damping,
        speed_per_volt_counts_s=kt / resistance / damping * counts_per_rad,
        coulomb_v=load_torque_nm * resistance / kt,
        supply_v=supply_v,
    )


def simulated_model(axis: AxisConfig) -> AxisModel:
    """The exact model of a simulated axis's motor (its ``sim`` table, as the device
    holds it: :func:`true_model` of its figures).

    Raises:
        ArgumentError: the axis has no ``sim`` table.
    """
    if axis.sim is None:
        raise ArgumentError(f"axis {axis.name} has no sim table: no simulated motor",
                            reason="axis")
    if not isinstance(axis.sim, SimMotorConfig):
        raise ArgumentError(f"axis {axis.name} is a stepper: its simulated motor is no DC"
                            " motor to model", reason="axis")
    motor = axis.sim.model()
    return true_model(torque_constant_nm_per_a=motor.torque_constant_nm_per_a,
                      resistance_ohm=motor.resistance_ohm, inertia_kg_m2=motor.inertia_kg_m2,
                      viscous_nm_s_per_rad=motor.viscous_nm_s_per_rad,
                      load_torque_nm=motor.load_torque_nm,
                      counts_per_revolution=motor.counts_per_revolution,
                      supply_v=motor.source_voltage_v)


# --- the discrete-time model -----------------------------------------------------------------


def tick_constants(time_constant_s: float, tick_s: float) -> tuple[float, float, float]:
    """``(e, F, Q)`` of one tick under a held voltage: ``e = exp(-h/tau)``, ``F = 1 - e``,
    ``Q = h - tau F``. Over the tick the speed goes ``w -> e w + F u`` and the shaft travels
    ``tau F w + Q u``, where ``u = g (V - C sign(w))`` is the speed the voltage holds."""
    ratio = tick_s / time_constant_s
    decay = -math.expm1(-ratio)
    return 1.0 - decay, decay, tick_s - time_constant_s * decay


def simulate_open_loop(model: AxisModel, voltages_v: FloatArray, *, tick_s: float,
                       speed_counts_s: float = 0.0) -> FloatArray:
    """Positions (counts, from 0) at the end of each tick under ``voltages_v``, one voltage
    per tick, with the Coulomb torque as the device's motor has it: at rest the shaft stays
    until the voltage exceeds ``C``, and a tick in which the speed would reverse ends at
    rest."""
    keep, decay, lag = tick_constants(model.time_constant_s, tick_s)
    spread = model.time_constant_s * decay
    g, coulomb = model.speed_per_volt_counts_s, model.coulomb_v
    w = speed_counts_s
    x = 0.0
    out = np.empty(voltages_v.size, dtype=np.float64)
    for k, v in enumerate(voltages_v.tolist()):
        if w > 0:
            direction = 1.0
        elif w < 0:
            direction = -1.0
        elif abs(v) <= coulomb:
            out[k] = x
            continue
        else:
            direction = 1.0 if v > 0 else -1.0
        w, travel = motor_tick(w, g * (v - direction * coulomb), direction,
                               keep=keep, decay=decay, spread=spread, lag=lag)
        x += travel
        out[k] = x
    return out


def motor_tick(w: float, u: float, direction: float, *, keep: float, decay: float,
               spread: float, lag: float) -> tuple[float, float]:
    """One tick of the motor moving in ``direction`` (+1, -1) from speed ``w`` (counts/s)
    toward ``u`` (speed per volt x the voltage beyond the Coulomb voltage): its speed at
    the tick's end and the counts it travelled (:func:`tick_constants`); a tick in which
    the speed would reverse ends at rest."""
    w_next = keep * w + decay * u
    travel = spread * w + lag * u
    if direction > 0:
        return max(w_next, 0.0), max(travel, 0.0)
    return min(w_next, 0.0), min(travel, 0.0)


# --- the fit ---------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Segment:
    """A stretch of a record that starts at rest: the tick it rests on and the ticks after.

    Fields:
        start: index of the resting sample (its position is the origin of the stretch).
        stop: index one past the last sample of the stretch.
    """

    start: int
    stop: int


@dataclass(frozen=True, slots=True)
class ModelFit:
    """A fitted :class:`AxisModel` with the standard error of each figure.

    Fields:
        model: the fitted model.
        time_constant_sigma_s, speed_per_volt_sigma_counts_s, coulomb_sigma_v: one standard
            error of each figure (:attr:`uncertainty` says how it was found).
        rms_residual_counts: how far the measured positions are from the model's, RMS.
        samples: the ticks the fit used.
        segments: the stretches from rest it used.
        covariance: the covariance of ``(tau, g, C)``, row by row (their correlations
            matter for figures made of several: the inertia is ``Kt / (R k g / tau)``).
        uncertainty: how the standard errors were found: ``"jackknife"`` over the
            stretches, or ``"least squares"`` (:func:`fit_model`).
    """

    model: AxisModel
    time_constant_sigma_s: float
    speed_per_volt_sigma_counts_s: float
    coulomb_sigma_v: float
    rms_residual_counts: float
    samples: int
    segments: int

    covariance: tuple[tuple[float, ...], ...] = ()
    uncertainty: str = "least squares"

    def sigma_of(self, figure: Callable[[AxisModel], float], *, step: float = 1e-6) -> float:
        """One standard error of ``figure(model)``, from the fit's covariance (the figure
        linearised by central differences of each of ``tau``, ``g``, ``C``)."""
        if not self.covariance:
            return math.nan
        base = self.model
        fields = ("time_constant_s", "speed_per_volt_counts_s", "coulomb_v")
        gradient = []
        for name in fields:
            value = getattr(base, name)
            h = step * max(abs(value), 1e-12)
            up = figure(dataclasses.replace(base, **{name: value + h}))
            down = figure(dataclasses.replace(base, **{name: value - h}))
            gradient.append((up - down) / (2 * h))
        grad = np.array(gradient)
        variance = float(grad @ np.array(self.covariance) @ grad)
        return math.sqrt(variance) if variance >= 0 else math.nan


REST_TICKS = 10
"""A position unchanged for this many ticks is at rest (the speed is 0 in the middle)..."""
REST_S = 0.003
"""... and for at least this long (at 10 kHz a shaft creeping at 1000 counts/s keeps its
count for 10 ticks; one whose count stays 3 ms is slower than 333 counts/s, and the fit's
second pass drops the rests whose voltage could move it)."""


def rest_ticks_for(tick_s: float) -> int:
    """The ticks a rest lasts at least at a servo period: :data:`REST_TICKS`, at least
    :data:`REST_S`."""
    return max(REST_TICKS, round(REST_S / tick_s))
MIN_SEGMENT_COUNTS = 20
"""A stretch that moves less than this is left out of the fit (quantisation and stiction)."""


def rest_runs(positions: FloatArray, *, rest_ticks: int = REST_TICKS) -> list[tuple[int, int]]:
    """``(first, last)`` index of every run of at least ``rest_ticks`` equal positions."""
    runs: list[tuple[int, int]] = []
    first = 0
    n = positions.size
    for k in range(1, n + 1):
        if k == n or positions[k] != positions[k - 1]:
            if k - first >= rest_ticks:
                runs.append((first, k - 1))
            first = k
    return runs


def rest_segments(positions: FloatArray, *, rest_ticks: int = REST_TICKS,
                  min_counts: float = MIN_SEGMENT_COUNTS) -> list[Segment]:
    """The stretches of ``positions`` between rests that move at least ``min_counts``: each
    from the middle of a rest (``rest_ticks`` equal positions: the shaft stopped and has not
    started yet) to the middle of the next one (or the record's end)."""
    runs = rest_runs(positions, rest_ticks=rest_ticks)
    segments: list[Segment] = []
    for index, (first, last) in enumerate(runs):
        start = (first + last) // 2
        if index + 1 < len(runs):
            after_first, after_last = runs[index + 1]
            stop = (after_first + after_last) // 2 + 1
        else:
            stop = positions.size
        stretch = positions[start:stop]
        if stop - start > 2 and float(np.max(np.abs(stretch - stretch[0]))) >= min_counts:
            segments.append(Segment(start, stop))
    return segments


def _moving_part(positions: FloatArray, segment: Segment) -> Segment:
    """``segment`` from the last tick of its rest to the first tick of the next: where the
    shaft moves all along, so a model without stiction may be fitted there."""
    x = positions
    start = segment.start
    while start + 1 < segment.stop and x[start + 1] == x[segment.start]:
        start += 1
    stop = segment.stop
    while stop - 1 > start + 2 and x[stop - 1] == x[stop - 2]:
        stop -= 1
    return Segment(start, stop)


def _directions(positions: FloatArray, segment: Segment) -> FloatArray:
    """The sign of the motion on each tick of ``segment`` after its first, from the
    positions: the centred difference, else the last one, else the direction before."""
    x = positions[segment.start:segment.stop]
    signs = np.zeros(x.size - 1, dtype=np.float64)
    last = 0.0
    for k in range(1, x.size):
        ahead = x[min(k + 1, x.size - 1)] - x[k - 1]
        step = x[k] - x[k - 1]
        if ahead != 0:
            last = 1.0 if ahead > 0 else -1.0
        elif step != 0:
            last = 1.0 if step > 0 else -1.0
        signs[k - 1] = last
    if signs.size and signs[0] == 0:
        nonzero = np.nonzero(signs)[0]
        if nonzero.size:
            signs[:nonzero[0]] = signs[nonzero[0]]
    return signs


def _bases(time_constant_s: float, tick_s: float, voltages: Sequence[FloatArray],
           signs: Sequence[FloatArray]) -> tuple[FloatArray, FloatArray]:
    """For every segment from rest, the positions a unit speed-per-volt gives under its
    voltages, and those the signs give: the model's positions are ``g (a - C b)``."""
    keep, decay, lag = tick_constants(time_constant_s, tick_s)
    spread = time_constant_s * decay
    from_volts: list[float] = []
    from_signs: list[float] = []
    for volts, sign in zip(voltages, signs, strict=True):
        wa = wb = xa = xb = 0.0
        for v, s in zip(volts.tolist(), sign.tolist(), strict=True):
            xa += spread * wa + lag * v
            wa = keep * wa + decay * v
            xb += spread * wb + lag * s
            wb = keep * wb + decay * s
            from_volts.append(xa)
            from_signs.append(xb)
    return np.asarray(from_volts), np.asarray(from_signs)


def _initial_guess(voltages_v: FloatArray, positions: FloatArray, segments: Sequence[Segment],
                   tick_s: float) -> tuple[float, float, float]:
    """``(tau, g, C)`` from the moving parts of ``segments`` by a model without stiction
    (linear in ``g`` and ``g C`` for a given ``tau``; ``tau`` by a search on its logarithm)."""
    parts = [_moving_part(positions, s) for s in segments]
    volts = [voltages_v[s.start + 1:s.stop] for s in parts]
    signs = [_directions(positions, s) for s in parts]
    moved = np.concatenate([positions[s.start + 1:s.stop] - positions[s.start] for s in parts])

    def solve(tau: float) -> tuple[float, float, float]:
        a, b = _bases(tau, tick_s, volts, signs)
        design = np.stack([a, -b], axis=1)
        (g, gc), *_ = np.linalg.lstsq(design, moved, rcond=None)
        residual = moved - design @ np.array([g, gc])
        return float(g), float(gc), float(residual @ residual)

    grid = np.geomspace(tick_s / 5, 20.0, 31)
    costs = [solve(float(t))[2] for t in grid]
    best = int(np.argmin(costs))
    low = math.log(float(grid[max(best - 1, 0)]))
    high = math.log(float(grid[min(best + 1, grid.size - 1)]))
    ratio = (math.sqrt(5) - 1) / 2
    a_, b_ = high - ratio * (high - low), low + ratio * (high - low)
    cost_a, cost_b = solve(math.exp(a_))[2], solve(math.exp(b_))[2]
    while high - low > 1e-4:
        if cost_a < cost_b:
            high, b_, cost_b = b_, a_, cost_a
            a_ = high - ratio * (high - low)
            cost_a = solve(math.exp(a_))[2]
        else:
            low, a_, cost_a = a_, b_, cost_b
            b_ = low + ratio * (high - low)
            cost_b = solve(math.exp(b_))[2]
    tau = math.exp((low + high) / 2)
    g, gc, _ = solve(tau)
    return tau, g, max(0.0, gc / g) if g > 0 else 0.0


def _segment_residuals(params: FloatArray, voltages: Sequence[FloatArray],
                       moved: FloatArray, tick_s: float, supply_v: float) -> FloatArray:
    """Measured less modelled positions of every stretch, each less its mean (clipped to a
    count: the unknown place of the resting shaft within its count)."""
    tau, g, coulomb = math.exp(params[0]), math.exp(params[1]), float(params[2])
    model = AxisModel(tau, g, coulomb, supply_v)
    runs = [simulate_open_loop(model, v, tick_s=tick_s) for v in voltages]
    residual = moved - np.concatenate(runs)
    first = 0
    for run in runs:
        part = residual[first:first + run.size]
        part -= max(-1.0, min(1.0, float(np.mean(part))))
        first += run.size
    return residual


def fit_model(voltages_v: FloatArray, positions: FloatArray, *, tick_s: float,
              supply_v: float, segments: Sequence[Segment] | None = None,
              iterations: int = 30, jackknife: bool = True) -> ModelFit:
    """Fit :class:`AxisModel` to a record, one sample per servo tick: least squares on the
    exact discrete-time model.

    ``voltages_v[k]`` is the output the drive held over tick ``k`` and ``positions[k]`` the
    count at its end (what a diagnostics line carries). The record is cut into stretches
    that start in the middle of a rest (:func:`rest_segments`, :func:`rest_ticks_for`),
    where the shaft is still;
    on each, the model (:func:`simulate_open_loop`: the exact solution over each tick, the
    Coulomb torque holding the shaft below ``C`` and stopping it where it would reverse)
    runs from rest under the measured voltages and is compared with the measured
    positions, less the stretch's mean difference (within one count: where in its count
    the shaft rested is unknown, and a position loop rests it at a count's edge, not
    uniformly within). Output error, not equation error: the encoder's quantisation is
    noise on what is compared, never on what the model is fed, so it does not bias the
    fit.
    Levenberg-Marquardt on ``(log tau, log g, C)`` from a first guess of a model without
    stiction; then once more without the stretches whose resting voltage was above the
    fitted ``C`` (the shaft may have crept there, not rested). The standard errors are the
    jackknife's over the stretches (each left out in turn, the fit done again: the spread
    of the fits from stretch to stretch, which holds what the quantisation noise does not:
    where each rest stood within its count, the drive's rounding), when there are at least
    :data:`JACKKNIFE_MIN_SEGMENTS` and ``jackknife``; else those of least squares, from
    the Jacobian at the optimum (these count the quantisation noise alone, and on
    simulated axes come out about ten times below the real errors).

    Raises:
        ArgumentError: arrays of different shapes, a tick not above 0, or no stretch from
            rest that moves (the record has nothing to fit).
    """
    if voltages_v.shape != positions.shape or voltages_v.ndim != 1:
        raise ArgumentError(f"voltages {voltages_v.shape} and positions {positions.shape}"
                            " must be one-dimensional and match", reason="arrays")
    if not tick_s > 0:
        raise ArgumentError(f"tick_s {tick_s!r} must be above 0", reason="tick_s")
    rest_ticks = rest_ticks_for(tick_s)
    chosen = list(rest_segments(positions, rest_ticks=rest_ticks) if segments is None
                  else segments)
    if not chosen:
        raise ArgumentError(
            f"no stretch of the record starts at rest ({rest_ticks} ticks still) and moves"
            f" {MIN_SEGMENT_COUNTS} counts: nothing to fit", reason="record")
    tau, g, coulomb = _initial_guess(voltages_v, positions, chosen, tick_s)
    fit = _refine(voltages_v, positions, chosen, tick_s, supply_v, (tau, g, coulomb),
                  iterations)
    still = [s for s in chosen
             if abs(voltages_v[s.start]) < fit.model.coulomb_v
             and abs(voltages_v[s.start - 1]) < fit.model.coulomb_v]
    used = chosen
    if still and len(still) < len(chosen):
        fit = _refine(voltages_v, positions, still, tick_s, supply_v, _figures(fit.model),
                      iterations)
        used = still
    if not jackknife or len(used) < JACKKNIFE_MIN_SEGMENTS:
        return fit
    estimates = np.array([
        _figures(_refine(voltages_v, positions, [s for j, s in enumerate(used) if j != i],
                         tick_s, supply_v, _figures(fit.model), iterations).model)
        for i in range(len(used))])
    n = len(used)
    spread = estimates - estimates.mean(axis=0)
    covariance = (n - 1) / n * spread.T @ spread
    sigmas = np.sqrt(np.maximum(np.diag(covariance), 0.0))
    return dataclasses.replace(
        fit, time_constant_sigma_s=float(sigmas[0]),
        speed_per_volt_sigma_counts_s=float(sigmas[1]), coulomb_sigma_v=float(sigmas[2]),
        covariance=tuple(tuple(float(v) for v in row) for row in covariance),
        uncertainty="jackknife")


JACKKNIFE_MIN_SEGMENTS = 4
"""The fewest stretches from rest the jackknife takes; with fewer, the least-squares errors."""


def _figures(model: AxisModel) -> tuple[float, float, float]:
    return model.time_constant_s, model.speed_per_volt_counts_s, model.coulomb_v


def _refine(voltages_v: FloatArray, positions: FloatArray, chosen: Sequence[Segment],
            tick_s: float, supply_v: float, guess: tuple[float, float, float],
            iterations: int) -> ModelFit:
    """Levenberg-Marquardt from ``guess`` on the stretches ``chosen``."""
    tau, g, coulomb = guess
    volts = [voltages_v[s.start + 1:s.stop] for s in chosen]
    moved = np.concatenate([positions[s.start + 1:s.stop] - positions[s.start] for s in chosen])

    def residuals(p: FloatArray) -> FloatArray:
        return _segment_residuals(p, volts, moved, tick_s, supply_v)

    def jacobian(p: FloatArray, base: FloatArray) -> FloatArray:
        columns = []
        for i, step in enumerate((1e-6, 1e-6, 1e-5)):
            shifted = p.copy()
            shifted[i] += step
            columns.append((residuals(shifted) - base) / step)
        return np.stack(columns, axis=1)

    p = np.array([math.log(tau), math.log(g), coulomb])
    r = residuals(p)
    cost = float(r @ r)
    damping = 1e-3
    for _ in range(iterations):
        jac = jacobian(p, r)
        normal = jac.T @ jac
        gradient = jac.T @ r
        improved = False
        shrink = 0.0
        for _ in range(10):
            try:
                delta = np.linalg.solve(normal + damping * np.diag(np.diag(normal)), -gradient)
            except np.linalg.LinAlgError:
                damping *= 10
                continue
            trial = p + delta
            trial[2] = max(trial[2], 0.0)
            r_trial = residuals(trial)
            cost_trial = float(r_trial @ r_trial)
            if cost_trial < cost:
                shrink = (cost - cost_trial) / cost if cost else 0.0
                p, r, cost = trial, r_trial, cost_trial
                damping = max(damping / 10, 1e-9)
                improved = True
                break
            damping *= 10
        if not improved or shrink < 1e-12:
            break
    jac = jacobian(p, r)
    n = moved.size
    variance = cost / max(1, n - 3)
    tau, g, coulomb = math.exp(p[0]), math.exp(p[1]), float(p[2])
    try:
        scale = np.diag([tau, g, 1.0])  # from (log tau, log g, C) to (tau, g, C)
        covariance = scale @ (variance * np.linalg.inv(jac.T @ jac)) @ scale
    except np.linalg.LinAlgError:
        covariance = np.full((3, 3), math.inf)
    sigmas = np.sqrt(np.maximum(np.diag(covariance), 0.0))
    return ModelFit(AxisModel(tau, g, coulomb, supply_v), float(sigmas[0]), float(sigmas[1]),
                    float(sigmas[2]), math.sqrt(cost / n), n, len(chosen),
                    tuple(tuple(float(v) for v in row) for row in covariance))


__all__ = ["AxisModel", "ModelFit", "PhysicalModel", "Segment", "fit_model", "rest_runs",
           "rest_segments",
           "simulate_open_loop", "tick_constants", "true_model"]
