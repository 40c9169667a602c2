"""Work offsets as LinuxCNC keeps them: coordinate systems, G92, stored positions, and the
parameter file that carries them from one run to the next.

A program position becomes a machine position as LinuxCNC's task makes it
(``emccanon.cc``)::

    machine = rotate_XY(program + G92 offset, R of the active system) + G5x offset + tool offset

:class:`WorkOffsets` is what persists (LinuxCNC's ``.var`` parameters, same numbers, in mm:
the machine's units); :class:`Frame` is the interpreter's working copy while a program is
read, with the tool offset, which does not persist.

Parameter numbers (each block is X Y Z A B C U V W, mm and degrees; the machine's own axes
among them are in effect, the others kept as read):

- 5161-5169 the G28 position, 5181-5189 the G30 position (machine coordinates);
- 5210 1 when the G92 offset is applied, 5211-5219 the G92 offset;
- 5220 the active coordinate system, 1 (G54) to 9 (G59.3);
- 5221-5229 the G54 offset and 5230 its XY rotation in degrees, then every 20 numbers the
  next system: 5241-5250 G55, ..., 5381-5390 G59.3.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field, replace
from pathlib import Path

from usbmotion.errors import ConfigError
from usbmotion.files import write_text_atomically
from usbmotion.motion.moves import AXIS_ORDER

__all__ = [
    "COORDINATE_SYSTEMS",
    "NO_OFFSETS",
    "Frame",
    "WorkOffsets",
    "format_parameter_file",
    "format_point",
    "g5x_parameter",
    "parse_parameter_file",
    "read_parameter_file",
    "write_parameter_file",
]

Point = tuple[float, ...]
"""One value per axis of :data:`~usbmotion.motion.moves.AXIS_ORDER` (X Y Z A B C U V W): mm,
degrees for A B C."""
_ZERO: Point = (0.0,) * len(AXIS_ORDER)
# where each axis sits in a parameter block of X Y Z A B C U V W (the same order)
_SLOTS = tuple("XYZABCUVW".index(letter) for letter in AXIS_ORDER)

COORDINATE_SYSTEMS = ("G54", "G55", "G56", "G57", "G58", "G59", "G59.1", "G59.2", "G59.3")
"""The coordinate systems by number 1-9 (index 0-8 here)."""

G28_PARAMETER = 5161
G30_PARAMETER = 5181
G92_ENABLED_PARAMETER = 5210
G92_PARAMETER = 5211
SYSTEM_PARAMETER = 5220
_G5X_BASE = 5221
_G5X_STRIDE = 20
_ROTATION = 9  # R follows the nine axes of a system's block


def g5x_parameter(system: int) -> int:
    """The parameter of the X offset of coordinate system ``system`` (1 = G54 .. 9 = G59.3)."""
    return _G5X_BASE + _G5X_STRIDE * (system - 1)


def _zero_systems() -> tuple[Point, ...]:
    return (_ZERO,) * len(COORDINATE_SYSTEMS)


@dataclass(frozen=True, slots=True)
class WorkOffsets:
    """The offsets and stored positions that persist across runs (mm, machine coordinates).

    Fields:
        g5x: the offset of each coordinate system, G54 first (index 0) to G59.3; every
            point here holds X Y Z A B C U V W (:data:`Point`), whatever axes a machine has.
        rotation_deg: each system's XY rotation about its origin (``G10 L2 R``), degrees.
        coordinate_system: the active system, 1 (G54) to 9 (G59.3).
        g92: the G92 offset, applied only while ``g92_enabled``.
        g92_enabled: whether the G92 offset applies (G92 and G92.3 set it; G92.1, G92.2
            and a program's end clear it).
        g28: the position G28 goes to; g30: the position G30 goes to.
        other: every other numbered parameter of the file, kept as read (numbers
            usbmotion does not use).

    Raises:
        ValueError: a point has not one value per axis of X Y Z A B C U V W, or not nine
            systems.
    """

    g5x: tuple[Point, ...] = field(default_factory=_zero_systems)
    rotation_deg: tuple[float, ...] = (0.0,) * len(COORDINATE_SYSTEMS)
    coordinate_system: int = 1
    g92: Point = _ZERO
    g92_enabled: bool = False
    g28: Point = _ZERO
    g30: Point = _ZERO
    other: tuple[tuple[int, float], ...] = ()

    def __post_init__(self) -> None:
        if len(self.g5x) != len(COORDINATE_SYSTEMS) or len(self.rotation_deg) != len(
                COORDINATE_SYSTEMS):
            raise ValueError(f"g5x and rotation_deg need {len(COORDINATE_SYSTEMS)} systems each")
        for name, point in (("g92", self.g92), ("g28", self.g28), ("g30", self.g30),
                            *(("g5x", p) for p in self.g5x)):
            if len(point) != len(AXIS_ORDER):
                raise ValueError(f"{name} {point!r} needs one value per axis of {AXIS_ORDER!r}")

    @property
    def origin_set(self) -> bool:
        """Whether any work offset moves a program off the machine's coordinates: a
        coordinate system's offset or rotation, or a G92 offset in force (all 0: a program's
        X0 Y0 Z0 is the machine's)."""
        return (any(any(point) for point in self.g5x) or any(self.rotation_deg)
                or (self.g92_enabled and any(self.g92)))

    def with_g5x(self, system: int, offset: Point) -> WorkOffsets:
        """These offsets with coordinate system ``system`` (1-9) at ``offset`` (mm, one
        value per axis of X Y Z A B C U V W)."""
        systems = list(self.g5x)
        systems[system - 1] = offset
        return replace(self, g5x=tuple(systems))

    def parameters(self) -> dict[int, float]:
        """Every parameter as LinuxCNC numbers it, in mm and degrees."""
        values = dict(self.other)
        for base, point in ((G28_PARAMETER, self.g28), (G30_PARAMETER, self.g30),
                            (G92_PARAMETER, self.g92)):
            for slot, value in zip(_SLOTS, point, strict=True):
                values[base + slot] = value
        values[G92_ENABLED_PARAMETER] = 1.0 if self.g92_enabled else 0.0
        values[SYSTEM_PARAMETER] = float(self.coordinate_system)
        for index, (offset, rotation) in enumerate(zip(self.g5x, self.rotation_deg,
                                                       strict=True)):
            base = g5x_parameter(index + 1)
            for slot, value in zip(_SLOTS, offset, strict=True):
                values[base + slot] = value
            values[base + _ROTATION] = rotation
        return values


NO_OFFSETS = WorkOffsets()
"""Every offset and stored position at 0, G54 active: LinuxCNC with no parameter file."""


def _known_numbers() -> frozenset[int]:
    numbers = {G92_ENABLED_PARAMETER, SYSTEM_PARAMETER}
    for base in (G28_PARAMETER, G30_PARAMETER, G92_PARAMETER):
        numbers.update(base + slot for slot in _SLOTS)
    for system in range(1, len(COORDINATE_SYSTEMS) + 1):
        base = g5x_parameter(system)
        numbers.update(base + slot for slot in _SLOTS)
        numbers.add(base + _ROTATION)
    return frozenset(numbers)


_KNOWN = _known_numbers()


def parse_parameter_file(text: str, *, path: str = "<string>") -> WorkOffsets:
    """Read LinuxCNC's parameter file format: one ``NUMBER VALUE`` pair a line.

    Blank lines are skipped; anything after the two fields is ignored, as LinuxCNC does.

    Raises:
        ConfigError: a line that is not two numbers, a parameter number outside 1..5602,
            a number given twice, a value that is not finite, a coordinate system that is
            not 1-9 or a G92 flag that is not 0 or 1 (names the file, the line and what is
            allowed).
    """
    values: dict[int, float] = {}
    lines: dict[int, int] = {}

    def fail(line: int, problem: str) -> ConfigError:
        return ConfigError(f"{path}:{line}: {problem}", path=path, key="parameters", line=line)

    for number, raw in enumerate(text.splitlines(), start=1):
        fields = raw.split()
        if not fields:
            continue
        if len(fields) < 2:
            raise fail(number, f"{raw.strip()!r} is not a parameter line; allowed: a parameter"
                       " number and its value, such as '5221 10.0'")
        try:
            parameter = int(fields[0])
        except ValueError:
            raise fail(number, f"parameter number {fields[0]!r} is not a whole number;"
                       " allowed: 1..5602") from None
        if not 1 <= parameter <= 5602:
            raise fail(number, f"parameter number {parameter} is out of range; allowed: 1..5602")
        try:
            value = float(fields[1])
        except ValueError:
            raise fail(number, f"parameter {parameter}: value {fields[1]!r} is not a number")\
                from None
        if not math.isfinite(value):
            raise fail(number, f"parameter {parameter}: value {fields[1]!r} is not finite")
        if parameter in values:
            raise fail(number, f"parameter {parameter} is given twice (also line"
                       f" {lines[parameter]}); allowed: once")
        values[parameter] = value
        lines[parameter] = number

    def point(base: int) -> Point:
        return tuple(values.get(base + slot, 0.0) for slot in _SLOTS)

    system = values.get(SYSTEM_PARAMETER, 1.0)
    if system not in (1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0):
        raise fail(lines[SYSTEM_PARAMETER], f"parameter {SYSTEM_PARAMETER} (the active"
                   f" coordinate system) is {system:g}; allowed: 1 (G54) to 9 (G59.3)")
    enabled = values.get(G92_ENABLED_PARAMETER, 0.0)
    if enabled not in (0.0, 1.0):
        raise fail(lines[G92_ENABLED_PARAMETER], f"parameter {G92_ENABLED_PARAMETER} (G92"
                   f" offset applied) is {enabled:g}; allowed: 0 or 1")
    systems = range(1, len(COORDINATE_SYSTEMS) + 1)
    return WorkOffsets(
        g5x=tuple(point(g5x_parameter(s)) for s in systems),
        rotation_deg=tuple(values.get(g5x_parameter(s) + _ROTATION, 0.0) for s in systems),
        coordinate_system=int(system),
        g92=point(G92_PARAMETER),
        g92_enabled=enabled == 1.0,
        g28=point(G28_PARAMETER),
        g30=point(G30_PARAMETER),
        other=tuple(sorted((n, v) for n, v in values.items() if n not in _KNOWN)),
    )


def read_parameter_file(path: str | os.PathLike[str]) -> WorkOffsets:
    """Read a parameter file; a file that does not exist holds every parameter at 0 (G54).

    Raises:
        ConfigError: the file cannot be read or is malformed (see
            :func:`parse_parameter_file`).
    """
    file = Path(path)
    try:
        text = file.read_text(encoding="utf-8")
    except FileNotFoundError:
        return WorkOffsets()
    except (OSError, UnicodeDecodeError) as error:
        raise ConfigError(f"{file}: cannot read the parameter file: {error}",
                          path=str(file), key="parameters") from error
    return parse_parameter_file(text, path=str(file))


def format_point(point: Point, axes: str, *, separator: str = "") -> str:
    """``X100.000 Y100.000 Z60.000``: the values of ``point`` (X Y Z A B C U V W) for ``axes``."""
    return " ".join(f"{letter}{separator}{point[AXIS_ORDER.index(letter)]:.3f}"
                    for letter in axes)


def format_parameter_file(offsets: WorkOffsets) -> str:
    """The parameter file's text: every parameter, in number order, tab-separated."""
    return "".join(f"{number}\t{value:.6f}\n"
                   for number, value in sorted(offsets.parameters().items()))


def write_parameter_file(path: str | os.PathLike[str], offsets: WorkOffsets) -> None:
    """Write a parameter file atomically: a reader finds the old file or the new one.

    Raises:
        OSError: the file cannot be written.
    """
    write_text_atomically(path, format_parameter_file(offsets))


class Frame:
    """The interpreter's offsets while a program is read, for a machine's axes (mm; mutable,
    one per program).

    Every list holds one value per axis of ``axes`` (a subsequence of X Y Z A B C U V W);
    :meth:`snapshot` writes them back over the offsets it was made from, so the values of
    axes the machine lacks are kept as read. ``translation`` is G5x + G92 + tool, the whole
    transform while the active system has no rotation (``rotated`` false), which is what
    the interpreter's fast path adds. A rotation turns X and Y; it is never in effect on a
    machine without both.

    With ``g92_volatile`` (grbl, Marlin) the G92 offset belongs to the controller alone: it
    starts cleared whatever ``offsets`` hold, and :meth:`snapshot` gives back their G92 as
    it was, so it is never written to a parameter file.
    """

    __slots__ = (
        "axes",
        "base",
        "g5x",
        "g28",
        "g30",
        "g92",
        "g92_enabled",
        "g92_volatile",
        "rotated",
        "rotation_deg",
        "system",
        "tool",
        "translation",
        "x",
        "y",
    )

    def __init__(self, offsets: WorkOffsets, axes: str = "XYZ", *,
                 g92_volatile: bool = False) -> None:
        self.base = offsets
        self.axes = axes
        self.g92_volatile = g92_volatile
        slots = [AXIS_ORDER.index(letter) for letter in axes]

        def mine(point: Point) -> list[float]:
            return [point[slot] for slot in slots]

        self.x, self.y = axes.find("X"), axes.find("Y")
        self.g5x = [mine(point) for point in offsets.g5x]
        self.rotation_deg = list(offsets.rotation_deg)
        self.system = offsets.coordinate_system - 1
        self.g92 = [0.0] * len(axes) if g92_volatile else mine(offsets.g92)
        self.g92_enabled = offsets.g92_enabled and not g92_volatile
        self.g28 = mine(offsets.g28)
        self.g30 = mine(offsets.g30)
        self.tool = [0.0] * len(axes)
        self.translation = [0.0] * len(axes)
        self.rotated = False
        self.update()

    @property
    def has_xy(self) -> bool:
        """The machine has both X and Y, the axes a rotation turns."""
        return self.x >= 0 and self.y >= 0

    def update(self) -> None:
        """Recompute ``translation`` and ``rotated`` after an offset changed."""
        g5x = self.g5x[self.system]
        g92 = self.active_g92()
        self.translation = [a + b + c for a, b, c in zip(g5x, g92, self.tool, strict=True)]
        self.rotated = self.rotation_deg[self.system] != 0.0 and self.has_xy

    def active_g92(self) -> list[float]:
        """The G92 offset as it applies now (zero while suspended)."""
        return self.g92 if self.g92_enabled else [0.0] * len(self.axes)

    def _rotation(self, index: int) -> float:
        return self.rotation_deg[index] if self.has_xy else 0.0

    def to_machine(self, program: list[float], *, system: int | None = None) -> list[float]:
        """The machine position of a program position (in the active system by default)."""
        index = self.system if system is None else system
        shifted = [p + g for p, g in zip(program, self.active_g92(), strict=True)]
        rotation = self._rotation(index)
        if rotation != 0.0:
            x, y = self.x, self.y
            shifted[x], shifted[y] = _rotate(shifted[x], shifted[y], rotation)
        return [s + o + t for s, o, t in zip(shifted, self.g5x[index], self.tool, strict=True)]

    def to_program(self, machine: list[float], *, system: int | None = None) -> list[float]:
        """The program position of a machine position (in the active system by default)."""
        index = self.system if system is None else system
        unshifted = [m - o - t for m, o, t in zip(machine, self.g5x[index], self.tool,
                                                 strict=True)]
        rotation = self._rotation(index)
        if rotation != 0.0:
            x, y = self.x, self.y
            unshifted[x], unshifted[y] = _rotate(unshifted[x], unshifted[y], -rotation)
        return [u - g for u, g in zip(unshifted, self.active_g92(), strict=True)]

    def rotate_vector(self, x: float, y: float) -> tuple[float, float]:
        """An XY displacement in the active system, as a machine displacement."""
        rotation = self._rotation(self.system)
        return _rotate(x, y, rotation) if rotation != 0.0 else (x, y)

    def set_g92(self, machine: list[float], values: dict[int, float]) -> None:
        """G92: the named axes (index -> mm) read ``values`` at the machine position."""
        unshifted = self.to_program(machine)
        current = self.active_g92()
        for axis in range(len(self.axes)):
            if axis in values:
                self.g92[axis] = unshifted[axis] + current[axis] - values[axis]
            else:
                self.g92[axis] = current[axis]
        self.g92_enabled = True
        self.update()

    def clear_g92(self) -> None:
        """G92.1: the G92 offset and its stored value to zero, not applied."""
        self.g92 = [0.0] * len(self.axes)
        self.g92_enabled = False
        self.update()

    def set_l20(self, system: int, machine: list[float], values: dict[int, float]) -> None:
        """G10 L20: system ``system`` (0-8) offset so that ``machine`` reads ``values`` there
        (named axes only; the others keep reading what they read)."""
        reading = self.to_program(machine, system=system)
        for axis, value in values.items():
            reading[axis] = value
        shifted = [r + g for r, g in zip(reading, self.active_g92(), strict=True)]
        rotation = self._rotation(system)
        if rotation != 0.0:
            x, y = self.x, self.y
            shifted[x], shifted[y] = _rotate(shifted[x], shifted[y], rotation)
        self.g5x[system] = [m - t - s for m, t, s in zip(machine, self.tool, shifted,
                                                         strict=True)]
        self.update()

    def snapshot(self) -> WorkOffsets:
        """The persistent part as it stands now (axes the machine lacks as read; a volatile
        G92 offset as it was read)."""
        axes = self.axes

        def full(point: Point, values: list[float]) -> Point:
            merged = list(point)
            for letter, value in zip(axes, values, strict=True):
                merged[AXIS_ORDER.index(letter)] = value
            return tuple(merged)

        base = self.base
        return replace(
            base,
            g5x=tuple(full(old, new) for old, new in zip(base.g5x, self.g5x, strict=True)),
            rotation_deg=tuple(self.rotation_deg),
            coordinate_system=self.system + 1,
            g92=base.g92 if self.g92_volatile else full(base.g92, self.g92),
            g92_enabled=base.g92_enabled if self.g92_volatile else self.g92_enabled,
            g28=full(base.g28, self.g28),
            g30=full(base.g30, self.g30),
        )


def _rotate(x: float, y: float, degrees: float) -> tuple[float, float]:
    theta = math.radians(degrees)
    cos, sin = math.cos(theta), math.sin(theta)
    return x * cos - y * sin, x * sin + y * cos
