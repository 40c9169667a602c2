"""``usbmotion run``: the main job. Home, run a G-code program, report, plot."""

from __future__ import annotations

import gc
import json
import math
import re
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from usbmotion.cli.connect import connect_any
from usbmotion.cli.exits import (
    EXIT_BAD_INPUT,
    EXIT_COMPLETED,
    EXIT_FAULT,
    EXIT_INTERRUPTED,
    EXIT_TERMINATED,
    exit_code,
)
from usbmotion.cli.machines import MachineOption, default_machine, load_machine
from usbmotion.cli.signals import stop_on_signals
from usbmotion.errors import (
    ArgumentError,
    ConfigError,
    GCodeError,
    PlanningError,
    SequenceFaultError,
    SoftLimitError,
    StopRequestedError,
    UsbMotionError,
)

if TYPE_CHECKING:
    from usbmotion.host.config import MachineConfig
    from usbmotion.motion.dialects import Dialect
    from usbmotion.motion.gcode import Pause
    from usbmotion.session import MachineSession, Prepared, RunReport, Trace
    from usbmotion.session.live import LiveSnapshot
    from usbmotion.sim.predict import Prediction

__all__ = ["EXIT_BAD_INPUT", "EXIT_COMPLETED", "EXIT_FAULT", "EXIT_INTERRUPTED",
           "EXIT_TERMINATED", "NO_ORIGIN_HINT", "MachineOption", "default_machine", "exit_code",
           "load_machine", "parse_origin", "run", "stop_on_signals"]


NO_ORIGIN_HINT = (
    "hint: no work origin is set (every work offset of the machine's parameter file is 0), so"
    " the program's X0 Y0 Z0 is the machine's own; set the origin where the program's zero is"
    " on the stock first: --origin 'X.. Y.. Z..' in machine mm, or jog there and"
    " `usbmotion zero`")
"""What a program refused for leaving the travel is told when no work origin is set (a CAM
program's zero is usually the stock's top corner, the machine's is where it homes)."""

_ORIGIN_WORD = re.compile(r"\s*([XYZUVWxyzuvw])\s*([-+]?(?:[0-9]+\.?[0-9]*|\.[0-9]+))\s*")


def parse_origin(values: list[str]) -> dict[str, float]:
    """``["X100 Y100", "Z-40"]`` -> ``{"X": 100.0, "Y": 100.0, "Z": -40.0}`` (mm).

    Raises:
        typer.BadParameter: a word that is not an axis letter (X Y Z U V W) and a number,
            or an axis twice. (Whether the machine has the axis is the session's to check.)
    """
    origin: dict[str, float] = {}
    for value in values:
        position = 0
        for match in _ORIGIN_WORD.finditer(value):
            if match.start() != position:
                break
            letter = match.group(1).upper()
            if letter in origin:
                raise typer.BadParameter(f"{letter} is given twice in {value!r}; allowed: each"
                                         " axis once", param_hint="--origin")
            origin[letter] = float(match.group(2))
            position = match.end()
        if position != len(value) or not value.strip():
            raise typer.BadParameter(
                f"{value!r} is not an origin; allowed: axis words in machine mm, such as"
                " 'X100 Y100 Z-40'", param_hint="--origin")
    if any(not math.isfinite(v) for v in origin.values()):
        raise typer.BadParameter("origin values must be finite", param_hint="--origin")
    return origin


