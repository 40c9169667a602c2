"""``usbmotion tune``: a position step on one axis, its figures and a plot; or, with
``--reach``, what the axis's motor can do at full voltage, as a line for the machine file;
or, with ``--auto``, the axis identified, its gains placed and checked
(:mod:`usbmotion.cli.tune_auto`)."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from usbmotion.cli.exits import EXIT_BAD_INPUT, EXIT_FAULT, fail
from usbmotion.cli.machines import MachineOption, load_machine
from usbmotion.errors import ArgumentError, UsbMotionError

if TYPE_CHECKING:
    from usbmotion.host.config import AxisConfig, MachineConfig

REACH_DISTANCE_MAX_MM = 30.0
"""The default room of ``--reach``: a quarter of the axis's travel, at most this."""


def tune(
    axis: Annotated[str, typer.Option("--axis", "-a", help="The axis to test (e.g. X).")],
    step_mm: Annotated[
        float | None, typer.Option("--step-mm", help="Step size, mm (default 2).")
    ] = None,
    duration_s: Annotated[
        float | None, typer.Option("--duration-s", help="Record after the step, s (default 0.5).")
    ] = None,
    kp: Annotated[float | None, typer.Option("--kp", help="Try this proportional gain.")] = None,
    ki: Annotated[float | None, typer.Option("--ki", help="Try this integral gain.")] = None,
    kd: Annotated[float | None, typer.Option("--kd", help="Try this derivative gain.")] = None,
    reach: Annotated[
        bool,
        typer.Option(
            "--reach",
            help="Instead of a step: run the axis at full voltage there and back and print its"
            " top speed and acceleration, and the machine file's reach line.",
        ),
    ] = False,
    distance_mm: Annotated[
        float | None,
        typer.Option(
            "--distance-mm",
            help="With --reach: the room the test may use from where the axis stands, mm"
            " (negative: toward lower positions; default a quarter of the travel, at most 30).",
        ),
    ] = None,
    auto: Annotated[
        bool,
        typer.Option(
            "--auto",
            help="Instead of a step: identify the axis within --travel, pick PID gains for"
            " a bandwidth with at least 45 deg of phase margin and 6 dB of gain margin,"
            " check them with a step and a move, predicted beside measured.",
        ),
    ] = False,
    travel: Annotated[
        float | None,
        typer.Option("--travel", help="With --auto: the room the test may use from where the"
                     " axis stands, mm (negative: toward lower positions)."),
    ] = None,
    excite_s: Annotated[
        float | None,
        typer.Option("--excite-s", help="With --auto: how long the identification moves the"
                     " axis, s (default 6, at most 10)."),
    ] = None,
    bandwidth_hz: Annotated[
        float | None,
        typer.Option("--bandwidth-hz", help="With --auto: the loop's gain crossover, Hz"
                     " (default: the best of 5..80 Hz on the model)."),
    ] = None,
    objective: Annotated[
        str | None,
        typer.Option("--objective", help="With --auto: the following error the gains"
                     " minimise: 'aligned' (against the count at the tick's start, the error"
                     " the PID acts on; default) or 'device' (at the tick's end, as the"
                     " device's statistics and usbmotion run count it)."),
    ] = None,
    write: Annotated[
        bool,
        typer.Option("--write", help="With --auto: put the gains and the identified model"
                     " (the axis's model table, which usbmotion run --predict plays programs"
                     " on) into the machine file, its comments kept."),
    ] = False,
    as_json: Annotated[
        bool, typer.Option("--json", help="With --auto: print every figure as JSON.")
    ] = False,
    machine: MachineOption = None,
    plot: Annotated[
        Path | None, typer.Option("--plot", help="PNG to write (default: tune-AXIS.png).")
    ] = None,
    no_plot: Annotated[bool, typer.Option("--no-plot", help="Write no plot.")] = False,
) -> None:
    """Step one axis and print rise time, overshoot, settling time and steady-state error.

    The step starts from where the axis stands; a step that would leave the axis's
    travel_mm from there is refused before anything moves (on an axis that is not homed
    and has no simulated motor, where it stands is unknown: only a step longer than the
    whole travel is refused). --kp/--ki/--kd try gains without editing the
    configuration. --reach measures instead what the motor can do (keep --distance-mm
    free ahead of the axis) and prints the reach line that lets the machine file refuse
    limits the motor cannot reach. --auto identifies the axis's model within --travel
    (at most 10 s, never beyond that room nor the soft limits; a stall or a reversed
    encoder stops it), places its PID gains for a bandwidth with at least 45 degrees of
    phase margin and 6 dB of gain margin, checks them with a step and a move, and prints
    predicted beside measured; --write puts the gains and the model into the machine file.
    """
    if plot is not None and no_plot:
        fail("tune", f"--plot {plot} and --no-plot: give one or the other", EXIT_BAD_INPUT)
    config = load_machine(machine, "tune")
    if axis.upper() not in config.axis_names:
        fail("tune", f"no axis {axis!r}; {config.path} has {', '.join(config.axis_names)}",
             EXIT_BAD_INPUT)
    axis_config = config.axis(axis.upper())
    auto_only = [name for name, value in (("--travel", travel), ("--excite-s", excite_s),
                                          ("--bandwidth-hz", bandwidth_hz),
                                          ("--objective", objective))
                 if value is not None] + [name for name, on in (("--write", write),
                                                                ("--json", as_json)) if on]
    if auto:
        given = [name for name, value in (("--step-mm", step_mm), ("--duration-s", duration_s),
                                          ("--kp", kp), ("--ki", ki), ("--kd", kd),
                                          ("--plot", plot), ("--distance-mm", distance_mm))
                 if value is not None] + (["--reach"] if reach else [])
        if given:
            verb = "does" if len(given) == 1 else "do"
            fail("tune", f"{', '.join(given)} {verb} not apply to --auto; allowed with --auto:"
                 " --axis, --travel, --excite-s, --bandwidth-hz, --objective, --write, --json,"
                 " --machine",
                 EXIT_BAD_INPUT)
        if travel is None:
            fail("tune", "--auto needs --travel MM: the room the test may use from where the"
                 " axis stands (negative: toward lower positions)", EXIT_BAD_INPUT)
        if objective not in (None, "aligned", "device"):
            fail("tune", f"--objective {objective!r} is not one of aligned, device",
                 EXIT_BAD_INPUT)
        from usbmotion.cli.tune_auto import auto_tune  # noqa: PLC0415

        auto_tune(config, axis_config, travel_mm=travel,
                  excite_s=6.0 if excite_s is None else excite_s, bandwidth_hz=bandwidth_hz,
                  objective=objective or "aligned", write=write, as_json=as_json)
        return
    if auto_only:
        verb = "applies" if len(auto_only) == 1 else "apply"
        fail("tune", f"{', '.join(auto_only)} {verb} to --auto only", EXIT_BAD_INPUT)
    if reach:
        given = [name for name, value in (("--step-mm", step_mm), ("--duration-s", duration_s),
                                          ("--kp", kp), ("--ki", ki), ("--kd", kd),
                                          ("--plot", plot)) if value is not None]
        if given:
            verb = "does" if len(given) == 1 else "do"
            typer.echo(f"usbmotion tune: {', '.join(given)} {verb} not apply to --reach, which"
                       " runs the axis at full voltage on its own gains; allowed with --reach:"
                       " --axis, --distance-mm, --machine", err=True)
            raise typer.Exit(EXIT_BAD_INPUT)
        _reach(config, axis_config, distance_mm)
        return
    if distance_mm is not None:
        typer.echo("usbmotion tune: --distance-mm applies to --reach only", err=True)
        raise typer.Exit(EXIT_BAD_INPUT)
    _step(config, axis_config, step_mm=2.0 if step_mm is None else step_mm,
          duration_s=0.5 if duration_s is None else duration_s, kp=kp, ki=ki, kd=kd, plot=plot,
          no_plot=no_plot)


