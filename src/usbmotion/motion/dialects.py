"""G-code dialects: what a program written for LinuxCNC, grbl or Marlin means.

The interpreter (:mod:`usbmotion.motion.gcode`) reads RS274/NGC as LinuxCNC does; a
:class:`Dialect` says where another controller reads the same text differently, as data
the interpreter consults (:data:`RULES`):

- ``linuxcnc``, the default: LinuxCNC 2.9's interpreter, as the conformance cases check. A
  line holds what LinuxCNC's 255-byte line buffer takes.
- ``grbl``: grbl 1.1 as a laser or small mill runs it. The motion mode at power-on is G0
  (a line of axis words alone is a rapid), a program needs no M2/M30/``%``, and lines
  that start with ``$`` are controller commands: ``$H`` (and ``$HX``, ``$HY``, ... of one
  axis) homes, every other one is refused by name. ``G4 P`` is seconds, as LinuxCNC's.
  What grbl lacks is refused by name: canned cycles, ``G43`` from a tool table (grbl has
  ``G43.1``), ``G59.1``-``G59.3``, ``G92.2`` and ``G92.3``. A line keeps at most 79
  characters once grbl's pre-parser has dropped its comments and blanks. The G92 offset is
  grbl's alone (``gc_state``, cleared by a reset): never kept in the parameter file.
- ``marlin``: a 3D printer's file from a slicer. ``G4 P`` is milliseconds and ``G4 S``
  seconds; ``G28`` homes the axes it names (all of them when it names none) and, as
  Marlin's homing does, clears their G92 shift; ``E`` words (the extruder) and the
  temperature, fan, progress, motor and printer-setting M codes are accepted and reported
  as ignored with their meaning; a program needs no end; ``M117`` and ``M118`` carry a
  message to the end of the line. Codes that would change the geometry (bed levelling,
  firmware retraction's Z hop, its G30 probe) stay refused, and so do the codes Marlin
  lacks (canned cycles, tool length offsets, G28.1 and G30.1). A command keeps at most 95
  characters besides its comments (``MAX_CMD_SIZE``); its G92 shift is Marlin's alone.

In every dialect a program's end (M2, M30, a closing ``%``) suspends the G92 offset, and a
grbl or Marlin one (volatile: :attr:`DialectRules.g92_volatile`) is cleared there, at a
reset, and at the start of the next program.

Homing inside a program (grbl's ``$H``, Marlin's ``G28``) is, on a machine the run has
homed, a move at rapid to where homing leaves each axis, in the machine's homing order.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from enum import Enum

from usbmotion.motion.gcode_codes import GCode, MCode
from usbmotion.motion.gcode_lexer import LineLimit

__all__ = ["GRBL_COMMANDS", "RULES", "Declared", "Dialect", "DialectMCode", "DialectRules",
           "declared_dialect", "dialect_named"]

MARLIN_G11 = 110
"""Marlin's G11 (firmware recover), ten times its number: a code LinuxCNC has no name for."""
MARLIN_G29 = 290
"""Marlin's G29 (bed levelling), ten times its number."""


class Dialect(Enum):
    """The controller whose reading of G-code a program follows."""

    LINUXCNC = "linuxcnc"
    GRBL = "grbl"
    MARLIN = "marlin"


@dataclass(frozen=True, slots=True)
class DialectMCode:
    """An M code a dialect accepts and ignores: what it is for, and the letters on its line
    that are its parameters (not axis words: ``M201 X500`` sets an acceleration)."""

    meaning: str
    parameters: str = ""