def run(
    program: Annotated[Path, typer.Argument(help="The G-code program.", show_default=False)],
    machine: MachineOption = None,
    plot: Annotated[
        Path | None, typer.Option("--plot", help="PNG to write (default: the program's name"
                                  " with .png, in the working directory).")
    ] = None,
    no_plot: Annotated[bool, typer.Option("--no-plot", help="Write no plot.")] = False,
    report_path: Annotated[
        Path | None, typer.Option("--report", help="Write the report's figures as JSON here.")
    ] = None,
    realtime: Annotated[
        bool, typer.Option("--realtime", help="Pace the simulation by the wall clock.")
    ] = False,
    no_home: Annotated[bool, typer.Option(
        "--no-home", help="Do not home a machine that is not homed: run in the devices' own"
        " counts, without soft limits.")] = False,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No progress bar.")] = False,
    dialect: Annotated[str | None, typer.Option(
        "--dialect", help="Read the program as linuxcnc, grbl or marlin reads it (default:"
        " the machine file's dialect, linuxcnc when it names none).")] = None,
    origin: Annotated[list[str] | None, typer.Option(
        "--origin", help="Set the work origin (G54) first, in machine mm: --origin 'X100 Y100"
        " Z-40' (or X100Y100Z-40, or repeated); kept in the machine's parameter file.")] = None,
    pause_on_m6: Annotated[bool, typer.Option(
        "--pause-on-m6", help="Someone is at the machine: pause at each tool change (M6 of"
        " another tool) and at M0, saying which tool and pocket, until Enter is pressed"
        " (standard input ending stops the run there).")] = False,
    from_line: Annotated[int | None, typer.Option(
        "--from-line", min=1, help="Run from this line (after a stop, a fault or a broken"
        " tool: the report of the stopped run names it): the lines before it set the modes,"
        " offsets and tool without moving, then Z goes up to where homing leaves it, over"
        " the line's start, and down at the program's feed.")] = None,
    predict: Annotated[bool, typer.Option(
        "--predict", help="Before anything moves, play the program on every axis's"
        " identified model (its model table, written by usbmotion tune --auto --write; a"
        " simulated axis's sim table) and print the predicted following error; after the"
        " run, predicted beside measured, per axis and per line.")] = False,
    predict_only: Annotated[bool, typer.Option(
        "--predict-only", help="Print the prediction and stop: nothing connects to the"
        " machine.")] = False,
    tolerance: Annotated[float | None, typer.Option(
        "--tolerance", help="With --predict or --predict-only (implies --predict): name the"
        " lines whose predicted peak following error exceeds this many mm (deg on a rotary"
        " axis); any such line refuses the run (exit 2, nothing moved).")] = None,
) -> None:
    """Run a G-code program: home if needed, plan from where the machine stands, stream, report.

    Before streaming, the program is checked against every axis's travel; at the end
    the report is printed and the commanded and actual paths plotted.

    The program starts from where the machine is (after homing: each axis's
    home position), never from 0, and a program that leaves an axis's travel
    is refused before anything moves. At the end, or on Ctrl-C or SIGTERM,
    every axis comes to rest along its deceleration and the servos are
    disabled, so the next run finds the machine homed.

    Exit status: 0 the program ran to its end; 1 a device fault, a lost link
    or a failed homing (every axis stopped; the report says where); 2 the
    program or the machine file is invalid or leaves the travel (nothing
    moved); 130 interrupted by Ctrl-C, 143 by SIGTERM (every axis brought to
    rest along its deceleration, then the servos disabled; a second Ctrl-C
    stops at once).

    The program runs in the work offsets of the machine's parameter file (set by
    --origin, usbmotion zero, or a program's G10), with the tool table the machine
    file names. Every tool change (M6, M61) is in the report with its tool and its
    pocket; without --pause-on-m6 the run does not stop for them (change the tool
    by hand before the run, or let the program's own length offsets apply).
    """
    from usbmotion.motion.dialects import dialect_named  # noqa: PLC0415
    from usbmotion.motion.gcode import read_gcode_text  # noqa: PLC0415
    from usbmotion.motion.offsets import format_point  # noqa: PLC0415
    from usbmotion.session.planning import machine_axes  # noqa: PLC0415

    chosen: Dialect | None = None
    if dialect is not None:
        try:
            chosen = dialect_named(dialect)
        except ValueError as error:
            typer.echo(f"usbmotion run: --dialect: {error}", err=True)
            raise typer.Exit(EXIT_BAD_INPUT) from None
    if plot is not None and no_plot:
        typer.echo(f"usbmotion run: --plot {plot} and --no-plot: give one or the other",
                   err=True)
        raise typer.Exit(EXIT_BAD_INPUT)
    origin_mm = parse_origin(origin or [])
    if tolerance is not None and not (math.isfinite(tolerance) and tolerance > 0):
        typer.echo(f"usbmotion run: --tolerance: {tolerance!r} is not a following error;"
                   " allowed: mm above 0, such as 0.05", err=True)
        raise typer.Exit(EXIT_BAD_INPUT)
    predicting = predict or predict_only or tolerance is not None
    try:
        config = load_machine(machine)
        text = read_gcode_text(program)
        if origin_mm:  # a program refused leaves the parameter file as it was
            _check_program(config, program, text, chosen)
    except GCodeError as error:
        _unread(error, text, config, chosen)
        raise typer.Exit(EXIT_BAD_INPUT) from None
    except ConfigError as error:
        typer.echo(f"usbmotion run: {error}", err=True)
        raise typer.Exit(EXIT_BAD_INPUT) from None
    except OSError as error:
        typer.echo(f"usbmotion run: cannot read {error.filename!r}: {error.strerror}", err=True)
        raise typer.Exit(EXIT_BAD_INPUT) from None

    if predict_only:
        if origin_mm:
            typer.echo("usbmotion run: --origin with --predict-only: nothing connects to the"
                       " machine, so no origin is set; set it first (usbmotion zero, or"
                       " --origin with --predict)", err=True)
            raise typer.Exit(EXIT_BAD_INPUT)
        _predict(config, program, text, chosen, from_line=from_line, standing_mm=None,
                 tolerance_mm=tolerance)
        return
    try:
        with _startup_kept():
            session = connect_any(config, realtime=realtime)
            if config.is_simulated:  # it will move: the kernel loaded now, and kept
                from usbmotion.device.kernel import preload  # noqa: PLC0415

                preload()
    except UsbMotionError as error:
        typer.echo(f"usbmotion run: {error}", err=True)
        raise typer.Exit(EXIT_FAULT) from None
    predicted: Prediction | None = None
    with session, stop_on_signals(session):
        for notice in session.notices:
            typer.echo(f"notice         {notice}", err=True)
        if origin_mm:
            offsets = session.set_work_origin(origin_mm)
            shown = format_point(offsets.g5x[0], machine_axes(config).axes)
            typer.echo(f"work origin    G54 {shown} mm (machine), saved in"
                       f" {config.parameter_path}", err=True)
        if predicting:
            standing = session.positions_mm() if session.is_homed else None
            predicted = _predict(config, program, text, chosen, from_line=from_line,
                                 standing_mm=standing, tolerance_mm=tolerance)
        with resumed_from_stdin(session, enabled=pause_on_m6):
            code, report, trace, prepared = _job(session, program, text, no_home=no_home,
                                                  quiet=quiet, dialect=chosen,
                                                  pauses=pause_on_m6, from_line=from_line)
        try:
            session.shutdown()
        except UsbMotionError as error:
            typer.echo(f"usbmotion run: {error}", err=True)
            code = max(code, EXIT_FAULT) if code == EXIT_COMPLETED else code
    if report is not None:
        _write(report, trace, prepared, program, report_path=report_path, plot=plot,
               no_plot=no_plot, predicted=predicted, config=config)
    sys.stdout.flush()
    if code != EXIT_COMPLETED:
        raise typer.Exit(code)