def _step(config: MachineConfig, axis_config: AxisConfig, *, step_mm: float,
          duration_s: float, kp: float | None, ki: float | None, kd: float | None,
          plot: Path | None, no_plot: bool = False) -> None:
    from usbmotion.host.config import PidGains  # noqa: PLC0415
    from usbmotion.sim.machine import connect_machine  # noqa: PLC0415
    from usbmotion.tuning import stands_at_mm, step_response  # noqa: PLC0415

    gains = axis_config.gains
    tried = PidGains(kp if kp is not None else gains.kp, ki if ki is not None else gains.ki,
                     kd if kd is not None else gains.kd)
    axes = tuple(dataclasses.replace(a, gains=tried) if a.name == axis_config.name else a
                 for a in config.axes)
    config = dataclasses.replace(config, axes=axes)
    try:
        with connect_machine(config) as connected:
            connected.configure()
            if stands_at_mm(connected, axis_config.name) is None:
                typer.echo(f"usbmotion tune: axis {axis_config.name} is not homed, so where it"
                           " stands in its travel is unknown: keep the step clear of its"
                           " ends", err=True)
            response = step_response(connected, axis_config.name, step_mm=step_mm,
                                     duration_s=duration_s)
            connected.stop()
    except ArgumentError as error:
        fail("tune", str(error), EXIT_BAD_INPUT)
    except UsbMotionError as error:
        fail("tune", str(error), EXIT_FAULT)
    m = response.metrics
    scale = axis_config.counts_per_mm

    def ms(value: float) -> str:
        return "never" if math.isnan(value) else f"{value * 1000:.1f} ms"

    typer.echo(f"axis {axis_config.name}: step {m.step_counts} counts ({step_mm:g} mm),"
               f" gains kp {tried.kp:g} ki {tried.ki:g} kd {tried.kd:g}")
    typer.echo(f"rise time (10-90 %)   {ms(m.rise_time_s)}")
    typer.echo(f"overshoot             {m.overshoot_pct:.2f} %")
    typer.echo(f"settling time         {ms(m.settling_time_s)} (band +-{m.settling_band_counts:g}"
               " counts)")
    typer.echo(f"steady-state error    {m.steady_state_error_counts:.2f} counts"
               f" ({m.steady_state_error_counts / scale * 1000:.2f} um)")
    if no_plot:
        return
    from usbmotion.cli.plots import plot_step  # noqa: PLC0415

    target = plot or Path(f"tune-{axis_config.name}.png")
    plot_step(target, response)
    typer.echo(f"plot                  {target}")


