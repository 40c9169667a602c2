"""``usbmotion tune``: a position step on one axis, its figures and a plot."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Annotated

import typer

from usbmotion.cli.run import EXIT_BAD_INPUT, EXIT_FAULT, MachineOption, default_machine
from usbmotion.errors import ConfigError, UsbMotionError


def tune(
    axis: Annotated[str, typer.Option("--axis", "-a", help="The axis to step (e.g. X).")],
    step_mm: Annotated[float, typer.Option("--step-mm", help="Step size, mm.")] = 2.0,
    duration_s: Annotated[
        float, typer.Option("--duration-s", help="Record after the step, s.")
    ] = 0.5,
    kp: Annotated[float | None, typer.Option("--kp", help="Try this proportional gain.")] = None,
    ki: Annotated[float | None, typer.Option("--ki", help="Try this integral gain.")] = None,
    kd: Annotated[float | None, typer.Option("--kd", help="Try this derivative gain.")] = None,
    machine: MachineOption = None,
    plot: Annotated[
        Path | None, typer.Option("--plot", help="PNG to write (default: tune-AXIS.png).")
    ] = None,
) -> None:
    """Step one axis and print rise time, overshoot, settling time and steady-state error.

    The step starts from where the axis stands (keep it inside its travel). --kp/--ki/--kd
    try gains without editing the configuration.
    """
    from usbmotion.host.config import PidGains, load_config  # noqa: PLC0415
    from usbmotion.host.machine import Machine  # noqa: PLC0415
    from usbmotion.tuning import step_response  # noqa: PLC0415

    try:
        config = load_config(machine or default_machine())
        axis_config = config.axis(axis.upper())
    except (ConfigError, KeyError) as error:
        typer.echo(f"usbmotion tune: {error}", err=True)
        raise typer.Exit(EXIT_BAD_INPUT) from None
    gains = axis_config.gains
    tried = PidGains(kp if kp is not None else gains.kp, ki if ki is not None else gains.ki,
                     kd if kd is not None else gains.kd)
    axes = tuple(dataclasses.replace(a, gains=tried) if a.name == axis_config.name else a
                 for a in config.axes)
    config = dataclasses.replace(config, axes=axes)
    try:
        with Machine.connect(config) as connected:
            connected.configure()
            response = step_response(connected, axis_config.name, step_mm=step_mm,
                                     duration_s=duration_s)
            connected.stop()
    except UsbMotionError as error:
        typer.echo(f"usbmotion tune: {error}", err=True)
        raise typer.Exit(EXIT_FAULT) from None
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
    from usbmotion.cli.plots import plot_step  # noqa: PLC0415

    target = plot or Path(f"tune-{axis_config.name}.png")
    plot_step(target, response)
    typer.echo(f"plot                  {target}")