def _check_program(config: MachineConfig, program: Path, text: str,
                   dialect: Dialect | None) -> None:
    """Interpret the program once before anything is changed (``--origin`` saves the
    origin first). The run interprets it again from where the machine will stand.

    Raises:
        GCodeError: the program does not parse; ConfigError: the tool table or the
            parameter file is malformed.
    """
    from usbmotion.motion.gcode import parse_gcode  # noqa: PLC0415
    from usbmotion.motion.offsets import read_parameter_file  # noqa: PLC0415
    from usbmotion.motion.tools import NO_TOOLS, load_tool_table  # noqa: PLC0415
    from usbmotion.session.planning import machine_axes, machine_dialect  # noqa: PLC0415

    parse_gcode(text, file=str(program), machine=machine_axes(config),
                dialect=machine_dialect(config, dialect),
                tools=load_tool_table(config.tool_table) if config.tool_table else NO_TOOLS,
                offsets=read_parameter_file(config.parameter_path))


@contextmanager
def _startup_kept() -> Iterator[None]:
    """The garbage collector paused while the command connects (and loads a simulated
    machine's servo kernel), and everything made so far frozen out of its collections then:
    the modules, numba and the kernel live as long as the process, and two full collections
    of numba's objects took 0.1 s of a run."""
    gc.disable()
    try:
        yield
    finally:
        gc.freeze()
        gc.enable()