def _stepper_reach(config: MachineConfig, axis_config: AxisConfig) -> None:
    """``--reach`` on a stepper axis: what limits it, said honestly. The step rate is the
    device's (call 48, at the driver's timing); the torque is not measured (open loop the
    device counts the steps it issues, not the shaft); a simulated stepper's torque curve
    gives the limits its machine file may set."""
    from usbmotion.host.config import (  # noqa: PLC0415
        OPEN_LOOP_MARGIN,
        REACH_MARGIN,
        SimStepperConfig,
        round_down,
        stepper_reach,
    )
    from usbmotion.sim.machine import connect_machine  # noqa: PLC0415

    stepper = axis_config.stepper
    assert stepper is not None
    name = axis_config.name
    try:
        with connect_machine(config) as connected:
            connected.configure()
            client = connected.axis(name).client
            per_tick = client.steps().max_per_tick
            tick_us = client.servo_interval_us()
    except UsbMotionError as error:
        fail("tune", str(error), EXIT_FAULT)
    scale = axis_config.counts_per_mm
    rate = per_tick / (tick_us * 1e-6)
    share = 1.0 - REACH_MARGIN if stepper.closed else 1.0
    typer.echo(f"axis {name}: a stepper, {stepper.loop} loop, {scale:g} microsteps per mm"
               f" ({stepper.microsteps} microsteps per full step)")
    typer.echo(f"step rate  the driver's timing ({stepper.step_pulse_ns} ns pulses,"
               f" {stepper.dir_setup_ns} ns set-up) lets the device issue {per_tick} steps a"
               f" {tick_us} us tick (call 48): {rate:.6g} steps/s, {rate / scale:.6g} mm/s;"
               f" max_velocity_mm_s <= {round_down(share * rate / scale):g}"
               + (f" ({1 - REACH_MARGIN:.0%}: the closed loop keeps the rest to catch up)"
                  if stepper.closed else ""))
    if stepper.closed:
        typer.echo("torque     not measured: a run at full torque (the field a full step"
                   " ahead of the shaft) does not come back to rest by itself on the device's"
                   " closed loop; a load beyond the torque shows as following error on the"
                   f" tick it comes (try gains with a step: usbmotion tune -a {name} --kp ...)")
    else:
        typer.echo("torque     not measured: open loop the device counts the steps it issues,"
                   " not the shaft, so no run shows what the motor did; a step it loses shows"
                   " only at the next homing, as the switch closing at another step count")
    sim = axis_config.sim
    top = axis_config.max_velocity_mm_s
    if isinstance(sim, SimStepperConfig):
        reach = stepper_reach(sim, stepper, scale)
        margin = REACH_MARGIN if stepper.closed else OPEN_LOOP_MARGIN
        typer.echo(
            f"simulated  {sim.holding_torque_mnm} mNm up to {reach.corner_mm_s:.4g} mm/s"
            f" ({sim.corner_rpm} rpm), falling as 1/speed; keeping {margin:.0%} of it,"
            f" the machine file may set max_velocity_mm_s <="
            f" {round_down(reach.usable_velocity_mm_s(margin=margin)):g} and, at"
            f" max_velocity_mm_s {top:g}, max_accel_mm_s2 <="
            f" {round_down(reach.usable_accel_mm_s2(top, margin=margin)):g} (it sets"
            f" {top:g} and {axis_config.max_accel_mm_s2:g})")
    typer.echo("no reach line: a stepper axis takes none; its limits are checked against its"
               " step rate (and a simulated one's against its torque) when the file loads")