@dataclass(frozen=True, slots=True)
class DialectRules:
    """How a dialect reads G-code where it differs from LinuxCNC.

    Fields:
        dialect: which one.
        start_motion: the motion mode at power-on (``GCode.G_0``), or -1 for none (an axis
            word needs a G0-G3 first).
        needs_end: a program must end with M2, M30 or ``%``.
        line_limit: whose line length applies.
        g92_volatile: the G92 offset is the controller's alone: a program starts without
            one whatever the parameter file holds, its end and a reset clear it, and it is
            never written back (the parameter file keeps what it held).
        homing_clears_g92: homing (``g28_homes``) clears the G92 offset of the axes homed.
        reset_modes: a reset takes the modal state back to power-on (grbl's ``gc_init``,
            Marlin's restart); without it a reset keeps the modal state (LinuxCNC's abort).
        controller_commands: lines starting with ``$`` are controller commands.
        message_codes: M codes whose text runs to the end of the line (Marlin's M117).
        flags: a letter with no number is a word of value 0 (Marlin's ``G28 X Y``).
        dwell_p_seconds: seconds per unit of ``G4 P``.
        dwell_s: ``G4 S`` is a dwell in seconds.
        g28_homes: ``G28`` homes the named axes instead of going to the stored position.
        m_codes: M codes the dialect adds or means differently (code -> meaning and the
            letters that are its parameters).
        m_removed: LinuxCNC's M codes the dialect does not have.
        g_refused: G codes refused with the dialect's own reason (code x10 -> reason).
        letters: letters ignored with this meaning instead of refused (Marlin's ``E``).
        letter_meanings: what an ignored letter is for in this dialect, when it differs.
    """

    dialect: Dialect
    start_motion: int = -1
    needs_end: bool = True
    line_limit: LineLimit = LineLimit.LINUXCNC
    g92_volatile: bool = False
    homing_clears_g92: bool = False
    reset_modes: bool = False
    controller_commands: bool = False
    message_codes: frozenset[int] = frozenset()
    flags: bool = False
    dwell_p_seconds: float = 1.0
    dwell_s: bool = False
    g28_homes: bool = False
    m_codes: dict[int, DialectMCode] = field(default_factory=dict)
    m_removed: frozenset[int] = frozenset()
    g_refused: dict[int, str] = field(default_factory=dict)
    letters: dict[str, str] = field(default_factory=dict)
    letter_meanings: dict[str, str] = field(default_factory=dict)


GRBL_COMMANDS: dict[str, str] = {
    "$": "grbl's settings listing ($$)",
    "#": "grbl's parameter listing ($#)",
    "G": "grbl's parser state report ($G)",
    "I": "grbl's build information ($I)",
    "N": "grbl's startup blocks ($N)",
    "C": "grbl's check mode ($C)",
    "X": "grbl's alarm unlock ($X)",
    "J": "a jog ($J=)",
    "RST": "restoring grbl's settings ($RST=)",
    "SLP": "grbl's sleep mode ($SLP)",
}
"""grbl's ``$`` commands other than homing (the text after ``$``, up to ``=`` or a digit),
each refused by name: they are the operator's, not a program's."""

_MARLIN_M_CODES: dict[int, DialectMCode] = {
    73: DialectMCode("print progress (percent done, minutes left)", "PRQSC"),
    82: DialectMCode("extruder positions absolute (no extruder)"),
    83: DialectMCode("extruder positions relative (no extruder)"),
    17: DialectMCode("enable the motors (the run enables the servos)", "XYZEUVW"),
    18: DialectMCode("disable the motors (the run disables the servos when it ends)",
                     "SXYZEUVW"),
    84: DialectMCode("disable the motors (the run disables the servos when it ends)",
                     "SXYZEUVW"),
    104: DialectMCode("set the hotend temperature (no hotend)", "STBFI"),
    105: DialectMCode("report the temperatures (no heaters)", "TR"),
    106: DialectMCode("fan on (no fan)", "SPT"),
    107: DialectMCode("fan off (no fan)", "P"),
    109: DialectMCode("wait for the hotend temperature (no hotend)", "SRTBFI"),
    117: DialectMCode("display a message"),
    118: DialectMCode("send a message to the host"),
    140: DialectMCode("set the bed temperature (no heated bed)", "SI"),
    141: DialectMCode("set the chamber temperature (no heated chamber)", "S"),
    155: DialectMCode("temperature auto-report interval (no heaters)", "S"),
    190: DialectMCode("wait for the bed temperature (no heated bed)", "SRI"),
    191: DialectMCode("wait for the chamber temperature (no heated chamber)", "SR"),
    201: DialectMCode("maximum accelerations (the machine file sets them)", "XYZEFT"),
    203: DialectMCode("maximum feed rates (the machine file sets them)", "XYZET"),
    204: DialectMCode("default accelerations (the machine file sets them)", "PRTS"),
    205: DialectMCode("jerk and minimum speeds (the planner's junction deviation rules)",
                      "XYZEBSTJ"),
    220: DialectMCode("feed rate percentage (not applied: feeds run as programmed)", "SBR"),
    221: DialectMCode("extrusion flow percentage (no extruder)", "ST"),
    300: DialectMCode("play a tone", "SP"),
    400: DialectMCode("wait for the moves to finish (they run in order)"),
    900: DialectMCode("linear advance factor (no extruder)", "KLST"),
}
_LINUXCNC_ONLY_M_CODES = frozenset((MCode.M_48, MCode.M_49, MCode.M_50, MCode.M_51,
                                    MCode.M_52, MCode.M_53, MCode.M_60, MCode.M_61))
_CANNED_CYCLES = (GCode.G_73, GCode.G_81, GCode.G_82, GCode.G_83, GCode.G_85, GCode.G_89)

