"""``usbmotion run``: the main job. Home, run a G-code program, report, plot."""

from __future__ import annotations

import json
import signal
import sys
from collections.abc import Callable
from importlib import resources
from pathlib import Path
from types import FrameType
from typing import TYPE_CHECKING, Annotated

import typer

from usbmotion.errors import ConfigError, GCodeError, PlanningError, UsbMotionError

if TYPE_CHECKING:
    from usbmotion.host.machine import Machine
    from usbmotion.job import RunReport, Trace
    from usbmotion.motion.gcode import GCodeProgram
    from usbmotion.motion.planner import Plan

EXIT_FAULT = 1
EXIT_BAD_INPUT = 2


MachineOption = Annotated[
    Path | None,
    typer.Option("--machine", "-m", help="Machine configuration (default: the built-in"
                 " simulated XYZ machine)."),
]
"""The ``--machine`` option of the commands that drive a machine (``default_machine()``
when it is not given)."""


def default_machine() -> Path:
    """The built-in simulated 3-axis machine (the same file as ``examples/machine.toml``)."""
    return Path(str(resources.files("usbmotion") / "data" / "machine.toml"))


def run(
    program: Annotated[Path, typer.Argument(help="The G-code program.", show_default=False)],
    machine: MachineOption = None,
    plot: Annotated[
        Path | None, typer.Option("--plot", help="PNG to write (default: PROGRAM.png).")
    ] = None,
    no_plot: Annotated[bool, typer.Option("--no-plot", help="Write no plot.")] = False,
    report_path: Annotated[
        Path | None, typer.Option("--report", help="Write the report's figures as JSON here.")
    ] = None,
    realtime: Annotated[
        bool, typer.Option("--realtime", help="Pace the simulation by the wall clock.")
    ] = False,
    no_home: Annotated[bool, typer.Option("--no-home", help="Skip homing.")] = False,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No progress bar.")] = False,
) -> None:
    """Run a G-code program on the machine: home, plan, stream, then report and plot.

    Exit status 0 when the program ran to the end, 1 after a fault or Ctrl-C (every axis
    stopped; the report says where), 2 when the program or the configuration is invalid
    (nothing moved).
    """
    from usbmotion.host.config import load_config  # noqa: PLC0415 - keep --help fast
    from usbmotion.host.machine import Machine  # noqa: PLC0415
    from usbmotion.job import describe, plan_program, run_program  # noqa: PLC0415
    from usbmotion.motion.gcode import load_gcode  # noqa: PLC0415
    from usbmotion.sim.world import SimWorld  # noqa: PLC0415

    try:
        config = load_config(machine or default_machine())
        parsed = load_gcode(program)
        plan = plan_program(parsed, config)
    except GCodeError as error:
        typer.echo(f"{error.file}:{error.line}: {error.message}", err=True)
        raise typer.Exit(EXIT_BAD_INPUT) from None
    except (ConfigError, PlanningError) as error:
        typer.echo(f"usbmotion run: {error}", err=True)
        raise typer.Exit(EXIT_BAD_INPUT) from None
    except OSError as error:
        typer.echo(f"usbmotion run: cannot read {error.filename!r}: {error.strerror}", err=True)
        raise typer.Exit(EXIT_BAD_INPUT) from None

    interrupted = [False]

    def on_interrupt(signum: int, frame: FrameType | None) -> None:
        interrupted[0] = True

    previous = signal.signal(signal.SIGINT, on_interrupt)
    try:
        world = SimWorld(realtime=realtime) if config.is_simulated else None
        with Machine.connect(config, world=world) as connected:
            if quiet:
                report, trace = run_program(connected, parsed, plan, home=not no_home,
                                            should_stop=lambda: interrupted[0])
            else:
                report, trace = _with_progress(connected, parsed, plan, not no_home,
                                               lambda: interrupted[0])
    except UsbMotionError as error:
        typer.echo(f"usbmotion run: {error}", err=True)
        raise typer.Exit(EXIT_FAULT) from None
    finally:
        signal.signal(signal.SIGINT, previous)
    typer.echo(describe(report))
    if report_path is not None:
        report_path.write_text(json.dumps(report.to_json(), indent=2) + "\n", encoding="utf-8")
        typer.echo(f"report         {report_path}")
    if not no_plot:
        from usbmotion.cli.plots import plot_run  # noqa: PLC0415

        target = plot or program.with_suffix(".png")
        plot_run(target, plan, trace, report)
        typer.echo(f"plot           {target}")
    sys.stdout.flush()
    if not report.completed:
        raise typer.Exit(EXIT_FAULT)


def _with_progress(
    machine: Machine, program: GCodeProgram, plan: Plan, home: bool,
    should_stop: Callable[[], bool],
) -> tuple[RunReport, Trace]:
    from rich.progress import (  # noqa: PLC0415
        BarColumn,
        Progress,
        TextColumn,
        TimeRemainingColumn,
    )

    from usbmotion.job import run_program  # noqa: PLC0415

    columns = (TextColumn("[bold]{task.description}"), BarColumn(),
               TextColumn("{task.completed:.2f}/{task.total:.2f} s program time"),
               TimeRemainingColumn())
    with Progress(*columns, transient=True, disable=not sys.stderr.isatty()) as progress:
        task = progress.add_task("running", total=plan.duration_s)

        def update(done_s: float, total_s: float) -> None:
            progress.update(task, completed=done_s)

        return run_program(machine, program, plan, home=home, on_progress=update,
                           should_stop=should_stop)