def _reach(config: MachineConfig, axis_config: AxisConfig, distance_mm: float | None) -> None:
    from usbmotion.host.config import REACH_MARGIN, round_down  # noqa: PLC0415

    if axis_config.stepper is not None:
        if distance_mm is not None:
            fail("tune", "--distance-mm: --reach on a stepper axis runs no motor",
                 EXIT_BAD_INPUT)
        _stepper_reach(config, axis_config)
        return
    from usbmotion.sim.machine import connect_machine  # noqa: PLC0415
    from usbmotion.tuning import measure_reach  # noqa: PLC0415

    low, high = axis_config.travel_mm
    distance = (distance_mm if distance_mm is not None
                else min(REACH_DISTANCE_MAX_MM, (high - low) / 4))
    try:
        with connect_machine(config) as connected:
            connected.configure()
            try:
                measured = measure_reach(connected, axis_config.name, distance_mm=distance)
            finally:
                connected.stop()
    except ArgumentError as error:
        typer.echo(f"usbmotion tune: {error}", err=True)
        raise typer.Exit(EXIT_BAD_INPUT) from None
    except UsbMotionError as error:
        typer.echo(f"usbmotion tune: {error}", err=True)
        raise typer.Exit(EXIT_FAULT) from None
    scale = axis_config.counts_per_mm
    name = axis_config.name
    typer.echo(f"axis {name}: at full voltage ({measured.supply_v:g} V) from where it stood,"
               f" {abs(distance):g} mm toward {'+' if distance > 0 else '-'} and back")
    typer.echo("run  top speed      time constant  from standstill   fit RMS")
    for run in measured.runs:
        fit = run.fit
        typer.echo(f"{'+' if run.direction > 0 else '-'}    "
                   f"{fit.top_speed_counts_s / scale:8.2f} mm/s  "
                   f"{fit.time_constant_s * 1000:8.1f} ms    "
                   f"{fit.accel_counts_s2 / scale:8.0f} mm/s^2   "
                   f"{fit.rms_residual_counts:.2f} counts")
    result = measured.reach
    velocity, accel = round_down(result.velocity_mm_s), round_down(result.accel_mm_s2)
    typer.echo(f"reach {velocity:g} mm/s top speed, {accel:g} mm/s^2 from standstill (the lesser"
               " of the runs)")
    top = axis_config.max_velocity_mm_s
    typer.echo(
        f"at max_velocity_mm_s {top:g} the motor gives {result.accel_at_mm_s2(top):.4g} mm/s^2;"
        f" keeping {REACH_MARGIN:.0%} of the supply for the PID, the machine file may set"
        f" max_velocity_mm_s <= {round_down(result.usable_velocity_mm_s):g} and"
        f" max_accel_mm_s2 <= {round_down(result.usable_accel_mm_s2(top)):g}"
        f" (it sets {top:g} and {axis_config.max_accel_mm_s2:g})"
    )
    over = (top > result.usable_velocity_mm_s
            or axis_config.max_accel_mm_s2 > result.usable_accel_mm_s2(top))
    if over:
        typer.echo("the file's limits are beyond that: lower them before adding the reach line")
    typer.echo(f"put in [axes.{name}] of {config.path}:")
    typer.echo(f"reach = {{ velocity_mm_s = {velocity:g}, accel_mm_s2 = {accel:g} }}")