@contextmanager
def resumed_from_stdin(session: MachineSession, *, enabled: bool) -> Iterator[None]:
    """While inside (when ``enabled``): a program pause is announced on standard error and
    a line on standard input resumes it; standard input ending at a pause stops the run."""
    if not enabled:
        yield
        return
    import threading  # noqa: PLC0415

    from usbmotion.session import StopReason  # noqa: PLC0415

    def announce(pause: Pause) -> None:
        typer.echo(f"paused         line {pause.line} ({pause.code}): {pause.message};"
                   " press Enter to go on", err=True)

    ended = threading.Event()

    def at_pause() -> bool:
        """Wait until the run pauses (True) or ends (False)."""
        while session.paused is None:
            if ended.wait(0.02):
                return False
        return True

    def read() -> None:
        for _ in sys.stdin:  # each line resumes one pause, however early it was typed
            if not at_pause():
                return
            pause = session.paused
            session.request_resume()
            while session.paused is pause and not ended.wait(0.02):
                pass
        if at_pause():
            session.request_stop(f"{StopReason.USER.value}: standard input ended at a pause")

    session.on_pause = announce
    threading.Thread(target=read, name="usbmotion-run-resume", daemon=True).start()
    try:
        yield
    finally:
        ended.set()
        session.on_pause = None


