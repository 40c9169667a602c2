"""Measuring a tool on the machine's tool-length setter (``[tool_setter]``).

grblHAL's and LinuxCNC's way: the tool in the spindle is lowered onto a fixed probe button
and the height where it touches, against where the reference tool touches (the gauge line
the tool table's lengths count from), is its length. :func:`measure_tool` lifts Z to the
top of its travel (where homing leaves it), goes over the button, descends at rapid speed
to ``start_z_mm``, probes down at ``feed_mm_min`` (G38.2: the contact latched by the
devices, exact to the count), lifts Z again and writes the length into the machine's tool
table (LinuxCNC's ``tool.tbl``), where the next ``G43`` reads it. The console's ``$tls``,
the grbl front's ``$TLS`` and the dashboard's ``POST /api/tool/measure`` call it.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

from usbmotion.errors import ConfigError, MachineStateError
from usbmotion.host.config import MachineConfig, ToolSetterConfig
from usbmotion.motion.tools import with_tool_length
from usbmotion.session.homing import home_position_mm
from usbmotion.session.probing import MODES, ProbeMode, ProbeResult
from usbmotion.session.state import MachineState


class Moves(Protocol):
    """What measuring needs of a machine session: its configuration, its state, a jog and
    a probing move (:class:`~usbmotion.session.MachineSession`'s)."""

    config: MachineConfig

    @property
    def state(self) -> MachineState: ...

    def jog(self, moves: Mapping[str, float], *, feed_mm_min: float,
            absolute: bool = False) -> object: ...

    def probe(self, target_mm: Mapping[str, float], *, feed_mm_min: float,
              mode: ProbeMode) -> ProbeResult: ...


@dataclass(frozen=True, slots=True)
class ToolMeasurement:
    """A tool measured on the setter.

    Fields:
        tool: the tool number.
        contact_z_mm: machine Z where it touched the button (the devices' latched count).
        length_mm: its length, ``contact - reference_z_mm`` (None: the machine file has no
            ``reference_z_mm`` yet; this contact is then the one to write there).
        table: the tool table it was written to ("" when not written).
    """

    tool: int
    contact_z_mm: float
    length_mm: float | None
    table: str

    def describe(self) -> str:
        """One line for an operator."""
        if self.length_mm is None:
            return (f"T{self.tool} touched the setter at machine Z {self.contact_z_mm:.4f} mm;"
                    " no tool_setter.reference_z_mm in the machine file: write this contact"
                    f" there to make T{self.tool} the reference (length 0)")
        return (f"T{self.tool} touched the setter at machine Z {self.contact_z_mm:.4f} mm:"
                f" length {self.length_mm:.4f} mm"
                + (f", written to {self.table}" if self.table else ""))


@dataclass(frozen=True, slots=True)
class MeasureAtChange:
    """A measurement asked at a program's ``M6`` pause (grblHAL's semi-automatic tool
    change): the run ends there, at rest; tool ``tool``, put in the spindle at ``line``, is
    measured on the setter, and the program goes on from the line after (``from_line``),
    interpreted again so that its ``G43`` reads the new length."""

    tool: int
    line: int

    @property
    def from_line(self) -> int:
        """The line the program goes on from."""
        return self.line + 1


def setter_of(config: MachineConfig) -> ToolSetterConfig:
    """The machine's ``[tool_setter]``.

    Raises:
        ConfigError: it has none.
    """
    if config.tool_setter is None:
        raise ConfigError(f"{config.path}: no [tool_setter] table: where the setter is"
                          " (position_mm, start_z_mm, lowest_z_mm) is needed to measure a tool",
                          path=str(config.path), key="tool_setter")
    return config.tool_setter


def measure_tool(session: Moves, tool: int, *, write: bool = True) -> ToolMeasurement:
    """Measure tool ``tool`` (in the spindle now) on the setter; its length written to the
    tool table (see the module docstring), unless ``write`` is false (grbl's way: the
    length is applied as ``G43.1``, and the tool's number may be 0, none).

    Raises:
        ConfigError: no ``[tool_setter]``, or a length to write and no ``tool_table``.
        MachineStateError: a tool number below 1; as :meth:`MachineSession.jog`.
        ProbeFailedError: the tool did not touch by ``lowest_z_mm``, or the probe already
            touched.
    """
    config = session.config
    setter = setter_of(config)
    if tool < (1 if write else 0):
        raise MachineStateError(f"no tool to measure (T{tool}): put one in the spindle (M6 T1,"
                                " M61 Q1) or name it: $tls 1", state=session.state.value)
    if write and setter.reference_z_mm is not None and config.tool_table is None:
        raise ConfigError(f"{config.path}: no tool_table to write T{tool}'s length into;"
                          " allowed: tool_table = \"tool.tbl\" (LinuxCNC's format)",
                          path=str(config.path), key="tool_table")
    z_axis = config.axis("Z")
    top = home_position_mm(z_axis)
    rapid = {name: config.axis(name).max_velocity_mm_s * 60.0 for name in "XYZ"}
    session.jog({"Z": top}, feed_mm_min=rapid["Z"], absolute=True)
    x, y = setter.position_mm
    session.jog({"X": x, "Y": y}, feed_mm_min=min(rapid["X"], rapid["Y"]), absolute=True)
    session.jog({"Z": setter.start_z_mm}, feed_mm_min=rapid["Z"], absolute=True)
    try:
        found = session.probe({"Z": setter.lowest_z_mm}, feed_mm_min=setter.feed_mm_min,
                              mode=MODES["2"])
    finally:
        session.jog({"Z": top}, feed_mm_min=rapid["Z"], absolute=True)
    contact = found.position_mm["Z"]
    if setter.reference_z_mm is None:
        return ToolMeasurement(tool, contact, None, "")
    length = contact - setter.reference_z_mm
    table = config.tool_table
    if not write:
        return ToolMeasurement(tool, contact, length, "")
    assert table is not None
    path = Path(table)
    text = path.read_text(encoding="utf-8") if path.exists() else ""
    path.write_text(with_tool_length(text, tool, length, comment="measured on the tool setter"),
                    encoding="utf-8")
    return ToolMeasurement(tool, contact, length, str(path))
