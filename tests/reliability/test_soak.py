"""Soak: a long program on the default 3-axis machine in virtual time.

``make test`` runs three minutes of program; ``make soak`` runs one hour
(``USBMOTION_SOAK_S=3600``). The program repeats squares, full circles and arcs at
1200 mm/min with a Z lift between laps, every axis moving. It starts where the carriages
power up (mid-travel), without homing: the soak is about the run, and the lap stays
inside the travel from there.

Time: every device takes one setpoint per servo tick from the synchronised start; a
queue that ran dry before the end would stretch the program (a host that fell behind).
Each device is watched: its queue must run dry exactly once, on the tick after the last
setpoint, so the executed time is the number of setpoints times the period, within one
servo tick of the planned time.

Memory: tracemalloc runs through the whole program, with snapshots of the traced memory
before the run and after it. The job keeps every diagnostics line for the report and the
plot (its ``Trace``), which grows with the program by design; its size is measured by
dropping it and taking a third snapshot. What is left, the growth of everything else
(devices, simulation, link, streams), must stay under ``LEAK_BOUND_BYTES`` however long the
program.

The devices send their diagnostics at least every ``SOAK_DIAGNOSTICS_S`` (0.1 s; the job
itself goes down to 10 ms for programs under 200 s and aims at 20,000 lines per axis for
longer ones, one every 0.18 s for an hour): tracing every allocation costs about 9x, and
the diagnostics lines are most of the host's work. Every other part runs at full rate.
``USBMOTION_SOAK_DIAGNOSTICS_S=0.01`` soaks at the job's own shortest period.
"""

from __future__ import annotations

import gc
import math
import os
import time
import tracemalloc
from collections.abc import Callable
from dataclasses import dataclass

import pytest

from usbmotion.cli.run import default_machine
from usbmotion.device import Device
from usbmotion.host.config import MachineConfig, load_config
from usbmotion.session import RunReport, plan_gcode
from usbmotion.session import watch as job
from usbmotion.sim.machine import connect_session

SOAK_ENV = "USBMOTION_SOAK_S"
"""Environment variable: seconds of program to soak (``make soak`` sets 3600)."""
DEFAULT_SOAK_S = 180.0
DIAGNOSTICS_ENV = "USBMOTION_SOAK_DIAGNOSTICS_S"
"""Environment variable: diagnostics period of the soak, seconds (default 0.1)."""
SOAK_DIAGNOSTICS_S = 0.1
LEAK_BOUND_BYTES = 1_000_000
"""Memory the run may leave behind besides the job's trace, however long the program."""
FOLLOWING_ERROR_BOUND_MM = 0.1
"""The bound ``tests/test_job.py`` states for the demo programs holds for the whole soak."""

LAP = (
    "G0 Z5\nG0 X30 Y30\nG1 Z2 F600\n"
    "G1 X90 Y30 F1200\nG1 X90 Y90\nG1 X30 Y90\nG1 X30 Y30\n"
    "G2 X30 Y30 I20 J0\nG3 X70 Y30 R20\nG2 X30 Y30 R20\n"
)
"""One lap, about 23 s: a 60 mm square, a full circle and two half circles, 10 mm or more
inside the travel (a carriage at the end of its travel closes the switch there)."""


def soak_seconds() -> float:
    """Seconds of program to soak, from ``USBMOTION_SOAK_S`` (default 180)."""
    return _seconds(SOAK_ENV, DEFAULT_SOAK_S)


def _seconds(variable: str, default: float) -> float:
    """A duration from an environment variable.

    Raises:
        ValueError: the variable is set but is not a number > 0.
    """
    text = os.environ.get(variable, "").strip()
    if not text:
        return default
    try:
        seconds = float(text)
    except ValueError:
        seconds = 0.0
    if not (math.isfinite(seconds) and seconds > 0):
        raise ValueError(f"{variable} {text!r} is not a number of seconds > 0")
    return seconds