def _job(session: MachineSession, program: Path, text: str, *, no_home: bool,
         quiet: bool, dialect: Dialect | None = None, pauses: bool = False,
         from_line: int | None = None,
         ) -> tuple[int, RunReport | None, Trace | None, Prepared | None]:
    """Prepare, home if needed, run: (exit status, report, trace, the prepared program).
    ``pauses``: M0 and tool changes pause the run (someone is there to resume it)."""
    from usbmotion.motion.gcode import Pauses  # noqa: PLC0415

    rule = Pauses.PROGRAM if pauses else Pauses.NONE
    from usbmotion.motion.sampler import sample_count  # noqa: PLC0415
    from usbmotion.session import StopReason  # noqa: PLC0415
    from usbmotion.session.report import unstarted_report  # noqa: PLC0415

    homing_s = 0.0
    try:
        prepared = session.prepare(program, text=text, unhomed=no_home, dialect=dialect,
                                   pauses=rule, from_line=from_line)
    except SoftLimitError as error:
        _refused(program, error, session.config)
        return EXIT_BAD_INPUT, None, None, None
    except GCodeError as error:
        _unread(error, text, session.config, dialect)
        return EXIT_BAD_INPUT, None, None, None
    except (ConfigError, PlanningError, ArgumentError) as error:
        typer.echo(f"usbmotion run: {error}", err=True)
        return EXIT_BAD_INPUT, None, None, None
    config = session.config

    def unstarted(reason: str, code: int) -> tuple[int, RunReport, None, Prepared]:
        try:
            where = session.positions_mm()
        except UsbMotionError:
            where = {}
        return code, unstarted_report(
            prepared.program, config.name, prepared.plan,
            setpoints_per_axis=sample_count(prepared.plan, config.motion_period_s),
            homing_s=homing_s, stop_reason=reason, end_position_mm=where,
            stop_latency_s=session.stop_latency_s, notes=tuple(session.notices)), None, prepared

    try:
        if not (no_home or session.is_homed):
            homing_s = _home_with_progress(session, quiet=quiet)
            if session.start_position_mm() != (prepared.start_mm, prepared.homed):
                prepared = session.prepare(program, text=text, dialect=dialect, pauses=rule,
                                           from_line=from_line)
    except StopRequestedError as error:
        reason = f"{error.reason} (while homing)"
        return unstarted(reason, exit_code(error.reason))
    except SequenceFaultError as error:
        typer.echo(f"usbmotion run: homing failed: {error}", err=True)
        return unstarted(f"fault: homing failed: {error}", EXIT_FAULT)
    except SoftLimitError as error:
        _refused(program, error, config)
        return EXIT_BAD_INPUT, None, None, None
    except UsbMotionError as error:
        typer.echo(f"usbmotion run: {error}", err=True)
        return unstarted(f"fault: {error}", EXIT_FAULT)
    for warning in prepared.warnings:
        typer.echo(f"warning        {warning}", err=True)
    if session.stop_requested:
        return unstarted(f"{session.stop_requested} (before the program started)",
                         exit_code(session.stop_requested))
    try:
        if quiet:
            report, trace = session.run(prepared, homing_s=homing_s)
        else:
            report, trace = _with_progress(session, prepared, homing_s)
    except UsbMotionError as error:
        typer.echo(f"usbmotion run: {error}", err=True)
        return unstarted(f"fault: {error}", EXIT_FAULT)
    code = EXIT_COMPLETED if report.completed else exit_code(report.stop_reason)
    if code == EXIT_COMPLETED and report.stop_reason != StopReason.COMPLETED.value:
        code = EXIT_FAULT
    return code, report, trace, prepared


def _unread(error: GCodeError, text: str, config: MachineConfig,
            dialect: Dialect | None) -> None:
    """``FILE:LINE: what`` for a program that does not read; when its own comments name
    another dialect than the one it was read in, how to read it in that one."""
    typer.echo(f"{error.file}:{error.line}: {error.message}", err=True)
    from usbmotion.cli.gcode import dialect_hint  # noqa: PLC0415
    from usbmotion.session.planning import machine_dialect  # noqa: PLC0415

    try:
        reading = machine_dialect(config, dialect)
    except ValueError:
        return
    hint = dialect_hint(text, reading)
    if hint is not None:
        typer.echo(hint, err=True)


def _refused(program: Path, error: SoftLimitError, config: MachineConfig) -> None:
    """``FILE:LINE: what`` for a program that leaves the travel; when no work origin is set
    (a program's zero is then the machine's), how to set one."""
    message = str(error).removeprefix(f"line {error.line}: ")
    typer.echo(f"{program}:{error.line}: {message}", err=True)
    from usbmotion.motion.offsets import read_parameter_file  # noqa: PLC0415

    try:
        offsets = read_parameter_file(config.parameter_path)
    except ConfigError:
        return
    if not offsets.origin_set:
        typer.echo(NO_ORIGIN_HINT, err=True)