RULES: dict[Dialect, DialectRules] = {
    Dialect.LINUXCNC: DialectRules(Dialect.LINUXCNC),
    Dialect.GRBL: DialectRules(
        Dialect.GRBL,
        start_motion=GCode.G_0,
        needs_end=False,
        line_limit=LineLimit.GRBL,
        g92_volatile=True,
        reset_modes=True,
        controller_commands=True,
        m_codes={
            MCode.M_3: DialectMCode("spindle on clockwise, or the laser on at constant power"
                                    " (laser mode)"),
            MCode.M_4: DialectMCode("spindle on counter-clockwise, or the laser on with power"
                                    " scaled to the speed (laser mode)"),
            MCode.M_5: DialectMCode("spindle or laser off"),
            56: DialectMCode("parking motion override control", "P"),
        },
        m_removed=_LINUXCNC_ONLY_M_CODES,
        g_refused={
            **dict.fromkeys(_CANNED_CYCLES, "grbl has no canned cycles"),
            GCode.G_43: "grbl has no tool table: its tool length offset is G43.1 (give it)"
                        " and G49",
            **dict.fromkeys((GCode.G_59_1, GCode.G_59_2, GCode.G_59_3),
                            "grbl's coordinate systems are G54-G59"),
            GCode.G_92_2: "grbl has no G92.2 (G92.1 clears the offset)",
            GCode.G_92_3: "grbl has no G92.3",
        },
        letter_meanings={"S": "spindle speed or laser power"},
    ),
    Dialect.MARLIN: DialectRules(
        Dialect.MARLIN,
        needs_end=False,
        line_limit=LineLimit.MARLIN,
        g92_volatile=True,
        homing_clears_g92=True,
        reset_modes=True,
        message_codes=frozenset((117, 118)),
        flags=True,
        dwell_p_seconds=0.001,
        dwell_s=True,
        g28_homes=True,
        m_codes=_MARLIN_M_CODES,
        m_removed=_LINUXCNC_ONLY_M_CODES,
        g_refused={
            GCode.G_10: "firmware retraction (G10) is not supported: it may lift Z",
            MARLIN_G11: "firmware retraction (G11) is not supported: it may lower Z",
            MARLIN_G29: "bed levelling (G29) changes the geometry and is not supported",
            GCode.G_30: "Marlin's G30 probes the bed at one point: not supported (no probe)",
            **dict.fromkeys((GCode.G_28_1, GCode.G_30_1),
                            "Marlin keeps no stored positions (its G28 homes)"),
            **dict.fromkeys((GCode.G_43, GCode.G_43_1), "Marlin has no tool length offsets"),
            **dict.fromkeys(_CANNED_CYCLES, "Marlin has no canned cycles"),
            GCode.G_93: "Marlin has no inverse time feed (G93)",
        },
        letters={"E": "extruder position (no extruder)"},
        letter_meanings={"S": "spindle speed, laser power or the parameter of its M code"},
    ),
}
"""Every dialect's rules."""


def dialect_named(name: str) -> Dialect:
    """The dialect called ``name`` (``"linuxcnc"``, ``"grbl"``, ``"marlin"``).

    Raises:
        ValueError: no dialect has that name (the message lists the names).
    """
    try:
        return Dialect(name)
    except ValueError:
        names = ", ".join(d.value for d in Dialect)
        raise ValueError(f"dialect {name!r} is not one of {names}") from None


@dataclass(frozen=True, slots=True)
class Declared:
    """A dialect a program's own comments name: ``words`` on line ``line``."""

    dialect: Dialect
    line: int
    words: str


_DECLARATIONS = (
    (re.compile(r"^;[ \t]*FLAVOR:[ \t]*Marlin\b.*$", re.IGNORECASE | re.MULTILINE),
     Dialect.MARLIN),  # Cura's header
    (re.compile(r"^;[ \t]*gcode_flavor[ \t]*=[ \t]*marlin\w*[ \t]*$",
                re.IGNORECASE | re.MULTILINE), Dialect.MARLIN),  # PrusaSlicer's and its
    # descendants' settings, at the file's end
    (re.compile(r"^;[ \t]*GRBL device profile\b.*$", re.IGNORECASE | re.MULTILINE),
     Dialect.GRBL),  # LightBurn's header
)


def declared_dialect(text: str) -> Declared | None:
    """The dialect a program says it was written for, in the comments its writer puts in
    (a slicer's flavour, a laser program's device profile), or None: the first such comment
    of the program's text."""
    found: Declared | None = None
    for pattern, dialect in _DECLARATIONS:
        match = pattern.search(text)
        if match is not None:
            line = text.count("\n", 0, match.start()) + 1
            if found is None or line < found.line:
                found = Declared(dialect, line, match.group(0).strip())
    return found