def long_program(config: MachineConfig, seconds: float) -> str:
    """A program of laps that lasts at least ``seconds`` on ``config``'s machine."""
    one, two = (plan_gcode(config, f"G21 G90 G17\n{LAP * n}M2\n")[1].duration_s
                for n in (1, 2))
    lap_s = two - one
    laps = max(1, math.ceil((seconds - (one - lap_s)) / lap_s))
    return "G21 G90 G17\n" + LAP * laps + "G0 Z10\nG0 X5 Y5\nM2\n"


@dataclass
class Drains:
    """The device clock at every tick on which a device's motion queue ran dry."""

    ticks: list[int]


def _watch_drains(device: Device, drains: Drains) -> Callable[[int], None]:
    run = device.run

    def watched(ticks: int) -> None:
        before = device.state.queued
        run(ticks)
        if before > 0 and device.state.queued == 0:
            drains.ticks.append(device.clock)

    return watched


@dataclass(frozen=True)
class Soak:
    """The figures of one soak."""

    report: RunReport
    planned_s: float
    setpoints: int
    period_s: float
    start_tick: int
    drains: dict[str, list[int]]
    wall_s: float


def _soak(config: MachineConfig, text: str) -> tuple[Soak, object]:
    started = time.perf_counter()
    with connect_session(config) as session:
        machine = session.machine
        assert machine.world is not None
        drains: dict[str, Drains] = {}
        for name in machine.axes:
            device = machine.world.device(name)
            assert isinstance(device, Device)
            drains[name] = Drains([])
            device.run = _watch_drains(device, drains[name])  # type: ignore[method-assign]
        prepared = session.prepare("soak.ngc", text=text, unhomed=True)
        plan = prepared.plan
        report, trace = session.run(prepared)
    wall_s = time.perf_counter() - started
    soak = Soak(report, plan.duration_s, report.setpoints_per_axis, config.motion_period_s,
                trace.start_tick, {k: v.ticks for k, v in drains.items()}, wall_s)
    return soak, trace


def _traced() -> int:
    gc.collect()
    return tracemalloc.get_traced_memory()[0]


def test_a_long_program_keeps_time_and_memory(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(job, "DIAGNOSTICS_PERIOD_S", _seconds(DIAGNOSTICS_ENV,
                                                              SOAK_DIAGNOSTICS_S))
    config = load_config(default_machine())
    seconds = soak_seconds()
    text = long_program(config, seconds)
    _soak(config, long_program(config, 1.0))  # first-use caches are not a leak
    tracemalloc.start()
    try:
        before = _traced()
        soak, trace = _soak(config, text)
        with_trace = _traced()
        del trace
        after = _traced()
    finally:
        tracemalloc.stop()
    trace_bytes = with_trace - after
    leaked = after - before

    report = soak.report
    assert soak.planned_s >= seconds
    assert report.completed and report.faults == ()
    period_ticks = config.motion_scalar
    for name, ticks in soak.drains.items():
        assert len(ticks) == 1, f"{name}'s queue ran dry before the end (at {ticks})"
        executed_ticks = ticks[0] - 1 - soak.start_tick
        assert executed_ticks == (soak.setpoints - 1) * period_ticks, name
        executed_s = executed_ticks * config.servo_period_s
        assert 0 <= executed_s - soak.planned_s < config.servo_period_s, name
    for axis in report.axes:
        assert axis.max_error_mm < FOLLOWING_ERROR_BOUND_MM, axis
    assert leaked < LEAK_BOUND_BYTES, f"{leaked} bytes left besides the trace"
    late_s = (soak.drains["X"][0] - 1 - soak.start_tick) * config.servo_period_s - soak.planned_s
    print(
        f"soak: {soak.planned_s:.1f} s of program, diagnostics every"
        f" {job.trace_period_s(soak.planned_s) * 1e3:g} ms ({soak.setpoints} setpoints per axis) in"
        f" {soak.wall_s:.1f} s of wall time; executed - planned"
        f" {late_s * 1e3:+.2f} ms;"
        f" memory: trace {trace_bytes / 1e6:.1f} MB"
        f" ({trace_bytes / soak.planned_s / 1e3:.1f} kB per program second), everything else"
        f" {leaked / 1e3:+.1f} kB"
    )