def _predict(config: MachineConfig, program: Path, text: str, dialect: Dialect | None, *,
             from_line: int | None, standing_mm: dict[str, float] | None,
             tolerance_mm: float | None) -> Prediction:
    """Play the program on the axes' models and print the prediction; exits 2 when it
    cannot be made or a line is predicted beyond ``tolerance_mm``."""
    from usbmotion.session.report_text import describe_prediction, lines_over  # noqa: PLC0415
    from usbmotion.sim.predict import predict  # noqa: PLC0415

    try:
        predicted = predict(config, program, text, dialect=dialect, from_line=from_line,
                            standing_mm=standing_mm)
    except SoftLimitError as error:
        _refused(program, error, config)
        raise typer.Exit(EXIT_BAD_INPUT) from None
    except GCodeError as error:
        _unread(error, text, config, dialect)
        raise typer.Exit(EXIT_BAD_INPUT) from None
    except (ConfigError, PlanningError, ArgumentError) as error:
        typer.echo(f"usbmotion run: --predict: {error}", err=True)
        raise typer.Exit(EXIT_BAD_INPUT) from None
    scales = {axis.name: axis.counts_per_mm for axis in config.axes}
    typer.echo(describe_prediction(predicted.report, predicted.motors, predicted.wall_s,
                                   scales=scales, tolerance_mm=tolerance_mm))
    sys.stdout.flush()
    if tolerance_mm is not None and lines_over(predicted.report, tolerance_mm, scales):
        typer.echo(f"usbmotion run: lines predicted beyond --tolerance {tolerance_mm:g}:"
                   " the run is refused, nothing moved (lower those lines' feed, or tune"
                   " the axes: usbmotion tune -a AXIS --auto)", err=True)
        raise typer.Exit(EXIT_BAD_INPUT)
    return predicted


def _write(report: RunReport, trace: Trace | None, prepared: Prepared | None, program: Path, *,
           report_path: Path | None, plot: Path | None, no_plot: bool,
           predicted: Prediction | None = None, config: MachineConfig | None = None) -> None:
    from usbmotion.session import describe  # noqa: PLC0415
    from usbmotion.session.report_text import describe_comparison  # noqa: PLC0415

    typer.echo(describe(report))
    data = report.to_json()
    if predicted is not None and config is not None:
        scales = {axis.name: axis.counts_per_mm for axis in config.axes}
        typer.echo(describe_comparison(predicted.report, report, scales=scales))
        forecast = predicted.report.to_json()
        data["prediction"] = {
            "motors": dict(predicted.motors), "wall_s": predicted.wall_s,
            "completed": forecast["completed"], "axes": forecast["axes"],
            "line_peaks": forecast["line_peaks"]}
    if report_path is not None:
        report_path.write_text(json.dumps(data, indent=2) + "\n", encoding="utf-8")
        typer.echo(f"report         {report_path}")
    if not no_plot and trace is not None and prepared is not None:
        from usbmotion.cli.plots import plot_run  # noqa: PLC0415

        # in the working directory: a program may sit where nothing should be written (a
        # demo inside the package, a read-only share)
        target = plot or Path(program.with_suffix(".png").name)
        plot_run(target, prepared.plan, trace, report)
        typer.echo(f"plot           {target}")


def _with_progress(session: MachineSession, prepared: Prepared,
                   homing_s: float) -> tuple[RunReport, Trace]:
    from rich.progress import (  # noqa: PLC0415
        BarColumn,
        Progress,
        TextColumn,
        TimeRemainingColumn,
    )

    columns = (TextColumn("{task.description}"), BarColumn(),
               TextColumn("{task.completed:.2f}/{task.total:.2f} s program time"),
               TimeRemainingColumn())
    with Progress(*columns, transient=True, disable=not sys.stderr.isatty()) as progress:
        task = progress.add_task("Run", total=prepared.plan.duration_s)

        def update(report: LiveSnapshot) -> None:
            progress.update(task, completed=report.done_s, description=report.describe())

        return session.run(prepared, on_progress=update, homing_s=homing_s)


def _home_with_progress(session: MachineSession, *, quiet: bool) -> float:
    """Home the machine, a progress line showing the state and the positions unless
    ``quiet``; returns the seconds."""
    from usbmotion.cli.progress import progress_line  # noqa: PLC0415

    with progress_line(not quiet) as show:
        return session.home(on_progress=show)

