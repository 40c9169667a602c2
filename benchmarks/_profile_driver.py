"""Run one ``usbmotion`` command with every wall microsecond charged to a part of the job.

    python benchmarks/_profile_driver.py PARTS.json COMMAND ARGS...

(used by ``run_profile.py``). A part's time is its own: while a wrapped function of another
part runs inside it, the time is that part's. ``PARTS.json`` gets each part's seconds and
``_inside``, the wall seconds from this script's first line to its end.
"""

from __future__ import annotations

import time

STARTED = time.perf_counter()

import functools  # noqa: E402
import importlib  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
from collections.abc import Callable  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

_clock = time.perf_counter
_stack: list[str] = ["other"]
_since = [STARTED]
totals: dict[str, float] = {}


def _switch(part: str) -> None:
    now = _clock()
    top = _stack[-1]
    totals[top] = totals.get(top, 0.0) + now - _since[0]
    _since[0] = now
    _stack.append(part)


def _back() -> None:
    now = _clock()
    top = _stack.pop()
    totals[top] = totals.get(top, 0.0) + now - _since[0]
    _since[0] = now


def charged(part: str, function: Callable[..., Any]) -> Callable[..., Any]:
    """``function``, its time charged to ``part``."""

    @functools.wraps(function)
    def timed(*args: Any, **kwargs: Any) -> Any:
        _switch(part)
        try:
            return function(*args, **kwargs)
        finally:
            _back()

    return timed


def _patch(module_name: str, attribute: str, part: str) -> None:
    """Charge ``module.attribute`` (a function, or ``Class.method``) to ``part``, wherever a
    loaded usbmotion module holds it by name."""
    module = importlib.import_module(module_name)
    owner_name, _, name = attribute.rpartition(".")
    owner: Any = getattr(module, owner_name) if owner_name else module
    original = getattr(owner, name)
    wrapped = charged(part, original)
    setattr(owner, name, wrapped)
    if owner_name:
        return
    for loaded in list(sys.modules.values()):
        if getattr(loaded, "__name__", "").startswith("usbmotion") and loaded is not module:
            for key, value in list(vars(loaded).items()):
                if value is original:
                    setattr(loaded, key, wrapped)


WRAPPED = (
    ("usbmotion.cli.machines", "load_machine", "files"),
    ("usbmotion.motion.gcode", "read_gcode_text", "files"),
    ("usbmotion.motion.gcode", "parse_gcode", "interpretation"),
    ("usbmotion.motion.planner", "plan_moves", "planning"),
    ("usbmotion.motion.limits", "check_travel", "checks"),
    ("usbmotion.motion.plunges", "rapid_plunges", "checks"),
    ("usbmotion.motion.plunges", "plunge_warnings", "checks"),
    ("usbmotion.motion.sampler", "sample_plan", "sampling"),
    ("usbmotion.motion.sampler", "sample_count", "sampling"),
    ("usbmotion.protocol.codec", "encode_call", "host: formatting calls"),
    ("usbmotion.protocol.codec", "parse_reply", "host: parsing replies"),
    ("usbmotion.protocol.codec", "parse_diagnostics", "host: parsing replies"),
    ("usbmotion.protocol.codec", "parse_diagnostics_lines", "host: parsing replies"),
    ("usbmotion.protocol.codec", "parse_call", "core0: parsing calls"),
    ("usbmotion.device.core0", "Device.feed", "core0: calls and output"),
    ("usbmotion.device.core0", "Device.take_timed_output", "core0: calls and output"),
    ("usbmotion.device.core0", "Device.ticks_until_event", "core0: calls and output"),
    ("usbmotion.device.core0", "Device.run", "core0: around the kernel"),
    ("usbmotion.sim.world", "SimWorld.advance_to", "sim world"),
    ("usbmotion.sim.world", "SimWorld.wait_for", "sim world"),
    ("usbmotion.sim.world", "SimLink.write", "sim world"),
    ("usbmotion.sim.world", "SimLink.receive", "sim world"),
    ("usbmotion.session.live", "LiveModel.take_line", "host: live model"),
    ("usbmotion.session.live", "LiveModel.take_lines", "host: live model"),
    ("usbmotion.session.live", "LiveModel.take_status", "host: live model"),
    ("usbmotion.session.live", "LiveModel.publish", "host: live model"),
    ("usbmotion.session.session", "MachineSession.run", "host: run loop"),
    ("usbmotion.session.session", "MachineSession.home", "homing sequence"),
    ("usbmotion.session.report", "build_report", "report"),
    ("usbmotion.session.report_text", "describe", "report"),
    ("usbmotion.session.report", "RunReport.to_json", "report"),
    ("usbmotion.cli.plots", "plot_run", "plot"),
)
"""(module, function or Class.method, part): what each part is made of."""


def _install() -> None:
    """Load the modules the command uses (charged to imports), then wrap the functions."""
    import importlib._bootstrap as bootstrap  # noqa: PLC0415

    loading = bootstrap._find_and_load  # type: ignore[attr-defined]

    def find_and_load(*args: Any) -> Any:
        _switch("imports")
        try:
            return loading(*args)
        finally:
            _back()

    bootstrap._find_and_load = find_and_load  # type: ignore[attr-defined]
    for module_name, _, _ in WRAPPED:
        importlib.import_module(module_name)
    from usbmotion.device import core0, kernel  # noqa: PLC0415

    _switch("kernel load")
    compiled = kernel.block_function()  # the machine code loaded from its file (or made)
    _back()
    servo = charged("kernel", compiled)
    core0.block_function = lambda: servo
    for module_name, attribute, part in WRAPPED:
        _patch(module_name, attribute, part)


def main() -> None:
    out = Path(sys.argv[1])
    _install()
    from usbmotion.cli.main import main as command  # noqa: PLC0415

    status = 0
    sys.argv = ["usbmotion", *sys.argv[2:]]
    try:
        command()
    except SystemExit as end:
        status = end.code if isinstance(end.code, int) else 1
    now = _clock()
    totals[_stack[-1]] = totals.get(_stack[-1], 0.0) + now - _since[0]
    totals["_inside"] = now - STARTED
    out.write_text(json.dumps(totals), encoding="utf-8")
    sys.exit(status)


if __name__ == "__main__":
    main()
