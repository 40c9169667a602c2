"""G-code to typed moves, with RS274/NGC semantics as LinuxCNC implements them.

The text is read by :mod:`usbmotion.motion.gcode_lexer` (words, comments, checksums) and
interpreted here block by block into :data:`~usbmotion.motion.moves.Move` values, in mm,
at absolute machine positions. LinuxCNC's interpreter is the reference; the conformance
cases in ``shared/gcode-conformance`` are run by the tests.

Start state (LinuxCNC's): G21 (mm), G17, G90, G91.1, G94, G98, feed 0, no motion mode (so
an axis word before any G0-G3 is an error), no tool length offset, tool 0 in the spindle,
and the work offsets and G28/G30 positions the caller passes (a parameter file's, by
default all zero in G54).

Supported: G0 G1 G2 G3 (I/J/K or R; P turns; helices), G4 (P seconds), G10 L2 (P0-P9, R
rotation) and G10 L20, G17 G18 G19, G20 G21, G28 G28.1 G30 G30.1, G43 (H, or the spindle
tool) G43.1 G49, G53, G54-G59.3, G73 G81 G82 G83 G85 G89 (R Q P L) with G98/G99, G80, G90
G91, G90.1 G91.1, G92 G92.1 G92.2 G92.3, F, T, M6, M61, N, comments, M2 M30, ``%``
delimiters, block delete, RepRap checksums. Moves come out at machine positions::

    machine = rotate_XY(program + G92, R of the system) + G5x offset + tool offset

(:mod:`usbmotion.motion.offsets`); canned cycles are expanded into G0/G1 moves and dwells
(:mod:`usbmotion.motion.cycles`); tools come from a LinuxCNC tool table
(:mod:`usbmotion.motion.tools`).

G and M codes and their modal groups carry LinuxCNC's names (:class:`GCode`, ``G_92_3`` is
923; :class:`ModalGroup`; :class:`MCode`, :class:`MGroup`: :mod:`usbmotion.motion.gcode_codes`).

Decisions worth knowing, LinuxCNC's unless said:

- Within a block, words act in LinuxCNC's order: F, then G4, plane, units, distance
  modes, G28/G30/G92, G92.1-G92.3 (a modal group of their own, as in LinuxCNC 2.9),
  motion, and M2/M30 last. So ``G20 F10`` sets 10 mm/min (F is read
  before G20 takes effect). A G20/G21 switch keeps the feed's physical speed, as
  LinuxCNC's task does (its stand-alone ``rs274`` keeps the number instead).
- G80 cancels the motion mode: after it, axis words need a G0-G3 again.
- A feed move (G1, G2, G3) with feed 0 is an error; G0 needs no feed.
- Centre-format arcs: with r1, r2 the radii to start and end, the arc is refused when
  ``|r2 - r1|`` exceeds 100 * t or exceeds t with a relative difference over 0.1 %, where
  t = 2 * 0.01 * sqrt(2) mm (G21) or 2 * 0.001 * sqrt(2) inch (G20). An accepted arc
  keeps the programmed centre (the path is a slight spiral).
- R-format arcs: a radius shorter than half the chord by more than 0.00005 inch
  (0.00127 mm) is refused; negative R takes the arc over 180 degrees.
- G92 and G10 values are always absolute; G28/G30 go first to the intermediate point given
  by the axis words (absolute or incremental per G90/G91), then, for the named axes only
  (all of them when none is named), to the stored machine position.
- An offset change (G10 on the active system, G92, G43, G49, G54-G59.3) does not move the
  machine: the axes the next move does not name stay where they are.
- M2 and M30 reset what LinuxCNC's documentation lists that matters here: G54 becomes the
  active system, G17, G90 and the motion mode G1 (:attr:`GCodeProgram.offsets`, and a
  stream's modal state). They also suspend the G92 offset as G92.2 does (its values kept,
  not applied), as RS274/NGC's program end specifies, so that a job never shifts the next
  one; LinuxCNC 2.9 differs: it keeps G92 applied across M2 unless its
  ``DISABLE_G92_PERSISTENCE`` is set, which clears it. usbmotion's choice: a closing ``%``
  ends a program the same way (LinuxCNC's ``%`` does not reset). Where the G92 offset is
  volatile (grbl, Marlin) it is cleared instead, and never reaches
  :attr:`GCodeProgram.offsets`.
- Arcs in a system rotated by ``G10 L2 R`` are supported in G17 only.
- Two words of the same letter, two G codes of one modal group, or words that nothing in
  the block uses (I, J, K, R, P, Q) are errors.
- A program must end with M2, M30 or ``%`` (when it opened with ``%``); the end of the
  text without one is an error, and nothing after the end is read.

Words that do not move the machine (S, D, H without G43, M0 M1 M3-M5 M7-M9 M48-M53 M60,
G40 G61 G61.1 G64 G94 G96 G97 and their P/Q) are accepted and listed in
:attr:`GCodeProgram.ignored`. Words that would change the geometry and are not supported
raise :class:`~usbmotion.errors.UnsupportedGCodeError` naming the word and the reason.

The axes are the machine's linear axes among X Y Z U V W (``axes``, ``"XYZ"`` by default):
moves carry one coordinate per axis of the set, in that order; a word of an axis the set
lacks is refused naming it, and an arc needs both axes of its plane. Other controllers'
readings (grbl, Marlin) are the dialects of :mod:`usbmotion.motion.dialects`.
"""

from __future__ import annotations

import copy
import math
import os
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, replace
from enum import Enum
from pathlib import Path

from usbmotion.errors import FeedRateError, GCodeError, UnsupportedGCodeError
from usbmotion.motion.cycles import CYCLE_NAMES, DWELL, RAPID, Cycle, expand_cycle
from usbmotion.motion.dialects import GRBL_COMMANDS, RULES, Dialect, DialectRules
from usbmotion.motion.gcode_codes import GCode, MCode, MGroup, ModalGroup, g_code_text
from usbmotion.motion.gcode_lexer import Block, Word, parse_blocks, tokenize, word_columns
from usbmotion.motion.moves import (
    AXIS_ORDER,
    DEFAULT_AXES,
    ROTARY_AXES,
    Arc,
    Dwell,
    Linear,
    Move,
    Plane,
    Point,
    Rapid,
)
from usbmotion.motion.offsets import COORDINATE_SYSTEMS, NO_OFFSETS, Frame, WorkOffsets
from usbmotion.motion.tools import NO_TOOLS, ToolTable

__all__ = [
    "NO_MOTION",
    "Block",
    "Dialect",
    "GCode",
    "GCodeProgram",
    "GCodeStream",
    "IgnoredWord",
    "MCode",
    "MGroup",
    "MachineAxes",
    "ModalGroup",
    "Modes",
    "Pause",
    "Pauses",
    "ToolChange",
    "Word",
    "distinct_ignored",
    "g_code_text",
    "interpret_setting",
    "interpret_until_error",
    "load_gcode",
    "move_record",
    "parse_blocks",
    "parse_gcode",
    "read_gcode_text",
    "tokenize",
]

MM_PER_INCH = 25.4
_SQRT2 = math.sqrt(2.0)
_SPIRAL_ABS_MM = 2 * 0.01 * _SQRT2  # LinuxCNC CENTER_ARC_RADIUS_TOLERANCE_MM
_SPIRAL_ABS_INCH = 2 * 0.001 * _SQRT2  # ..._INCH
_SPIRAL_REL = 0.001  # SPIRAL_RELATIVE_TOLERANCE
_RADIUS_TOL_MM = 0.00005 * MM_PER_INCH  # RADIUS_TOLERANCE_INCH, in mm
_TINY = 1e-12  # arc_data_r: a chord this close to the diameter is a semicircle
_LARGEST = 1e9  # magnitude limit of any number, in program units
_MAX_M_CODES = 4
_MOST_CYCLE_PASSES = 100_000  # holes x pecks of one canned cycle block

# --- the code tables ----------------------------------------------------------------------
# G codes are keyed by ten times their number (GCode.G_90_1 is 901), as LinuxCNC does.

NO_MOTION = -1
"""The motion mode after G80, and at power-on in LinuxCNC: an axis word needs a G0-G3 first."""

_MOTION, _DWELL, _PLANE, _UNITS, _DISTANCE, _ARC_DISTANCE, _HOME, _HOME_SET, _OFFSET = range(9)
_IGNORED, _UNSUPPORTED = 9, 10
_SET_OFFSETS, _TOOL_LENGTH, _MACHINE, _SYSTEM, _RETRACT, _G92_APPLIED = 11, 12, 13, 14, 15, 16
_FEED_MODE = 17

_G = GCode
_GROUP = ModalGroup
_SYSTEM_CODES = (_G.G_54, _G.G_55, _G.G_56, _G.G_57, _G.G_58, _G.G_59, _G.G_59_1, _G.G_59_2,
                 _G.G_59_3)

_PROBING_ALONE = ("probing runs a line at a time, from the console, a grbl sender or the"
                  " dashboard's MDI, not inside a program (a program is planned ahead of"
                  " where the probe stops)")

# code -> (modal group, kind, meaning or reason)
_G_CODES: dict[int, tuple[ModalGroup, int, str]] = {
    _G.G_0: (_GROUP.MOTION, _MOTION, "rapid"),
    _G.G_1: (_GROUP.MOTION, _MOTION, "linear feed"),
    _G.G_2: (_GROUP.MOTION, _MOTION, "clockwise arc"),
    _G.G_3: (_GROUP.MOTION, _MOTION, "counter-clockwise arc"),
    _G.G_80: (_GROUP.MOTION, _MOTION, "cancel motion mode"),
    _G.G_73: (_GROUP.MOTION, _MOTION, "peck drilling cycle with chip breaking"),
    _G.G_81: (_GROUP.MOTION, _MOTION, "drilling cycle"),
    _G.G_82: (_GROUP.MOTION, _MOTION, "drilling cycle with dwell"),
    _G.G_83: (_GROUP.MOTION, _MOTION, "peck drilling cycle"),
    _G.G_85: (_GROUP.MOTION, _MOTION, "boring cycle, feed out"),
    _G.G_89: (_GROUP.MOTION, _MOTION, "boring cycle, dwell, feed out"),
    _G.G_4: (_GROUP.MODAL_0, _DWELL, "dwell"),
    _G.G_17: (_GROUP.SET_PLANE, _PLANE, "XY plane"),
    _G.G_18: (_GROUP.SET_PLANE, _PLANE, "XZ plane"),
    _G.G_19: (_GROUP.SET_PLANE, _PLANE, "YZ plane"),
    _G.G_20: (_GROUP.LENGTH_UNITS, _UNITS, "inches"),
    _G.G_21: (_GROUP.LENGTH_UNITS, _UNITS, "millimetres"),
    _G.G_90: (_GROUP.DISTANCE_MODE, _DISTANCE, "absolute distances"),
    _G.G_91: (_GROUP.DISTANCE_MODE, _DISTANCE, "incremental distances"),
    _G.G_90_1: (_GROUP.IJK_DISTANCE_MODE, _ARC_DISTANCE, "absolute arc centres"),
    _G.G_91_1: (_GROUP.IJK_DISTANCE_MODE, _ARC_DISTANCE, "incremental arc centres"),
    _G.G_28: (_GROUP.MODAL_0, _HOME, "go to the G28 position"),
    _G.G_30: (_GROUP.MODAL_0, _HOME, "go to the G30 position"),
    _G.G_28_1: (_GROUP.MODAL_0, _HOME_SET, "store the G28 position"),
    _G.G_30_1: (_GROUP.MODAL_0, _HOME_SET, "store the G30 position"),
    _G.G_92: (_GROUP.MODAL_0, _OFFSET, "set the G92 offset"),
    _G.G_92_1: (_GROUP.G92_IS_APPLIED, _G92_APPLIED, "reset the G92 offset and its stored value"),
    _G.G_92_2: (_GROUP.G92_IS_APPLIED, _G92_APPLIED, "reset the G92 offset"),
    _G.G_92_3: (_GROUP.G92_IS_APPLIED, _G92_APPLIED, "restore the stored G92 offset"),
    _G.G_10: (_GROUP.MODAL_0, _SET_OFFSETS, "set a coordinate system's offset"),
    _G.G_53: (_GROUP.MODAL_0, _MACHINE, "move in machine coordinates"),
    _G.G_43: (_GROUP.TOOL_LENGTH_OFFSET, _TOOL_LENGTH, "tool length offset from the tool table"),
    _G.G_43_1: (_GROUP.TOOL_LENGTH_OFFSET, _TOOL_LENGTH,
               "tool length offset given by the axis words"),
    _G.G_49: (_GROUP.TOOL_LENGTH_OFFSET, _TOOL_LENGTH, "cancel the tool length offset"),
    **{code: (_GROUP.COORD_SYSTEM, _SYSTEM, f"coordinate system {name}")
       for code, name in zip(_SYSTEM_CODES, COORDINATE_SYSTEMS, strict=True)},
    _G.G_98: (_GROUP.RETRACT_MODE, _RETRACT, "canned cycles retract to the initial level"),
    _G.G_99: (_GROUP.RETRACT_MODE, _RETRACT, "canned cycles retract to R"),
    _G.G_40: (_GROUP.CUTTER_COMP, _IGNORED, "cutter radius compensation off (it is never on)"),
    _G.G_61: (_GROUP.CONTROL_MODE, _IGNORED,
             "exact path mode (path blending belongs to the planner)"),
    _G.G_61_1: (_GROUP.CONTROL_MODE, _IGNORED,
               "exact stop mode (path blending belongs to the planner)"),
    _G.G_64: (_GROUP.CONTROL_MODE, _IGNORED,
             "path blending tolerance (path blending belongs to the planner)"),
    _G.G_93: (_GROUP.FEED_MODE, _FEED_MODE, "inverse time feed mode"),
    _G.G_94: (_GROUP.FEED_MODE, _FEED_MODE, "units-per-minute feed mode"),
    _G.G_96: (_GROUP.SPINDLE_MODE, _IGNORED, "constant surface speed (spindle)"),
    _G.G_97: (_GROUP.SPINDLE_MODE, _IGNORED, "spindle RPM mode"),
}
_G_UNSUPPORTED: dict[int, str] = {
    _G.G_5: "cubic spline moves are not supported",
    _G.G_5_1: "quadratic spline moves are not supported",
    _G.G_5_2: "NURBS moves are not supported",
    _G.G_5_3: "NURBS moves are not supported",
    _G.G_7: "lathe diameter mode is not supported",
    _G.G_8: "lathe radius mode is not supported",
    _G.G_17_1: "the UV plane is not supported",
    _G.G_18_1: "the WU plane is not supported",
    _G.G_19_1: "the VW plane is not supported",
    _G.G_33: "spindle-synchronized motion is not supported",
    _G.G_33_1: "rigid tapping is not supported",
    _G.G_38_2: _PROBING_ALONE,
    _G.G_38_3: _PROBING_ALONE,
    _G.G_38_4: _PROBING_ALONE,
    _G.G_38_5: _PROBING_ALONE,
    _G.G_41: "cutter radius compensation is not supported",
    _G.G_41_1: "cutter radius compensation is not supported",
    _G.G_42: "cutter radius compensation is not supported",
    _G.G_42_1: "cutter radius compensation is not supported",
    _G.G_43_2: "adding to the tool length offset (G43.2) is not supported",
    _G.G_52: "local coordinate offsets are not supported",
    _G.G_70: "lathe finishing cycles are not supported",
    _G.G_71: "lathe roughing cycles are not supported",
    _G.G_71_1: "lathe roughing cycles are not supported",
    _G.G_72: "lathe roughing cycles are not supported",
    _G.G_72_1: "lathe roughing cycles are not supported",
    _G.G_74: "left-hand tapping cycles are not supported",
    _G.G_76: "threading cycles are not supported",
    _G.G_95: "feed per revolution is not supported",
}
_G_UNSUPPORTED |= dict.fromkeys(
    (_G.G_84, _G.G_86, _G.G_87, _G.G_88), "tapping and G86-G88 boring cycles are not supported"
)

_M = MCode
_M_END: dict[int, str] = {_M.M_2: "M2", _M.M_30: "M30"}
_DIALECT_M_GROUP = 1000  # a dialect's own M code is the only one of group 1000 + code
_M_ACTING = (_M.M_2, _M.M_30, _M.M_6, _M.M_61)  # M codes that are not merely listed as ignored
_OVERRIDE_CODES = (_M.M_50, _M.M_51, _M.M_52, _M.M_53)  # their P is theirs
# code -> (modal group, meaning)
_M_CODES: dict[int, tuple[int, str]] = {
    _M.M_0: (MGroup.STOPPING, "program pause"),
    _M.M_1: (MGroup.STOPPING, "optional program pause"),
    _M.M_2: (MGroup.STOPPING, "program end"),
    _M.M_30: (MGroup.STOPPING, "program end"),
    _M.M_60: (MGroup.STOPPING, "pallet change pause"),
    _M.M_3: (MGroup.SPINDLE, "spindle on, clockwise"),
    _M.M_4: (MGroup.SPINDLE, "spindle on, counter-clockwise"),
    _M.M_5: (MGroup.SPINDLE, "spindle stop"),
    _M.M_6: (MGroup.TOOL_CHANGE, "tool change"),
    _M.M_61: (MGroup.TOOL_CHANGE, "set the current tool number"),
    _M.M_7: (MGroup.COOLANT, "mist coolant on"),
    _M.M_8: (MGroup.COOLANT, "flood coolant on"),
    _M.M_9: (MGroup.COOLANT, "coolant off"),
    _M.M_48: (MGroup.OVERRIDES, "enable speed and feed overrides"),
    _M.M_49: (MGroup.OVERRIDES, "disable speed and feed overrides"),
    _M.M_50: (MGroup.OVERRIDES, "feed override control"),
    _M.M_51: (MGroup.OVERRIDES, "spindle speed override control"),
    _M.M_52: (MGroup.OVERRIDES, "adaptive feed control"),
    _M.M_53: (MGroup.OVERRIDES, "feed stop control"),
}
_M_UNSUPPORTED: dict[int, str] = {
    _M.M_19: "spindle orientation is not supported",
    _M.M_98: "subroutine calls are not supported",
    _M.M_99: "subroutine returns are not supported",
}
_USER_M_CODES = range(100, 200)
_M_GROUPS = frozenset(MGroup)
_M_UNSUPPORTED |= dict.fromkeys(range(62, 69), "digital and analog I/O is not supported")
_M_UNSUPPORTED |= dict.fromkeys(range(70, 74), "modal state save and restore is not supported")

# The codes and groups the interpreter tests blocks against, under LinuxCNC's names (its
# G_53, GM_MOTION), bound once: in CPython 3.11 every read of a member off its enum class
# (GCode.G_53) is a Python-level call (EnumType.__getattr__); read so on every block, they
# cost the interpreter a fifth of its speed (85,000 instead of 110,000 lines/s).
_G_0, _G_1, _G_2, _G_4 = GCode.G_0, GCode.G_1, GCode.G_2, GCode.G_4
_G_10, _G_20, _G_28, _G_28_1 = GCode.G_10, GCode.G_20, GCode.G_28, GCode.G_28_1
_G_30, _G_30_1, _G_43, _G_43_1 = GCode.G_30, GCode.G_30_1, GCode.G_43, GCode.G_43_1
_G_49, _G_53, _G_64, _G_80 = GCode.G_49, GCode.G_53, GCode.G_64, GCode.G_80
_G_82, _G_89, _G_91, _G_91_1 = GCode.G_82, GCode.G_89, GCode.G_91, GCode.G_91_1
_G_92, _G_92_1, _G_92_3, _G_96 = GCode.G_92, GCode.G_92_1, GCode.G_92_3, GCode.G_96
_G_99 = GCode.G_99
_G_93 = GCode.G_93
_GM_FEED_MODE = ModalGroup.FEED_MODE
_GM_CONTROL_MODE = ModalGroup.CONTROL_MODE
_GM_COORD_SYSTEM = ModalGroup.COORD_SYSTEM
_GM_DISTANCE_MODE = ModalGroup.DISTANCE_MODE
_GM_G92_IS_APPLIED = ModalGroup.G92_IS_APPLIED
_GM_IJK_DISTANCE_MODE = ModalGroup.IJK_DISTANCE_MODE
_GM_LENGTH_UNITS = ModalGroup.LENGTH_UNITS
_GM_MODAL_0 = ModalGroup.MODAL_0
_GM_MOTION = ModalGroup.MOTION
_GM_RETRACT_MODE = ModalGroup.RETRACT_MODE
_GM_SET_PLANE = ModalGroup.SET_PLANE
_GM_SPINDLE_MODE = ModalGroup.SPINDLE_MODE
_GM_TOOL_LENGTH_OFFSET = ModalGroup.TOOL_LENGTH_OFFSET
_M_0, _M_1, _M_6, _M_61 = MCode.M_0, MCode.M_1, MCode.M_6, MCode.M_61
_MG_OVERRIDES, _MG_STOPPING, _MG_TOOL_CHANGE = MGroup.OVERRIDES, MGroup.STOPPING, MGroup.TOOL_CHANGE
_MG_SPINDLE, _MG_COOLANT = MGroup.SPINDLE, MGroup.COOLANT
_M_3, _M_4, _M_7, _M_8 = MCode.M_3, MCode.M_4, MCode.M_7, MCode.M_8
_PAUSE_CODES = (_M_0, _M_1)

_LETTERS_UNSUPPORTED = {
    "E": "E words (an extruder axis, G76 or M66) are not supported",
}
_NOT_NEGATIVE = {"F": "feed rate", "S": "spindle speed", "T": "tool number"}
_LETTERS_IGNORED = {
    "S": "spindle speed",
    "D": "cutter compensation index (no cutter compensation)",
}
_H_WITHOUT_G43 = "tool length offset index with no G43 to use it"
_G10_NAMES = {2: "G10 L2", 20: "G10 L20"}
_G10_UNSUPPORTED = "only G10 L2 and G10 L20 (coordinate system offsets) are supported"


def _spellings(codes: Iterable[int]) -> dict[str, int]:
    """Common spellings of G codes (``1``, ``01``, ``1.``, ``1.0``, ``90.1``) to their codes."""
    spellings: dict[str, int] = {}
    for code in codes:
        whole, tenth = divmod(code, 10)
        for number in (f"{whole}", f"{whole:02d}"):
            if tenth:
                spellings[f"{number}.{tenth}"] = code
            else:
                spellings.update(dict.fromkeys((number, f"{number}.", f"{number}.0"), code))
    return spellings


# So that most G codes need no arithmetic.
_G_SPELLINGS = _spellings([*_G_CODES, *_G_UNSUPPORTED])

_PLANE_OF_CODE: dict[int, Plane] = {_G.G_17: Plane.XY, _G.G_18: Plane.XZ, _G.G_19: Plane.YZ}
_CODE_OF_PLANE = {Plane.XY: GCode.G_17, Plane.XZ: GCode.G_18, Plane.YZ: GCode.G_19}
# plane -> (letter of the first axis's centre offset, of the second's, the forbidden one)
_CENTRE_LETTERS = {Plane.XY: ("I", "J", "K"), Plane.XZ: ("K", "I", "J"), Plane.YZ: ("J", "K", "I")}

# --- the result ----------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class IgnoredWord:
    """A word that was accepted but does not move the machine.

    ``word`` is the word as written (upper-case letter), ``line`` and ``column`` are
    1-based, ``meaning`` says what the word is for.
    """

    word: str
    line: int
    column: int
    meaning: str

    @property
    def kind(self) -> tuple[str, str]:
        """What makes two ignored words the same for a report: the code of a G or M word
        (``"M104"``), the letter of any other (every ``E`` word is one), and the meaning
        (``S`` of M104 and ``S`` of M140 differ)."""
        letter = self.word[:1]
        return (self.word if letter in "GM" else letter, self.meaning)


def ignored_kind_label(word: str, count: int) -> str:
    """How a report names a kind of ignored word: a G or M code as itself (``M104``), a
    single word as written (``S1000``), several words of one letter by the letter
    (``S words``: their values differ)."""
    return f"{word[:1]} words" if count > 1 and word[:1] not in "GM" else word


def distinct_ignored(words: Iterable[IgnoredWord]) -> list[tuple[IgnoredWord, int]]:
    """Each kind of ignored word once (:attr:`IgnoredWord.kind`), at its first use, with
    how many times it occurs."""
    first: dict[tuple[str, str], IgnoredWord] = {}
    count: dict[tuple[str, str], int] = {}
    for word in words:
        kind = word.kind
        first.setdefault(kind, word)
        count[kind] = count.get(kind, 0) + 1
    return [(word, count[kind]) for kind, word in first.items()]


@dataclass(frozen=True, slots=True)
class ToolChange:
    """An ``M6`` (or ``M61``): tool ``tool`` goes in the spindle at ``line``.

    ``pocket`` is its pocket in the tool table (0 when there is no table or no tool);
    ``manual`` is false for M61, which only says which tool is in the spindle.
    """

    line: int
    tool: int
    pocket: int
    manual: bool


class Pauses(Enum):
    """Which program pauses stop a program until the operator resumes it.

    ``NONE``: M0 and M1 are listed as ignored words and M6 only changes the tool (a
    program read for its geometry, or run with nobody to resume it); ``PROGRAM``: M0
    pauses, and so does M6 when it puts another tool in the spindle (a manual tool
    change); ``OPTIONAL``: M1 pauses as well (the operator's optional stop is on).
    """

    NONE = "none"
    PROGRAM = "program"
    OPTIONAL = "optional"


@dataclass(frozen=True, slots=True)
class Pause:
    """A program pause: the machine comes to rest at the end of ``line`` and waits for the
    operator's cycle start.

    ``code`` is ``"M0"``, ``"M1"`` or ``"M6"``; ``message`` says what the operator is to do
    (a tool change names the tool and its pocket); ``move`` is the index in the program's
    moves of the zero-second :class:`Dwell` that brings the machine to rest there.
    ``spindle_rpm``: a spindle pause (``M3``, ``M4``, ``M5``, ``S``, the program's end):
    the speed the spindle is to turn at (+ clockwise, - counter-clockwise, 0 stopped);
    the run goes on by itself once it is there. None: a pause for the operator.
    """

    line: int
    code: str
    message: str
    move: int
    spindle_rpm: float | None = None


@dataclass(frozen=True, slots=True)
class OutputChange:
    """An output the program changes at ``line``: ``"flood"`` (M8, M9), ``"mist"`` (M7,
    M9) or ``"laser"`` (M3, M4, M5 and S on a laser machine), to ``value`` per mille of full
    (coolant 0 or 1000; the laser's S over the machine's ``laser_max_s``). It applies from
    the first move at or after ``line`` on (LinuxCNC's order: before the line's motion).
    ``dynamic``: the laser's power follows the speed the axes move at (grbl's M4), else it
    is constant while a feed move cuts (M3); a laser is off during rapids either way."""

    line: int
    output: str
    value: int
    dynamic: bool = False


OUTPUT_NAMES = ("flood", "mist", "laser")
"""The outputs a program switches: flood and mist coolant, the laser's power."""


@dataclass(frozen=True, slots=True)
class GCodeProgram:
    """An interpreted G-code program.

    ``moves`` are in program order, lengths in mm at absolute machine positions (work, G92
    and tool offsets applied). ``ignored`` lists the accepted words that do not move the
    machine. ``ended_by`` is ``"M2"``, ``"M30"`` or ``"%"``, and ``end_line`` its line; in a
    dialect that needs no end, a program that has none has ``ended_by == "end of text"`` and
    its last line; a program returned with an error by :func:`interpret_until_error` has
    ``ended_by == ""`` and ``end_line == 0``. ``axes`` are the letters of the moves'
    coordinates, ``dialect`` the dialect it was read in. ``offsets`` are the work offsets
    and stored positions as the program leaves them (what a parameter file keeps for the
    next run); ``tool_changes`` the tool changes in order; ``pauses`` the program pauses
    (M0, M1, M6) that stop it until the operator resumes, when it was read with pauses.
    ``frames`` say which offset from machine to program coordinates (G5x + G92 + tool, mm
    per axis; an XY rotation aside) each move was made in: ``(index, offset)`` pairs in
    order, the first ``(0, the offset at the start)``, each in effect from move ``index``
    on (for a check in the program's own coordinates: a rapid below work Z0). ``outputs``
    are the changes of the coolant and laser outputs the machine has, in order.
    """

    moves: tuple[Move, ...]
    ignored: tuple[IgnoredWord, ...]
    file: str
    end_line: int
    ended_by: str
    axes: str = DEFAULT_AXES
    dialect: Dialect = Dialect.LINUXCNC
    offsets: WorkOffsets = NO_OFFSETS
    tool_changes: tuple[ToolChange, ...] = ()
    pauses: tuple[Pause, ...] = ()
    frames: tuple[tuple[int, Point], ...] = ()
    outputs: tuple[OutputChange, ...] = ()


@dataclass(frozen=True, slots=True)
class MachineAxes:
    """What the interpreter needs to know of the machine a program is read for.

    Fields:
        axes: its axes, a subsequence of ``"XYZABCUVW"`` (one to nine letters; A B C are
            rotary, in degrees).
        home_mm: where homing leaves each axis (machine coordinates, mm), for grbl's
            ``$H`` and Marlin's ``G28``; zeros (the default machine's) when not given.
        homing_order: the groups of axes homed together, in order (``("Z", "XY")``);
            every axis of ``axes`` in one group; one group of all axes when empty.
        wrapped: its rotary axes that wrap (LinuxCNC's ``WRAPPED_ROTARY``): an absolute
            move takes the short way round, whatever the turns between.
        spindle_max_rpm: the fastest ``S`` of its spindle; 0: it has none (``S`` and
            ``M3``-``M5`` are then listed as ignored words). With one, every ``M3``,
            ``M4``, ``M5``, a change of ``S`` while it turns and the program's end bring the
            machine to rest at a spindle :class:`Pause` that waits until the spindle is at
            its new speed (LinuxCNC's spindle-at-speed), then goes on by itself.
        outputs: the outputs it has of :data:`OUTPUT_NAMES`: ``M7``/``M8``/``M9`` switch the
            coolant ones (:class:`OutputChange`), and with ``"laser"`` ``M3``/``M4``/``M5``
            and ``S`` set the laser's power, ``laser_max_s`` the ``S`` of full power (grbl's
            ``$30``); words for outputs it lacks are listed as ignored.

    Raises:
        ValueError: the axes are not a non-empty subsequence of ``"XYZABCUVW"``, the home
            position has not one coordinate per axis, the order misses or repeats one, or a
            wrapped axis is not one of its rotary axes.
    """

    axes: str = DEFAULT_AXES
    home_mm: Point | None = None
    homing_order: tuple[str, ...] = ()
    wrapped: str = ""
    spindle_max_rpm: float = 0.0
    outputs: tuple[str, ...] = ()
    laser_max_s: float = 1000.0

    def __post_init__(self) -> None:
        axes = self.axes
        if not axes or axes != "".join(a for a in AXIS_ORDER if a in axes) or len(
                set(axes)) != len(axes):
            raise ValueError(f"axes {axes!r} must be one to nine of {AXIS_ORDER!r}, in that"
                             " order, each once")
        if self.home_mm is not None and len(self.home_mm) != len(axes):
            raise ValueError(f"home_mm {self.home_mm!r} needs one coordinate per axis of"
                             f" {axes!r}")
        grouped = "".join(self.homing_order)
        if self.homing_order and sorted(grouped) != sorted(axes):
            raise ValueError(f"homing_order {self.homing_order!r} must hold every axis of"
                             f" {axes!r} once")
        if any(letter not in ROTARY_AXES or letter not in axes for letter in self.wrapped):
            raise ValueError(f"wrapped {self.wrapped!r}: rotary axes (A, B, C) of {axes!r}")


DEFAULT_MACHINE = MachineAxes()


def parse_gcode(text: str, *, file: str = "<string>", start: Point | None = None,
                machine: MachineAxes = DEFAULT_MACHINE,
                dialect: Dialect = Dialect.LINUXCNC, tools: ToolTable = NO_TOOLS,
                offsets: WorkOffsets | None = None, pauses: Pauses = Pauses.NONE,
                ) -> GCodeProgram:
    """Interpret a G-code program into moves.

    Parameters:
        text: the program.
        file: the name used in errors and in the result.
        start: where the machine stands when the program starts (machine coordinates, mm,
            one per axis of ``machine.axes``; zeros when not given): the first move
            starts there, as LinuxCNC's interpreter starts from the machine's current
            position.
        machine: the axes (X, Y, Z by default), and where homing leaves them.
        dialect: whose reading of G-code the program follows (LinuxCNC's by default).
        tools: the tool table (default: none, every tool of zero length).
        offsets: the work offsets and stored positions the program starts with (default:
            all zero, G54; a parameter file's offsets:
            :func:`~usbmotion.motion.offsets.read_parameter_file`).
        pauses: which of M0, M1 and M6 pause the program (:class:`Pauses`; none by
            default: they are listed as ignored words).

    Raises:
        UnsupportedGCodeError: a word that would change the geometry is not supported.
        GCodeError: the program is invalid (bad syntax, bad arc, no feed rate, no
            program end, ...); ``file``, ``line``, ``column`` and ``word`` locate it.
    """
    program, error = interpret_until_error(text, file=file, start=start, machine=machine,
                                           dialect=dialect, tools=tools, offsets=offsets,
                                           pauses=pauses)
    if error is not None:
        raise error
    return program


def interpret_until_error(
    text: str, *, file: str = "<string>", start: Point | None = None,
    machine: MachineAxes = DEFAULT_MACHINE, dialect: Dialect = Dialect.LINUXCNC,
    tools: ToolTable = NO_TOOLS, offsets: WorkOffsets | None = None,
    pauses: Pauses = Pauses.NONE,
) -> tuple[GCodeProgram, GCodeError | None]:
    """Interpret a G-code program, keeping the moves made before an error.

    Returns the program (complete, or up to the block before the error) and the error,
    or ``None`` when the program is valid. Never raises for bad G-code. ``start``,
    ``machine``, ``dialect``, ``tools``, ``offsets`` and ``pauses`` are as
    :func:`parse_gcode`'s.

    Raises:
        ValueError: ``start`` has not one coordinate per axis of ``machine.axes``.
    """
    interpreter = _Interpreter(file, machine, RULES[dialect], tools, offsets or NO_OFFSETS,
                               pauses)
    interpreter.start_at(start)
    rules = interpreter.rules
    error: GCodeError | None = None
    try:
        interpreter.run(_blocks(text, file, rules), text)
    except GCodeError as exc:
        error = exc
    return interpreter.result(), error


@dataclass(frozen=True, slots=True)
class Modes:
    """A stream's modal state: the motion mode (its :class:`GCode`, or :data:`NO_MOTION`
    after G80), the
    coordinate system (1 = G54 .. 9 = G59.3), the plane (17, 18, 19), inches (G20) or mm,
    incremental (G91) or absolute, the feed (mm/min), the tool in the spindle, and the
    offset from machine to program coordinates (G5x + G92 + tool, mm, per axis)."""

    motion_x10: int
    coordinate_system: int
    plane: int
    inches: bool
    incremental: bool
    feed_mm_min: float
    tool: int
    offset_mm: Point
    g92_mm: Point = ()
    """The G92 offset as it applies now (zeros while suspended), per axis."""
    inverse_time: bool = False
    """G93 (inverse time feed: ``feed_mm_min`` is then F, per minute), not G94."""
    tool_mm: Point = ()
    """The tool length offset in effect (G43, G43.1; zeros after G49), per axis."""


_MODAL_STATE = ("position", "frame", "offset", "tools", "cycle", "retract_to_r", "scale",
                "scales", "inverse_time", "incremental", "arc_incremental", "plane", "motion",
                "feed_mm_min", "ended_by", "end_line")
"""What a line may change of the interpreter's state besides what it adds (a failed line
of a stream is undone)."""


class GCodeStream:
    """G-code read one line at a time, the machine's modal state kept between lines: what a
    console, a sender or a file streamed into a running machine gives.

    Parameters are :func:`parse_gcode`'s; ``file`` names the stream in errors. A ``%`` line
    is skipped (a stream has no first or last line to mark). Once a line ends the program
    (M2, M30) no other line is taken until :meth:`restart` (a new program, the modal state
    as the end left it) or :meth:`reset` (a controller reset).

    Raises:
        ValueError: ``start`` has not one coordinate per axis of ``machine.axes``.
    """

    def __init__(self, *, file: str = "<stream>", start: Point | None = None,
                 machine: MachineAxes = DEFAULT_MACHINE, dialect: Dialect = Dialect.LINUXCNC,
                 tools: ToolTable = NO_TOOLS, offsets: WorkOffsets | None = None,
                 pauses: Pauses = Pauses.NONE) -> None:
        self._interpreter = _Interpreter(file, machine, RULES[dialect], tools,
                                         offsets or NO_OFFSETS, pauses)
        self._interpreter.start_at(start)
        self.lines = 0
        """The lines fed so far (the number of the last one)."""

    @property
    def ended_by(self) -> str:
        """``"M2"`` or ``"M30"`` once a line ended the program, else ``""``."""
        return self._interpreter.ended_by

    @property
    def moves(self) -> list[Move]:
        """Every move so far, in order (read-only by convention)."""
        return self._interpreter.moves

    @property
    def pauses(self) -> list[Pause]:
        """Every program pause so far, in order."""
        return self._interpreter.pauses

    @property
    def position(self) -> Point:
        """Where the machine stands after the lines fed so far (machine coordinates, mm)."""
        return _point(self._interpreter.position)

    def feed(self, text: str, *, line: int | None = None,
             check: Callable[[list[Move]], None] | None = None) -> list[Move]:
        """Interpret one line (its number ``line``, else the next one); the moves it adds.

        ``check`` is called with the line's moves and may refuse them by raising (soft
        limits). A line that fails adds nothing: its moves, pauses and ignored words are
        dropped.

        Raises:
            GCodeError: the line is invalid, holds more than one line, or comes after the
                program's end; its ``line`` is the line's number.
            Exception: what ``check`` raised.
        """
        state = self._interpreter
        number = self.lines + 1 if line is None else line
        self.lines = number
        if state.ended_by:
            raise GCodeError(f"the program ended at line {state.end_line} ({state.ended_by});"
                             " no line is taken after it", file=state.file, line=number)
        if "\n" in text.rstrip("\r\n"):
            raise GCodeError("one line at a time: this text holds a line break",
                             file=state.file, line=number)
        marks = (len(state.moves), len(state.pauses), len(state.ignored),
                 len(state.tool_changes), len(state.frames), len(state.outputs))
        modes = {name: copy.deepcopy(getattr(state, name)) for name in _MODAL_STATE}
        rules = state.rules
        try:
            for block in _blocks(text.rstrip("\r\n"), state.file, rules):
                if not block.delimiter:
                    state.execute(block._replace(line=number))
            added = state.moves[marks[0]:]
            if check is not None and added:
                check(added)
        except Exception as error:
            if isinstance(error, GCodeError):
                error.line = number
            moves, pauses, ignored, changes, frames, outputs = marks
            del state.moves[moves:], state.pauses[pauses:], state.ignored[ignored:]
            del state.tool_changes[changes:], state.frames[frames:], state.outputs[outputs:]
            for name, value in modes.items():
                setattr(state, name, value)
            raise
        return added

    def modes(self) -> Modes:
        """The modal state now (what a controller's ``$G`` reports)."""
        state = self._interpreter
        plane = _CODE_OF_PLANE[state.plane] // 10
        return Modes(motion_x10=state.motion, coordinate_system=state.frame.system + 1,
                     plane=plane, inches=state.scale != 1.0, incremental=state.incremental,
                     feed_mm_min=state.feed_mm_min, tool=state.tools.spindle,
                     offset_mm=_point(state.offset), g92_mm=_point(state.frame.active_g92()),
                     inverse_time=state.inverse_time, tool_mm=_point(state.frame.tool))

    def use_tools(self, table: ToolTable) -> None:
        """The tool table the next lines read (one changed on disk: a tool measured); the
        offset a ``G43`` already applied stays until the next ``G43``, as in LinuxCNC."""
        self._interpreter.tools.table = table

    def restart(self, start: Point) -> None:
        """A new program from ``start`` (where the machine stands), the modal state kept:
        the moves, pauses, ignored words and tool changes so far are dropped, and lines
        are taken again after an M2 or M30.

        Raises:
            ValueError: ``start`` has not one coordinate per axis.
        """
        state = self._interpreter
        state.start_at(start)
        del state.moves[:], state.pauses[:], state.ignored[:], state.tool_changes[:]
        del state.outputs[:]
        state.frames[:] = [(0, _point(state.offset))]
        state.ended_by = ""
        state.end_line = 0

    def reset(self, start: Point) -> None:
        """A controller reset (grbl's soft reset, Ctrl-X; Marlin's restart; LinuxCNC's
        abort) with the machine at ``start``: the program so far is dropped as by
        :meth:`restart`, and what the dialect's reset clears is cleared.

        In grbl and Marlin the modal state goes back to power-on (``gc_init``: G54, G17,
        G21, G90, G91.1, G98, the dialect's motion mode, feed 0, no tool length offset,
        tool 0) and the G92 offset is cleared. LinuxCNC's abort keeps the modal state and
        the G92 offset. In every dialect the work offsets (G10), the stored positions
        (G28.1, G30.1) and the tool table stay.

        Raises:
            ValueError: ``start`` has not one coordinate per axis.
        """
        state = self._interpreter
        if state.rules.reset_modes:
            offsets = replace(state.frame.snapshot(), coordinate_system=1)
            self._interpreter = _Interpreter(state.file, state.machine, state.rules,
                                             state.tools.table, offsets, state.pause_rule)
        self.restart(start)

    def result(self) -> GCodeProgram:
        """The program so far (``ended_by`` ``""`` while it has not ended)."""
        program = self._interpreter.result()
        if not program.ended_by:
            return GCodeProgram(program.moves, program.ignored, program.file, self.lines,
                                "", program.axes, program.dialect, program.offsets,
                                program.tool_changes, program.pauses, program.frames,
                                program.outputs)
        return program


def interpret_setting(
    text: str, *, file: str = "<console>", start: Point | None = None,
    machine: MachineAxes = DEFAULT_MACHINE, dialect: Dialect = Dialect.LINUXCNC,
    tools: ToolTable = NO_TOOLS, offsets: WorkOffsets | None = None,
) -> WorkOffsets:
    """Carry out lines that set offsets without moving (``G10 L20 P1 X0 Y0``, ``G10 L2``,
    ``G92``, ``G28.1``), as a console's command line does, with the machine at ``start``
    (one coordinate per axis of ``machine.axes``); returns the work offsets they leave.

    Raises:
        GCodeError: a line is invalid, it would move the machine or end a program (the
            message says what is allowed), or it sets the G92 offset in a dialect where
            that offset is volatile (grbl, Marlin: no setting keeps it).
        ValueError: ``start`` has not one coordinate per axis of ``machine.axes``.
    """
    interpreter = _Interpreter(file, machine, RULES[dialect], tools, offsets or NO_OFFSETS)
    interpreter.start_at(start)
    rules = interpreter.rules
    for block in _blocks(text, file, rules):
        if block.delimiter:
            continue
        if rules.g92_volatile:
            interpreter.refuse_volatile_g92(block)
        interpreter.execute(block)
        if interpreter.moves or interpreter.ended_by:
            raise GCodeError(
                "this line would move the machine or end a program; allowed here: lines that "
                "set offsets (G10 L2, G10 L20, G92, G92.1-G92.3, G28.1, G30.1)",
                file=file, line=block.line, column=1,
            )
    return interpreter.frame.snapshot()


def read_gcode_text(path: str | os.PathLike[str]) -> str:
    """Read a G-code file as text: UTF-8, or Latin-1 when it is not valid UTF-8.

    Raises:
        OSError: the file cannot be read.
    """
    data = Path(path).read_bytes()
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        return data.decode("latin-1")


def load_gcode(path: str | os.PathLike[str], *, start: Point | None = None,
               machine: MachineAxes = DEFAULT_MACHINE, dialect: Dialect = Dialect.LINUXCNC,
               tools: ToolTable = NO_TOOLS, offsets: WorkOffsets | None = None) -> GCodeProgram:
    """Read and interpret a G-code file (see :func:`parse_gcode`).

    Raises:
        OSError: the file cannot be read.
        GCodeError: as :func:`parse_gcode`, with ``file`` set to ``path``.
    """
    return parse_gcode(read_gcode_text(path), file=os.fspath(path), start=start,
                       machine=machine, dialect=dialect, tools=tools, offsets=offsets)


def move_record(move: Move, *, axes: str = DEFAULT_AXES) -> dict[str, object]:
    """A move as a JSON-ready record in the conformance schema (lengths in mm).

    Rapid, linear and arc records have ``line``, ``type``, ``start`` and ``end``; linear
    and arc add ``feed`` (as LinuxCNC states it: :func:`programmed_feed`); arcs add
    ``plane`` (``"XY"``, ``"XZ"``, ``"YZ"``), ``direction`` (``"cw"``/``"ccw"``),
    ``rotation`` and ``centre`` (the coordinate
    along the plane's normal is ``None``). Dwells have ``line``, ``type``, ``seconds``
    and ``position``. Points have one coordinate per letter of ``axes``.
    """
    if isinstance(move, Rapid):
        return {
            "line": move.line,
            "type": "rapid",
            "start": list(move.start),
            "end": list(move.end),
        }
    if isinstance(move, Linear):
        return {
            "line": move.line,
            "type": "linear",
            "start": list(move.start),
            "end": list(move.end),
            "feed": programmed_feed(move, axes),
        }
    if isinstance(move, Arc):
        normal = move.plane.indices(axes)[2]
        centre: list[float | None] = list(move.centre)
        if normal >= 0:
            centre[normal] = None
        return {
            "line": move.line,
            "type": "arc",
            "start": list(move.start),
            "end": list(move.end),
            "plane": move.plane.value,
            "direction": "cw" if move.rotation < 0 else "ccw",
            "rotation": move.rotation,
            "centre": centre,
            "feed": programmed_feed(move, axes),
        }
    return {
        "line": move.line,
        "type": "dwell",
        "seconds": move.seconds,
        "position": list(move.position),
    }


# --- the interpreter -----------------------------------------------------------------------


class _Interpreter:
    """The machine state while a program is read; one instance per program."""

    __slots__ = (
        "arc_incremental",
        "axes",
        "axis_set",
        "cycle",
        "end_line",
        "ended_by",
        "feed_lengths",
        "feed_mm_min",
        "file",
        "frame",
        "frames",
        "g_codes",
        "ignored",
        "ignored_letters",
        "incremental",
        "inverse_time",
        "laser_mode",
        "laser_power",
        "m_codes",
        "machine",
        "motion",
        "moves",
        "offset",
        "output_values",
        "outputs",
        "pause_rule",
        "pauses",
        "plane",
        "planes",
        "position",
        "refused_letters",
        "retract_to_r",
        "rules",
        "scale",
        "scales",
        "spindle_rpm",
        "spindle_speed",
        "spindle_turn",
        "tool_changes",
        "tools",
    )

    def __init__(self, file: str, machine: MachineAxes = DEFAULT_MACHINE,
                 rules: DialectRules = RULES[Dialect.LINUXCNC], tools: ToolTable = NO_TOOLS,
                 offsets: WorkOffsets = NO_OFFSETS, pauses: Pauses = Pauses.NONE) -> None:
        self.file = file
        self.pause_rule = pauses
        self.pauses: list[Pause] = []
        self.spindle_speed = 0.0  # S, rpm
        self.spindle_turn = 0  # M3 1, M4 -1, M5 0
        self.spindle_rpm = 0.0  # the speed the spindle was last told, signed
        self.outputs: list[OutputChange] = []
        self.output_values = dict.fromkeys(OUTPUT_NAMES, 0)  # as last changed
        self.laser_power = 0  # S as per mille of laser_max_s
        self.laser_mode = 0  # M3 1 (constant), M4 2 (dynamic), M5 0
        self.machine = machine
        self.rules = rules
        axes = machine.axes
        self.axes = axes
        self.axis_set = frozenset(axes)
        self.position = [0.0] * len(axes)  # machine, mm
        self.frame = Frame(offsets, axes, g92_volatile=rules.g92_volatile)
        self.offset = self.frame.translation  # G5x + G92 + tool, mm (with no rotation)
        self.frames: list[tuple[int, Point]] = [(0, _point(self.offset))]
        self.tools = _ToolState(tools)
        self.tool_changes: list[ToolChange] = []
        self.cycle = _CycleSeries()
        self.retract_to_r = False  # G99; G98 (retract to the initial level) at the start
        self.scale = 1.0  # mm per program unit
        self.scales = [1.0] * len(axes)  # per axis: mm (degrees for A B C) per program unit
        self.inverse_time = False  # G93
        self.feed_lengths = _feed_lengths(axes)
        self.incremental = False
        self.arc_incremental = True
        self.plane = Plane.XY
        self.motion = rules.start_motion  # the motion mode's G code, or NO_MOTION
        self.feed_mm_min = 0.0
        self.moves: list[Move] = []
        self.ignored: list[IgnoredWord] = []
        self.ended_by = ""
        self.end_line = 0
        self.planes = _plane_indices(axes)
        self.refused_letters, self.ignored_letters = _letter_tables(axes, rules)
        self.g_codes, self.m_codes = _code_tables(rules)

    def result(self) -> GCodeProgram:
        return GCodeProgram(
            moves=tuple(self.moves),
            ignored=tuple(self.ignored),
            file=self.file,
            end_line=self.end_line,
            ended_by=self.ended_by,
            axes=self.axes,
            dialect=self.rules.dialect,
            offsets=self.frame.snapshot(),
            tool_changes=tuple(self.tool_changes),
            pauses=tuple(self.pauses),
            frames=tuple(self.frames),
            outputs=tuple(self.outputs),
        )

    def start_at(self, start: Point | None) -> None:
        """Stand the machine at ``start`` (one coordinate per axis; zeros when ``None``).

        Raises:
            ValueError: ``start`` has not one coordinate per axis.
        """
        if start is None:
            return
        if len(start) != len(self.axes):
            raise ValueError(f"start {start!r} needs one coordinate per axis of"
                             f" {self.axes!r}")
        self.position = [float(value) for value in start]

    def reframe(self) -> None:
        """Take up a change of offsets: the machine stays where it is."""
        self.frame.update()
        self.offset = self.frame.translation
        self.frames.append((len(self.moves), _point(self.offset)))

    def end_program(self, ended_by: str, line: int) -> None:
        """M2, M30 or a closing '%': what LinuxCNC's M2 and M30 reset that this interpreter
        keeps (G54, G17, G90, the motion mode G1; a canned cycle series ends), and the G92
        offset suspended as G92.2 does (cleared where it is volatile: grbl, Marlin)."""
        self.ended_by = ended_by
        self.end_line = line
        for name in self.machine.outputs:  # and switch the coolant and the laser off
            if name == "laser":
                self.laser_mode = 0
            self.set_output(line, name, 0)
        if self.machine.spindle_max_rpm:  # M2 and M30 stop the spindle (LinuxCNC, grbl)
            self.spindle_turn = 0
            self.spindle_rpm = 0.0
            self.pause(line, ended_by, "spindle stop at the program's end", spindle_rpm=0.0)
        frame = self.frame
        frame.system = 0
        if self.rules.g92_volatile:
            frame.clear_g92()
        else:
            frame.g92_enabled = False
        self.plane = Plane.XY
        self.incremental = False
        self.motion = _G_1
        self.cycle.level = None
        self.reframe()

    def run(self, blocks: Iterable[Block], text: str) -> None:
        percent = False
        first = True
        for block in blocks:
            if block.delimiter:
                if first:
                    percent = True
                    first = False
                    continue
                if percent:
                    self.end_program("%", block.line)
                    return
                raise GCodeError(
                    "'%' ends a program only when the program also opens with a '%' line",
                    file=self.file,
                    line=block.line,
                    column=block.source.index("%") + 1,
                    word="%",
                )
            first = False
            self.execute(block)
            if self.ended_by:
                return
        last_line = max(1, text.count("\n") + (0 if text.endswith("\n") else 1))
        if not self.rules.needs_end and not percent:
            self.ended_by = "end of text"
            self.end_line = last_line
            return
        if percent:
            message = "the program opens with '%' but ends without a closing '%' line (or M2/M30)"
        else:
            message = ("the program ends without M2, M30 or '%': end it with M2 or M30, or"
                       " read it as grbl or Marlin do, which need no end (--dialect grbl or"
                       " --dialect marlin)")
        raise GCodeError(message, file=self.file, line=last_line, column=0)

    # --- one block ---------------------------------------------------------------------

    def error(self, block: Block, index: int, message: str) -> GCodeError:
        """The error for word ``index`` of ``block`` (its column and text).

        ``index`` -1 stands for the block's first axis or arc centre word (the motion of a
        line that has no motion G code), or its first word.
        """
        if index < 0:
            coveted = self.axes + "IJKR"
            index = next((i for i, c in enumerate(block.letters) if c in coveted), 0)
        column = word_columns(block)[index]
        word = block.letters[index] + block.numbers[index]
        return GCodeError(message, file=self.file, line=block.line, column=column, word=word)

    def unsupported(self, block: Block, index: int, reason: str) -> UnsupportedGCodeError:
        """The error for word ``index`` of ``block``, which is not supported for ``reason``."""
        word = block.letters[index] + block.numbers[index]
        dollar = block.letters == "$"
        column = block.source.index("$") + 1 if dollar else word_columns(block)[index]
        return UnsupportedGCodeError(
            f"{word}: {reason}",
            file=self.file,
            line=block.line,
            column=column,
            word=word,
            reason=reason,
        )

    def execute(self, block: Block) -> None:
        letters = block.letters
        values = block.values
        numbers = block.numbers
        params: dict[str, float] = {}
        where: dict[str, int] = {}
        g_codes: dict[ModalGroup, int] = {}  # modal group -> code x10
        g_where: dict[ModalGroup, int] = {}
        m_codes: dict[int, int] = {}  # M group (MGroup, or a dialect's own) -> code
        m_where: dict[int, int] = {}
        ignored: list[tuple[int, str]] = []  # (word index, meaning)
        g_table = self.g_codes
        m_table = self.m_codes
        refused = self.refused_letters
        ignored_letters = self.ignored_letters

        # Read the words in order, as LinuxCNC's read_items does.
        for index, letter in enumerate(letters):
            if letter == "G":
                code = _G_SPELLINGS.get(numbers[index])
                if code is None:
                    code = self.g_code(block, index)
                entry = g_table.get(code)
                if entry is None:
                    raise self.unsupported(block, index, self.g_reason(code))
                group, kind, meaning = entry
                previous = g_codes.get(group)
                if previous is not None and _G_80 not in (code, previous):
                    raise self.error(
                        block,
                        index,
                        f"G{numbers[index]} and {g_code_text(previous)} are both in the "
                        f"{group.description} group; a line may hold one of each group",
                    )
                if previous is None or previous == _G_80:
                    g_codes[group] = code
                    g_where[group] = index
                if kind == _IGNORED:
                    ignored.append((index, meaning))
            elif letter == "M":
                code = self.m_code(block, index)
                m_entry = m_table.get(code)
                if m_entry is None:
                    raise self.unsupported(block, index, self.m_reason(code))
                m_group, meaning = m_entry
                if m_group in m_codes:
                    raise self.error(
                        block,
                        index,
                        f"M{numbers[index]} and M{m_codes[m_group]} are both in the "
                        f"{_m_group_description(m_group, code)} group; a line may hold"
                        " one of each group",
                    )
                if len(m_codes) == _MAX_M_CODES:
                    raise self.error(block, index, f"more than {_MAX_M_CODES} M codes on one line")
                m_codes[m_group] = code
                m_where[m_group] = index
                if code not in _M_ACTING:
                    ignored.append((index, meaning))
            elif letter == "N":
                continue
            elif letter in params:
                raise self.error(
                    block,
                    index,
                    f"{letter} appears twice on this line ({letter}{numbers[where[letter]]} "
                    f"and {letter}{numbers[index]}); a word may appear once per line",
                )
            else:
                if letter in refused:
                    if letter == "$":
                        self.controller_command(block)
                        return
                    raise self.unsupported(block, index, refused[letter])
                value = values[index]
                if not -_LARGEST < value < _LARGEST:
                    raise self.error(
                        block,
                        index,
                        f"{letter}{numbers[index]} is out of range: at most {_LARGEST:g} "
                        "in magnitude",
                    )
                if value < 0.0 and letter in _NOT_NEGATIVE:
                    raise self.error(
                        block,
                        index,
                        f"{letter}{numbers[index]}: a {_NOT_NEGATIVE[letter]} is not negative",
                    )
                params[letter] = value
                where[letter] = index
                letter_meaning = ignored_letters.get(letter)
                if letter_meaning is not None:
                    ignored.append((index, letter_meaning))

        if m_codes and self.rules.m_codes:
            self.take_m_parameters(block, m_codes, params, where, ignored)
        motion = self.check(block, params, where, g_codes, g_where, m_codes, m_where, ignored)

        # Act, in LinuxCNC's order of execution.
        feed_mode = g_codes.get(_GM_FEED_MODE)
        if feed_mode is not None and (feed_mode == _G_93) != self.inverse_time:
            self.inverse_time = feed_mode == _G_93
            self.feed_mm_min = 0.0  # LinuxCNC sets the feed rate to 0 on a change of mode
        if "F" in params:
            self.feed_mm_min = params["F"] * (1.0 if self.inverse_time else self.scale)
        if "T" in params or _MG_TOOL_CHANGE in m_codes:
            self.change_tool(block, params, where, m_codes, m_where)
        if self.machine.outputs:
            acted = self.output_words(block, params, where, m_codes, m_where)
            ignored = [(i, meaning) for i, meaning in ignored if i not in acted]
        if self.machine.spindle_max_rpm:
            self.spindle_words(block, params, where, m_codes)
            spindle_words = {where["S"]} if "S" in where else set()
            if _MG_SPINDLE in m_where:
                spindle_words.add(m_where[_MG_SPINDLE])
            ignored = [(i, meaning) for i, meaning in ignored if i not in spindle_words]
        if len(g_codes) > (_GM_MOTION in g_codes):  # G codes besides the motion one
            self.set_modes(block, g_codes, g_where, params, where)
        if motion != NO_MOTION:
            if g_codes.get(_GM_MODAL_0) == _G_53:
                self.machine_move(block, motion, params)
            else:
                self.move(block, motion, params, where, g_where.get(_GM_MOTION, -1))
        stop = m_codes.get(_MG_STOPPING)
        if stop in _PAUSE_CODES and self.pauses_at(stop):
            held = m_where[_MG_STOPPING]
            ignored = [(i, meaning) for i, meaning in ignored if i != held]
            self.pause(block.line, f"M{stop}", "program pause" if stop == _M_0 else
                       "optional program pause (optional stop is on)")
        if ignored:
            columns = word_columns(block)
            self.ignored.extend(
                IgnoredWord(letters[i] + numbers[i], block.line, columns[i], meaning)
                for i, meaning in sorted(ignored)
            )
        if stop in _M_END:
            self.end_program(_M_END[stop], block.line)

    def pauses_at(self, code: int) -> bool:
        """Whether M``code`` (M0, M1 or M6) pauses the program under its pause rule."""
        rule = self.pause_rule
        if rule is Pauses.NONE:
            return False
        return code != _M_1 or rule is Pauses.OPTIONAL

    def pause(self, line: int, code: str, message: str, *,
              spindle_rpm: float | None = None) -> None:
        """The machine to rest where it stands, waiting for the operator's cycle start (or,
        a spindle pause, for the spindle to reach ``spindle_rpm``)."""
        self.pauses.append(Pause(line, code, message, len(self.moves), spindle_rpm))
        self.moves.append(Dwell(line, _point(self.position), 0.0))

    def output_words(self, block: Block, params: dict[str, float], where: dict[str, int],
                     m_codes: dict[int, int], m_where: dict[int, int]) -> set[int]:
        """``M7``/``M8``/``M9`` on a machine with coolant outputs, and ``M3``/``M4``/``M5``
        with ``S`` on one with a laser: the changes they make (:class:`OutputChange`), from
        the line's motion on; the indices of the words acted on."""
        has = self.machine.outputs
        acted: set[int] = set()
        coolant = m_codes.get(_MG_COOLANT)
        if coolant is not None:
            wanted = ({"mist": 1000} if coolant == _M_7 else {"flood": 1000}
                      if coolant == _M_8 else {"mist": 0, "flood": 0})
            if any(name in has for name in wanted):
                acted.add(m_where[_MG_COOLANT])
            for name, value in wanted.items():
                if name in has:
                    self.set_output(block.line, name, value)
        if "laser" in has:
            top = self.machine.laser_max_s
            power = params.get("S")
            if power is not None:
                if power > top:
                    raise self.error(block, where["S"], f"S{power:g} is beyond the laser's"
                                     f" laser_max_s {top:g} (full power); allowed: 0..{top:g}")
                self.laser_power = round(power / top * 1000)
                acted.add(where["S"])
            code = m_codes.get(_MG_SPINDLE)
            if code is not None:
                self.laser_mode = 1 if code == _M_3 else 2 if code == _M_4 else 0
                acted.add(m_where[_MG_SPINDLE])
            value = self.laser_power if self.laser_mode else 0
            dynamic = self.laser_mode == 2
            last = self.outputs_last("laser")
            if last is None or (last.value, last.dynamic) != (value, dynamic):
                if last is not None or value:
                    self.outputs.append(OutputChange(block.line, "laser", value, dynamic))
                self.output_values["laser"] = value
        return acted

    def set_output(self, line: int, name: str, value: int) -> None:
        """Output ``name`` to ``value`` from ``line`` on (nothing when it is so already)."""
        if self.output_values.get(name) != value:
            self.output_values[name] = value
            self.outputs.append(OutputChange(line, name, value))

    def outputs_last(self, name: str) -> OutputChange | None:
        """The last change of output ``name``, if any."""
        for change in reversed(self.outputs):
            if change.output == name:
                return change
        return None

    def spindle_words(self, block: Block, params: dict[str, float], where: dict[str, int],
                      m_codes: dict[int, int]) -> None:
        """``S`` and ``M3``/``M4``/``M5`` on a machine with a spindle, in LinuxCNC's order
        (the speed, then the direction, both before the line's motion): a spindle pause
        whenever the speed the spindle is to turn at may change."""
        speed = params.get("S")
        if speed is not None:
            top = self.machine.spindle_max_rpm
            if speed > top:
                raise self.error(block, where["S"], f"S{speed:g} is beyond the spindle's"
                                 f" max_rpm {top:g}; allowed: 0..{top:g} rpm")
            self.spindle_speed = speed
        code = m_codes.get(_MG_SPINDLE)
        if code is not None:
            self.spindle_turn = 1 if code == _M_3 else -1 if code == _M_4 else 0
        rpm = self.spindle_turn * self.spindle_speed
        if code is not None or rpm != self.spindle_rpm:
            self.spindle_rpm = rpm
            said = f"M{code}" if code is not None else "S"
            message = (f"spindle to {abs(rpm):g} rpm" + (" counter-clockwise" if rpm < 0 else "")
                       if rpm else "spindle stop")
            self.pause(block.line, said, message, spindle_rpm=rpm)

    def set_modes(self, block: Block, g_codes: dict[ModalGroup, int],
                  g_where: dict[ModalGroup, int], params: dict[str, float],
                  where: dict[str, int]) -> None:
        """Apply the block's G codes other than motion, in LinuxCNC's order."""
        group0 = g_codes.get(_GM_MODAL_0)
        if group0 == _G_4:
            self.dwell(block, params)
        plane = g_codes.get(_GM_SET_PLANE)
        if plane is not None:
            self.plane = _PLANE_OF_CODE[plane]
        units = g_codes.get(_GM_LENGTH_UNITS)
        if units is not None:
            self.scale = MM_PER_INCH if units == _G_20 else 1.0
            self.scales = [1.0 if letter in ROTARY_AXES else self.scale
                           for letter in self.axes]
        tool_length = g_codes.get(_GM_TOOL_LENGTH_OFFSET)
        if tool_length is not None:
            self.tool_length(block, tool_length, g_where[_GM_TOOL_LENGTH_OFFSET],
                             params, where)
        system = g_codes.get(_GM_COORD_SYSTEM)
        if system is not None:
            self.frame.system = _SYSTEM_INDEX[system]
            self.reframe()
        distance = g_codes.get(_GM_DISTANCE_MODE)
        if distance is not None:
            self.incremental = distance == _G_91
        arc_distance = g_codes.get(_GM_IJK_DISTANCE_MODE)
        if arc_distance is not None:
            self.arc_incremental = arc_distance == _G_91_1
        retract = g_codes.get(_GM_RETRACT_MODE)
        if retract is not None:
            self.retract_to_r = retract == _G_99
        if group0 == _G_10:
            self.set_offsets(block, g_where[_GM_MODAL_0], params, where)
        elif group0 is not None and group0 not in (_G_4, _G_53):
            self.non_modal(block, group0, params)
        applied = g_codes.get(_GM_G92_IS_APPLIED)
        if applied is not None:
            self.g92_applied(applied)

    def g_code(self, block: Block, index: int) -> int:
        """Ten times the G number (G90.1 -> 901), checked as LinuxCNC's read_g does."""
        tenfold = block.values[index] * 10.0
        code = math.floor(tenfold)
        if tenfold - code > 0.999:
            code = math.ceil(tenfold)
        elif tenfold - code > 0.001:
            raise self.error(
                block,
                index,
                f"G{block.numbers[index]} is not a G code: G numbers have at most one "
                "decimal (G90.1)",
            )
        if code < 0:
            raise self.error(block, index, f"G{block.numbers[index]}: G codes are not negative")
        return code

    def m_code(self, block: Block, index: int) -> int:
        """The M number, which must be a whole number (as LinuxCNC's read_m)."""
        value = block.values[index]
        code = math.floor(value)
        if value - code > 0.9999:
            code = math.ceil(value)
        elif value - code > 0.0001:
            raise self.error(block, index, f"M{block.numbers[index]}: M codes are whole numbers")
        if code < 0:
            raise self.error(block, index, f"M{block.numbers[index]}: M codes are not negative")
        return code

    def check(
        self,
        block: Block,
        params: dict[str, float],
        where: dict[str, int],
        g_codes: dict[ModalGroup, int],
        g_where: dict[ModalGroup, int],
        m_codes: dict[int, int],
        m_where: dict[int, int],
        ignored: list[tuple[int, str]],
    ) -> int:
        """Check the block as a whole; return the motion it makes (its G code, or
        :data:`NO_MOTION`)."""
        group0 = g_codes.get(_GM_MODAL_0, -1)
        motion_word = g_codes.get(_GM_MOTION, NO_MOTION)
        has_axis = not self.axis_set.isdisjoint(params)
        tool_length = g_codes.get(_GM_TOOL_LENGTH_OFFSET, -1)
        covets_axes = group0 in _AXIS_CODES or tool_length == _G_43_1
        coveter = group0 if group0 in _AXIS_CODES else tool_length
        if motion_word != NO_MOTION:
            if motion_word == _G_80:
                if has_axis and not covets_axes:
                    raise self.error(
                        block,
                        _first_of(where, self.axes),
                        "axis words cannot be used with G80, which cancels the motion mode",
                    )
            elif covets_axes:
                raise self.error(
                    block,
                    g_where[_GM_MOTION],
                    f"{g_code_text(motion_word)} and {g_code_text(coveter)} both use the "
                    "axis words; put them on separate lines",
                )
            motion = motion_word
        elif has_axis and not covets_axes:
            if self.motion == NO_MOTION:
                raise self.error(
                    block,
                    _first_of(where, self.axes),
                    "axis word with no motion mode: no G0, G1, G2 or G3 is active (a "
                    "program starts with none, and G80 cancels it); add one to this line",
                )
            motion = self.motion
        elif (
            not covets_axes
            and self.motion in _ARCS
            and ("I" in params or "J" in params or "K" in params)
        ):
            motion = self.motion  # a line such as "I1" continues the arc mode
        else:
            motion = NO_MOTION
        if group0 == _G_92 and not has_axis and not (
                "E" in params and "E" in self.ignored_letters):
            raise self.error(block, g_where[_GM_MODAL_0], "G92 needs at least one axis"
                             f" word ({', '.join(self.axes)})")
        if group0 == _G_53:
            self.check_machine_move(block, g_where[_GM_MODAL_0], motion, g_codes)

        arc = motion in _ARCS
        cycle = motion in CYCLE_NAMES
        if group0 == _G_4:
            self.check_dwell(block, params, where, g_where[_GM_MODAL_0], motion, ignored)
        if not arc:
            for letter in "IJK":
                if letter in params:
                    raise self.error(
                        block, where[letter], f"{letter} word with no G2 or G3 to use it"
                    )
            if "R" in params and not cycle and group0 != _G_10:
                raise self.error(
                    block, where["R"],
                    "R word with no G2, G3, canned cycle or G10 L2 to use it",
                )
        if "L" in params and not cycle and group0 != _G_10:
            raise self.error(block, where["L"], "L word with no G10 or canned cycle to use it")
        path_control = g_codes.get(_GM_CONTROL_MODE)
        override = m_codes.get(_MG_OVERRIDES)
        tool_change = m_codes.get(_MG_TOOL_CHANGE)
        if "P" in params:
            index = where["P"]
            if arc:
                turns = round(params["P"])
                if abs(turns - params["P"]) > 0.001 or turns < 1:
                    raise self.error(
                        block,
                        index,
                        f"P{block.numbers[index]} with G2/G3 is the number of turns: a whole "
                        "number, 1 or more",
                    )
            elif motion in (_G_82, _G_89) or group0 == _G_10:
                pass
            elif group0 != _G_4:
                if path_control != _G_64 and override not in _OVERRIDE_CODES:
                    raise self.error(
                        block, index,
                        "P word with no G2, G3, G4, G10, G82, G89, G64 or M50-M53 to use it",
                    )
                ignored.append((index, "parameter of an ignored code (G64, M50-M53)"))
        if "Q" in params and motion not in _PECKS:
            if path_control != _G_64 and tool_change != _M_61:
                raise self.error(
                    block, where["Q"], "Q word with no G73, G83, G64 or M61 to use it"
                )
            if tool_change != _M_61:
                ignored.append((where["Q"], "parameter of an ignored code (G64)"))
        if tool_change == _M_61:
            if "Q" not in params:
                raise self.error(block, m_where[_MG_TOOL_CHANGE],
                                 "M61 needs Q, the tool number")
            self.check_tool_number(block, where["Q"], "M61 Q", params["Q"])
        if "H" in params and tool_length != _G_43:
            ignored.append((where["H"], _H_WITHOUT_G43))
        if g_codes.get(_GM_SPINDLE_MODE) == _G_96 and "S" not in params:
            raise self.error(block, g_where[_GM_SPINDLE_MODE],
                             "G96 needs S, the surface speed")
        if "T" in params:
            self.check_tool_number(block, where["T"], "T", params["T"])
        return motion

    def check_dwell(self, block: Block, params: dict[str, float], where: dict[str, int],
                    g4: int, motion: int, ignored: list[tuple[int, str]]) -> None:
        """Refuse a G4 without its time, with a negative one, or beside a motion that uses P
        too (an arc's turns, a cycle's dwell); in a dialect where ``G4 S`` is seconds, its S
        is the dwell's and not an ignored word."""
        rules = self.rules
        unit = "seconds" if rules.dwell_p_seconds == 1.0 else "milliseconds"
        letters = "PS" if rules.dwell_s else "P"
        given = [letter for letter in letters if letter in params]
        if not given:
            allowed = f"P, the dwell time in {unit}" + (
                ", or S, in seconds" if rules.dwell_s else "")
            raise self.error(block, g4, f"G4 needs {allowed}")
        if len(given) > 1:
            raise self.error(block, where["S"], "G4 with both P and S: give one dwell time")
        if motion in _ARCS and "P" in params:
            raise self.error(block, g4, "G4 cannot share a line with G2 or G3: both use P")
        if motion in CYCLE_NAMES:
            raise self.error(block, g4,
                             f"G4 cannot share a line with {CYCLE_NAMES[motion]}: both use P")
        letter = given[0]
        if params[letter] < 0.0:
            raise self.error(
                block,
                where[letter],
                f"G4 {letter}{block.numbers[where[letter]]}: a dwell time is not negative",
            )
        if letter == "S":
            ignored[:] = [entry for entry in ignored if entry[0] != where["S"]]

    def dwell(self, block: Block, params: dict[str, float]) -> None:
        seconds = params["P"] * self.rules.dwell_p_seconds if "P" in params else params["S"]
        self.moves.append(Dwell(block.line, _point(self.position), seconds))

    def non_modal(self, block: Block, code: int, params: dict[str, float]) -> None:
        """G28, G30 (or a dialect's homing G28), G28.1, G30.1 and G92."""
        frame = self.frame
        if code == _G_28 and self.rules.g28_homes:
            named = "".join(letter for letter in self.axes if letter in params)
            self.home(block.line, named or self.axes)
            return
        if code in (_G_28, _G_30):
            self.traverse(block.line, self.ends(params))
            home = frame.g28 if code == _G_28 else frame.g30
            named_axes = [axis for axis, letter in enumerate(self.axes) if letter in params]
            end = list(self.position)
            for axis in named_axes or range(len(self.axes)):
                end[axis] = home[axis]
            self.traverse(block.line, end)
            return
        if code == _G_28_1:
            frame.g28 = list(self.position)
            return
        if code == _G_30_1:
            frame.g30 = list(self.position)
            return
        frame.set_g92(self.position, {  # G92
            axis: params[letter] * self.scales[axis]
            for axis, letter in enumerate(self.axes) if letter in params
        })
        self.reframe()

    def g92_applied(self, code: int) -> None:
        """G92.1 (clear the offset and its stored value), G92.2 (suspend it), G92.3 (apply
        the stored value again)."""
        frame = self.frame
        if code == _G_92_1:
            frame.clear_g92()
        else:
            frame.g92_enabled = code == _G_92_3
        self.reframe()

    def set_offsets(self, block: Block, index: int, params: dict[str, float],
                    where: dict[str, int]) -> None:
        """G10 L2 (a system's offset, and R its rotation) or G10 L20 (a system's offset
        such that the current point reads the given values). Values are absolute."""
        if "L" not in params:
            raise self.error(block, index, "G10 needs L: L2 or L20 (coordinate system offsets)")
        level = params["L"]
        if level not in (2.0, 20.0):
            raise self.unsupported(block, where["L"], _G10_UNSUPPORTED)
        name = _G10_NAMES[int(level)]
        if "P" not in params:
            raise self.error(
                block, index,
                f"{name} needs P, the coordinate system: 0 (the active one) or 1 (G54) to "
                "9 (G59.3)",
            )
        number = params["P"]
        if number != round(number) or not 0 <= number <= len(COORDINATE_SYSTEMS):
            raise self.error(
                block, where["P"],
                f"{name} P{block.numbers[where['P']]}: the coordinate system is 0 (the active "
                "one) or 1 (G54) to 9 (G59.3)",
            )
        frame = self.frame
        system = int(number) - 1 if number else frame.system
        values = {axis: params[letter] * self.scales[axis]
                  for axis, letter in enumerate(self.axes) if letter in params}
        if level == 2.0:
            offset = frame.g5x[system]
            for axis, value in values.items():
                offset[axis] = value
            if "R" in params:
                if params["R"] != 0.0 and not frame.has_xy:
                    raise self.unsupported(
                        block, where["R"],
                        "a rotation turns X and Y, and the machine lacks one (its axes are "
                        f"{', '.join(self.axes)})",
                    )
                frame.rotation_deg[system] = params["R"]
        else:
            if "R" in params:
                raise self.error(
                    block, where["R"],
                    "G10 L20 takes no R: set a rotation with G10 L2 R",
                )
            frame.set_l20(system, self.position, values)
        self.reframe()

    def tool_length(self, block: Block, code: int, index: int, params: dict[str, float],
                    where: dict[str, int]) -> None:
        """G43 (H, or the tool in the spindle), G43.1 (the axis words), G49."""
        frame = self.frame
        if code == _G_49:
            frame.tool = [0.0] * len(self.axes)
        elif code == _G_43_1:
            frame.tool = [params.get(letter, 0.0) * scale
                          for letter, scale in zip(self.axes, self.scales, strict=True)]
        else:
            if "H" in params:
                number = params["H"]
                if number != round(number) or number < 0:
                    raise self.error(
                        block, where["H"],
                        f"G43 H{block.numbers[where['H']]}: H is a tool number, a whole "
                        "number 0 or more",
                    )
                tool = int(number)
                blame = where["H"]
            else:
                tool = self.tools.spindle
                blame = index
            offset = self.tools.table.offset_mm(tool)
            if offset is None:
                raise self.error(
                    block, blame,
                    f"G43: tool {tool} is not in {self.tools.table.describe()}",
                )
            frame.tool = self.tool_offset(block, blame, tool, offset)
        self.reframe()

    def tool_offset(self, block: Block, blame: int, tool: int, offset: Point) -> list[float]:
        """A tool table offset (X Y Z U V W) on the machine's axes; an offset on an axis the
        machine lacks is refused (the tool would not be where the table says)."""
        for letter, value in zip(AXIS_ORDER, offset, strict=True):
            if value != 0.0 and letter not in self.axis_set:
                raise self.unsupported(
                    block, blame,
                    f"tool {tool} of {self.tools.table.describe()} is offset {value:g} mm on "
                    f"axis {letter}, and the machine has no axis {letter} (its axes are "
                    f"{', '.join(self.axes)})",
                )
        return [offset[AXIS_ORDER.index(letter)] for letter in self.axes]

    def check_tool_number(self, block: Block, index: int, what: str, value: float) -> None:
        """A T word or M61 Q: a whole number, of a tool the table holds (0: no tool)."""
        if value != round(value):
            raise self.error(
                block, index, f"{what}{block.numbers[index]}: a tool number is whole"
            )
        if value < 0:
            raise self.error(
                block, index, f"{what}{block.numbers[index]}: a tool number is not negative"
            )
        if self.tools.table.offset_mm(int(value)) is None:
            raise self.error(
                block, index,
                f"{what}{block.numbers[index]}: tool {int(value)} is not in "
                f"{self.tools.table.describe()}",
            )

    def change_tool(self, block: Block, params: dict[str, float], where: dict[str, int],
                    m_codes: dict[int, int], m_where: dict[int, int]) -> None:
        """T selects a tool; M6 puts the selected tool in the spindle, M61 Q names it."""
        tools = self.tools
        if "T" in params:
            tools.selected = int(params["T"])
        change = m_codes.get(_MG_TOOL_CHANGE)
        if change == _M_6:
            if tools.selected != tools.spindle and self.pauses_at(_M_6):
                pocket = tools.pocket(tools.selected)
                in_pocket = f" (pocket {pocket})" if pocket else ""
                self.pause(block.line, "M6",
                           f"tool change: put tool {tools.selected}{in_pocket} in the spindle,"
                           " then cycle start")
            tools.spindle = tools.selected
            self.tool_changes.append(
                ToolChange(block.line, tools.spindle, tools.pocket(tools.spindle), True)
            )
        elif change == _M_61:
            tools.spindle = int(params["Q"])
            self.tool_changes.append(
                ToolChange(block.line, tools.spindle, tools.pocket(tools.spindle), False)
            )

    def check_machine_move(self, block: Block, index: int, motion: int,
                           g_codes: dict[ModalGroup, int]) -> None:
        """G53 needs G0 or G1 and absolute distances, as in LinuxCNC."""
        if motion not in (_G_0, _G_1):
            raise self.error(
                block, index,
                "G53 moves in machine coordinates with G0 or G1 only: put G0 or G1 on this "
                "line, or make one the active motion mode",
            )
        distance = g_codes.get(_GM_DISTANCE_MODE)
        if distance == _G_91 or (distance is None and self.incremental):
            raise self.error(
                block, index,
                "G53 cannot be used with incremental distances (G91): machine coordinates "
                "are absolute; use G90",
            )

    def check_wrapped(self, block: Block, params: dict[str, float], *,
                      absolute: bool) -> None:
        """Refuse an absolute position of a wrapped rotary axis of a whole turn or more."""
        if not absolute:
            return
        for letter in self.machine.wrapped:
            value = params.get(letter)
            if value is not None and not -360.0 < value < 360.0:
                index = block.letters.index(letter)
                raise self.error(
                    block, index,
                    f"{letter}{block.numbers[index]}: {letter} is a wrapped rotary axis; an"
                    " absolute position is within -360..360 degrees, its sign the way to turn")

    def machine_move(self, block: Block, motion: int, params: dict[str, float]) -> None:
        """G0/G1 with G53: the axis words are machine coordinates (offsets not applied)."""
        self.check_wrapped(block, params, absolute=True)
        self.motion = motion
        self.cycle.level = None
        end = list(self.position)
        for axis, letter in enumerate(self.axes):
            if letter in params:
                end[axis] = (_unwrap(end[axis], params[letter]) if letter in self.machine.wrapped
                             else params[letter] * self.scales[axis])
        if motion == _G_0:
            self.traverse(block.line, end)
            return
        self.require_feed(block, -1, "G1")
        self.moves.append(Linear(block.line, _point(self.position), _point(end),
                                 self.path_feed(self.position, end)))
        self.position = end

    def home(self, line: int, named: str) -> None:
        """Homing the axes ``named`` on a homed machine: a rapid, group by group in the
        machine's homing order, to where homing leaves each axis; in Marlin it also clears
        their G92 shift (``set_axis_is_at_home``)."""
        machine = self.machine
        home = machine.home_mm or (0.0,) * len(self.axes)
        for group in machine.homing_order or (self.axes,):
            end = list(self.position)
            for letter in group:
                if letter in named:
                    axis = self.axes.index(letter)
                    end[axis] = home[axis]
            if end != self.position:
                self.traverse(line, end)
        if self.rules.homing_clears_g92:
            frame = self.frame
            for axis, letter in enumerate(self.axes):
                if letter in named:
                    frame.g92[axis] = 0.0
            self.reframe()

    def refuse_volatile_g92(self, block: Block) -> None:
        """Refuse G92, G92.1, G92.2 and G92.3 as a setting where the G92 offset is volatile
        (grbl, Marlin): it lasts until the program ends or the controller is reset, so no
        setting keeps it."""
        for index, letter in enumerate(block.letters):
            if letter != "G":
                continue
            code = _G_SPELLINGS.get(block.numbers[index])
            if code is None:
                code = self.g_code(block, index)
            if code in _G92_CODES:
                raise self.error(
                    block, index,
                    f"G{block.numbers[index]}: in the {self.rules.dialect.value} dialect the G92"
                    " offset lasts until the program ends or the controller is reset, so no"
                    " setting keeps it; set a lasting origin with G10 L20 P1 (such as G10 L20"
                    " P1 X0 Y0)",
                )

    def controller_command(self, block: Block) -> None:
        """A ``$`` line (grbl): ``$H`` homes every axis, ``$HX`` (``$HY``, ...) one axis;
        every other command is refused by name."""
        command = block.numbers[0].upper()
        if command == "H":
            self.home(block.line, self.axes)
            return
        if command.startswith("H") and all(letter in AXIS_ORDER for letter in command[1:]):
            missing = [letter for letter in command[1:] if letter not in self.axis_set]
            if missing:
                raise self.unsupported(block, 0, f"the machine has no axis {missing[0]} (its"
                                       f" axes are {', '.join(self.axes)})")
            self.home(block.line, command[1:])
            return
        name = command.split("=", 1)[0]
        if name[:1].isdigit():
            what = "a grbl setting ($N=value)"
        elif name[:3] in GRBL_COMMANDS:
            what = GRBL_COMMANDS[name[:3]]
        elif name[:1] in GRBL_COMMANDS:
            what = GRBL_COMMANDS[name[:1]]
        else:
            what = "a command grbl does not know"
        raise self.unsupported(block, 0, f"{what} belongs to the operator at the controller,"
                               " not to a program; of the $ commands a program may hold $H"
                               " (home every axis) and $HX, $HY, ... (one axis)")

    def take_m_parameters(self, block: Block, m_codes: dict[int, int],
                          params: dict[str, float], where: dict[str, int],
                          ignored: list[tuple[int, str]]) -> None:
        """The parameters of a dialect's M codes (``M201 X500``): out of ``params`` (they
        are not axis words) and into ``ignored`` as the M code's."""
        extra = self.rules.m_codes
        for code in m_codes.values():
            entry = extra.get(code)
            if entry is None or not entry.parameters:
                continue
            for letter in entry.parameters:
                if letter in params:
                    index = where.pop(letter)
                    del params[letter]
                    ignored[:] = [item for item in ignored if item[0] != index]
                    ignored.append((index, f"parameter of M{code}: {entry.meaning}"))

    def g_reason(self, code: int) -> str:
        """Why the G code ``code`` (x10) is refused."""
        reason = self.rules.g_refused.get(code) or _G_UNSUPPORTED.get(code)
        if reason is not None:
            return reason
        dialect = self.rules.dialect
        if dialect is Dialect.LINUXCNC:
            return "it is not a G code LinuxCNC knows"
        return f"it is not a G code of the {dialect.value} dialect"

    def m_reason(self, code: int) -> str:
        """Why the M code ``code`` is refused."""
        dialect = self.rules.dialect
        if dialect is Dialect.LINUXCNC:
            return _m_reason(code)
        reason = _M_UNSUPPORTED.get(code)
        return reason or f"it is not an M code of the {dialect.value} dialect"

    def ends(self, params: dict[str, float]) -> list[float]:
        """The end point named by the axis words (absolute or incremental), in mm."""
        if self.frame.rotated:
            return self.rotated_ends(params)
        end = list(self.position)
        scales = self.scales
        wrapped = self.machine.wrapped
        for axis, letter in enumerate(self.axes):
            value = params.get(letter)
            if value is not None:
                if self.incremental:
                    end[axis] += value * scales[axis]
                elif letter in wrapped:
                    offset = self.offset[axis]
                    end[axis] = _unwrap(end[axis] - offset, value) + offset
                else:
                    end[axis] = value * scales[axis] + self.offset[axis]
        return end

    def rotated_ends(self, params: dict[str, float]) -> list[float]:
        """:meth:`ends` in a coordinate system with an XY rotation."""
        frame = self.frame
        end = frame.to_program(self.position)
        wrapped = self.machine.wrapped
        for axis, letter in enumerate(self.axes):
            value = params.get(letter)
            if value is not None:
                if self.incremental:
                    end[axis] += value * self.scales[axis]
                elif letter in wrapped:
                    end[axis] = _unwrap(end[axis], value)
                else:
                    end[axis] = value * self.scales[axis]
        return frame.to_machine(end)

    def traverse(self, line: int, end: list[float]) -> None:
        self.moves.append(Rapid(line, _point(self.position), _point(end)))
        self.position = end

    def require_feed(self, block: Block, blame: int, name: str) -> None:
        """Refuse the feed move ``name`` (G1, G2, G3, a canned cycle) while the feed rate
        is 0, and in inverse time (G93) without an F word of its own (a cycle: at all)."""
        if self.inverse_time:
            cycle = name not in ("G1", "G2", "G3")
            if cycle or "F" not in block.letters:
                raise self.error(
                    block, blame,
                    f"{name} in inverse time feed (G93): " + (
                        "canned cycles need G94 (units per minute)" if cycle else
                        "every feed move needs its own F word (1/F minutes)"))
        if self.feed_mm_min == 0.0:
            error = self.error(
                block,
                blame,
                f"{name} with feed rate 0: set a feed rate with F (units per minute) before "
                "or on this line",
            )
            raise FeedRateError(error.message, file=error.file, line=error.line,
                                column=error.column, word=error.word)

    def path_feed(self, start: list[float], end: list[float], *,
                  arc: tuple[Plane, list[float], int, bool] | None = None) -> float:
        """The feed a move from ``start`` to ``end`` is planned at (mm per minute along its
        path, every axis alike: see ``motion.moves``), giving it LinuxCNC's time: F units
        per minute along its X Y Z length, along its U V W length when those alone move,
        along its A B C length (degrees per minute) when only rotary axes turn; in G93, 1/F
        minutes. ``arc``: (plane, centre, turns, clockwise) of an arc, whose X Y Z length
        is its helix."""
        groups = self.feed_lengths
        if groups is None and not self.inverse_time:
            return self.feed_mm_min  # X Y Z alone: the path is the X Y Z length
        primary, total = _feed_and_path_lengths(start, end, self.axes, groups, arc)
        if self.inverse_time:
            return self.feed_mm_min * total if total > 0.0 else self.feed_mm_min
        return self.feed_mm_min * total / primary if primary > 0.0 else self.feed_mm_min

    def move(
        self,
        block: Block,
        motion: int,
        params: dict[str, float],
        where: dict[str, int],
        motion_index: int,
    ) -> None:
        if motion == _G_80:
            self.motion = NO_MOTION
            self.cycle.level = None
            return
        self.check_wrapped(block, params, absolute=not self.incremental)
        previous = self.motion
        self.motion = motion
        # The word to blame: the motion G code, else (-1) the first axis or centre word.
        blame = motion_index
        if motion in CYCLE_NAMES:
            self.canned(block, motion, previous, params, where, blame)
            return
        self.cycle.level = None
        if motion == _G_0:
            self.traverse(block.line, self.ends(params))
            return
        if motion == _G_1:
            self.require_feed(block, blame, "G1")
            end = self.ends(params)
            self.moves.append(
                Linear(block.line, _point(self.position), _point(end),
                       self.path_feed(self.position, end))
            )
            self.position = end
            return
        self.arc(block, motion, params, where, blame)

    def canned(
        self,
        block: Block,
        motion: int,
        previous: int,
        params: dict[str, float],
        where: dict[str, int],
        blame: int,
    ) -> None:
        """A canned cycle block (G73 G81 G82 G83 G85 G89), expanded as LinuxCNC does."""
        name = CYCLE_NAMES[motion]
        plane = self.plane
        first_letter, second_letter, drill = plane.letters
        for letter in plane.letters:
            if letter not in self.axis_set:
                raise self.unsupported(
                    block, blame if blame >= 0 else 0,
                    f"{name} in the {plane.value} plane ({_CODE_OF_PLANE[plane].text}) needs axes "
                    f"{', '.join(plane.letters)}, and the machine has no axis {letter} (its "
                    f"axes are {', '.join(self.axes)})",
                )
        first, second, normal = axes = (self.axes.index(first_letter),
                                         self.axes.index(second_letter), self.axes.index(drill))
        series = self.cycle
        scale = self.scale
        changed = previous != motion
        if changed:
            for letter, what in ((drill, "the bottom of the hole"), ("R", "the retract level")):
                if letter not in params:
                    raise self.error(
                        block, blame,
                        f"{name} needs {letter}, {what}: the first block of a cycle, or one "
                        f"that changes the cycle, gives both R and {drill} "
                        f"({self.plane.value} plane)",
                    )
        if motion in _PECKS:
            series.peck_mm = self.cycle_word(block, params, where, blame, name, "Q", changed,
                                             series.peck_mm, "the peck depth", positive=True)
        if motion in (_G_82, _G_89):
            series.dwell_s = self.cycle_word(block, params, where, blame, name, "P", changed,
                                             series.dwell_s, "the dwell in seconds",
                                             positive=False)
        repeats = 1
        if "L" in params:
            count = params["L"]
            if count != round(count) or count < 1:
                raise self.error(
                    block, where["L"],
                    f"{name} L{block.numbers[where['L']]}: L, the number of holes, is a whole "
                    "number 1 or more",
                )
            repeats = int(count)
        self.require_feed(block, blame, name)
        program = self.frame.to_program(self.position)
        if series.level is None:
            series.level = program[normal]
        initial = series.level
        if "R" in params:
            series.r_word_mm = params["R"] * scale
        if drill in params:
            series.bottom_word_mm = params[drill] * scale
        if self.incremental:
            r_mm = initial + series.r_word_mm
            bottom_mm = r_mm + series.bottom_word_mm
            step = (params.get(first_letter, 0.0) * scale, params.get(second_letter, 0.0) * scale)
            hole = (program[first] + step[0], program[second] + step[1])
        else:
            r_mm, bottom_mm = series.r_word_mm, series.bottom_word_mm
            step = (0.0, 0.0)
            hole = (
                params[first_letter] * scale if first_letter in params else program[first],
                params[second_letter] * scale if second_letter in params else program[second],
            )
        if r_mm < bottom_mm:
            raise self.error(
                block, where.get("R", blame),
                f"{name}: R{r_mm / scale:g} (the retract level) is less than "
                f"{drill}{bottom_mm / scale:g} (the bottom of the hole); R must be at or "
                f"above {drill} in the {self.plane.value} plane",
            )
        pecks = 1
        if motion in _PECKS:
            pecks = math.ceil((r_mm - bottom_mm) / series.peck_mm)
        if repeats * pecks > _MOST_CYCLE_PASSES:
            raise self.error(
                block, blame,
                f"{name} would make {repeats} hole(s) of {pecks} peck(s); at most "
                f"{_MOST_CYCLE_PASSES:,} pecks in one block (fewer holes, L, or a larger Q)",
            )
        clear_mm = r_mm if self.retract_to_r else max(initial, r_mm)
        steps = expand_cycle(Cycle(
            GCode(motion), axes, tuple(program), hole, step, initial, r_mm,
            bottom_mm,
            clear_mm, repeats, series.peck_mm, series.dwell_s,
        ))
        to_machine = self.frame.to_machine
        line = block.line
        feed = self.feed_mm_min
        for move in steps:
            if move.kind == DWELL:
                self.moves.append(Dwell(line, _point(self.position), move.seconds))
                continue
            end = to_machine(list(move.point))
            if move.kind == RAPID:
                self.traverse(line, end)
            else:
                self.moves.append(Linear(line, _point(self.position), _point(end), feed))
                self.position = end

    def cycle_word(self, block: Block, params: dict[str, float], where: dict[str, int],
                   blame: int, name: str, letter: str, changed: bool, kept: float,
                   what: str, *, positive: bool) -> float:
        """A cycle's Q (mm, > 0) or P (seconds, >= 0): this block's, else the series' own."""
        if letter not in params:
            if changed:
                raise self.error(
                    block, blame,
                    f"{name} needs {letter}, {what} (the first block of a cycle gives it)",
                )
            return kept
        value = params[letter]
        if (positive and value <= 0.0) or value < 0.0:
            bound = "greater than 0" if positive else "0 or more"
            raise self.error(
                block, where[letter],
                f"{name} {letter}{block.numbers[where[letter]]}: {what} is {bound}",
            )
        return value * self.scale if letter == "Q" else value

    def arc(
        self,
        block: Block,
        motion: int,
        params: dict[str, float],
        where: dict[str, int],
        blame: int,
    ) -> None:
        name = g_code_text(motion)
        plane = self.plane
        indices = self.planes[plane]
        if isinstance(indices, str):
            raise self.unsupported(block, blame, f"{name} in the {plane.value} plane"
                                   f" ({_CODE_OF_PLANE[plane].text}): {indices}")
        first, second, _normal = indices
        first_letter, second_letter, other_letter = _CENTRE_LETTERS[plane]
        radius_format = "R" in params
        centre_format = "I" in params or "J" in params or "K" in params
        if self.frame.rotated and plane is not Plane.XY:
            raise self.unsupported(
                block, blame if blame >= 0 else max(0, _first_of(where, "XYZIJKR")),
                f"{name} in the {plane.value} plane of a coordinate system rotated by G10 L2 R "
                "is not supported (arcs in a rotated system: G17 only)",
            )
        if not radius_format and not centre_format:
            raise self.error(
                block,
                blame,
                f"{name} arc with no centre: R, I, J and K are all missing (give "
                f"{first_letter}/{second_letter} offsets to the centre in the "
                f"{plane.value} plane, or R, the radius)",
            )
        if radius_format and centre_format:
            raise self.error(block, where["R"], f"{name} arc with both R and I/J/K: use one form")
        self.require_feed(block, blame, name)
        first_axis, second_axis = self.axes[first], self.axes[second]
        if centre_format:
            if other_letter in params:
                raise self.error(
                    block,
                    where[other_letter],
                    f"{other_letter} word given for an arc in the {plane.value} plane "
                    f"({_CODE_OF_PLANE[plane].text}), which uses {first_letter} and "
                    f"{second_letter}",
                )
            if not self.arc_incremental:
                for letter in (first_letter, second_letter):
                    if letter not in params:
                        raise self.error(
                            block,
                            blame,
                            f"{letter} word missing for an arc with absolute centres (G90.1)",
                        )
        elif first_axis not in params and second_axis not in params:
            raise self.error(
                block,
                where["R"],
                f"{name} R arc with no {first_axis} or {second_axis} end point: an R arc "
                "cannot be a full circle",
            )
        end = self.ends(params)
        start = self.position
        scale = self.scale
        start1, start2 = start[first], start[second]
        end1, end2 = end[first], end[second]
        if radius_format:
            centre1, centre2 = self.radius_centre(
                block, motion, where["R"], params["R"], start1, start2, end1, end2
            )
        else:
            offset1 = params.get(first_letter, 0.0) * scale
            offset2 = params.get(second_letter, 0.0) * scale
            if self.frame.rotated:
                centre1, centre2 = self.rotated_centre(start, offset1, offset2)
            elif self.arc_incremental:
                centre1, centre2 = start1 + offset1, start2 + offset2
            else:
                centre1 = offset1 + self.offset[first]
                centre2 = offset2 + self.offset[second]
            self.check_radii(block, blame, plane, start1, start2, centre1, centre2, end1, end2)
        turns = round(params["P"]) if "P" in params else 1
        centre = list(start)
        centre[first] = centre1
        centre[second] = centre2
        self.moves.append(
            Arc(
                block.line,
                _point(start),
                _point(end),
                _point(centre),
                plane,
                -turns if motion == _G_2 else turns,
                self.path_feed(start, end, arc=(plane, centre, turns, motion == _G_2)),
            )
        )
        self.position = end

    def rotated_centre(self, start: list[float], offset1: float,
                       offset2: float) -> tuple[float, float]:
        """An XY arc's centre (machine X, Y) from I, J in a rotated coordinate system."""
        frame = self.frame
        x, y = frame.x, frame.y
        if self.arc_incremental:
            dx, dy = frame.rotate_vector(offset1, offset2)
            return start[x] + dx, start[y] + dy
        program = frame.to_program(start)
        program[x], program[y] = offset1, offset2
        centre = frame.to_machine(program)
        return centre[x], centre[y]

    def check_radii(
        self,
        block: Block,
        blame: int,
        plane: Plane,
        start1: float,
        start2: float,
        centre1: float,
        centre2: float,
        end1: float,
        end2: float,
    ) -> None:
        """Refuse a centre-format arc as LinuxCNC's arc_data_ijk does (in mm here)."""
        radius1 = math.hypot(centre1 - start1, centre2 - start2)
        radius2 = math.hypot(centre1 - end1, centre2 - end2)
        inch = self.scale != 1.0
        unit = "inch" if inch else "mm"
        if radius1 < _RADIUS_TOL_MM or radius2 < _RADIUS_TOL_MM:
            raise self.error(
                block,
                blame,
                "zero-radius arc: the centre is on the start or the end point "
                + self.arc_points(plane, start1, start2, centre1, centre2, end1, end2)
                + f" r1={radius1 / self.scale:.4f} r2={radius2 / self.scale:.4f} {unit}",
            )
        spiral_abs = _SPIRAL_ABS_INCH * MM_PER_INCH if inch else _SPIRAL_ABS_MM
        difference = abs(radius1 - radius2)
        relative = difference / max(radius1, radius2)
        if difference > 100.0 * spiral_abs or (difference > spiral_abs and relative > _SPIRAL_REL):
            scale = self.scale
            raise self.error(
                block,
                blame,
                "radius to the end of the arc differs from the radius to its start: "
                + self.arc_points(plane, start1, start2, centre1, centre2, end1, end2)
                + f" r1={radius1 / scale:.4f} r2={radius2 / scale:.4f} {unit}, "
                f"difference {difference / scale:.4g} {unit} ({relative * 100:.4f}%); "
                f"allowed {spiral_abs / scale:.4g} {unit}, or up to "
                f"{100 * spiral_abs / scale:.4g} {unit} within {_SPIRAL_REL * 100:g}%",
            )

    def arc_points(
        self,
        plane: Plane,
        start1: float,
        start2: float,
        centre1: float,
        centre2: float,
        end1: float,
        end2: float,
    ) -> str:
        """``start=(X..,Y..) centre=(..) end=(..)`` in program coordinates."""
        first, second = plane.indices(self.axes)[:2]
        a, b = self.axes[first], self.axes[second]
        scale = self.scale
        position = self.position

        def point(value1: float, value2: float) -> str:
            machine = list(position)
            machine[first], machine[second] = value1, value2
            program = self.frame.to_program(machine)
            return f"({a}{program[first] / scale:.4f},{b}{program[second] / scale:.4f})"

        return (
            f"start={point(start1, start2)} centre={point(centre1, centre2)} "
            f"end={point(end1, end2)}"
        )

    def radius_centre(
        self,
        block: Block,
        motion: int,
        index: int,
        radius: float,
        start1: float,
        start2: float,
        end1: float,
        end2: float,
    ) -> tuple[float, float]:
        """The centre of an R-format arc, as LinuxCNC's arc_data_r finds it (in mm)."""
        if end1 == start1 and end2 == start2:
            raise self.error(
                block,
                index,
                "R arc whose end point is its start point: a full circle needs I/J/K "
                "offsets to the centre",
            )
        if radius == 0.0:
            raise self.error(block, index, "R0: an arc radius cannot be zero")
        abs_radius = abs(radius) * self.scale
        mid1 = (end1 + start1) / 2.0
        mid2 = (end2 + start2) / 2.0
        half_length = math.hypot(mid1 - end1, mid2 - end2)
        if half_length - abs_radius > _RADIUS_TOL_MM:
            unit = "inch" if self.scale != 1.0 else "mm"
            raise self.error(
                block,
                index,
                f"arc radius R{block.numbers[index]} is too small to reach the end point: "
                f"half the distance to it is {half_length / self.scale:.4f} {unit}",
            )
        if half_length / abs_radius > 1.0 - _TINY:
            half_length = abs_radius
        direction = math.atan2(end2 - start2, end1 - start1)
        if (motion == _G_2) == (radius > 0.0):
            theta = direction - math.pi / 2.0
        else:
            theta = direction + math.pi / 2.0
        offset = abs_radius * math.cos(math.asin(half_length / abs_radius))
        return mid1 + offset * math.cos(theta), mid2 + offset * math.sin(theta)


_SYSTEM_INDEX: dict[int, int] = {code: index for index, code in enumerate(_SYSTEM_CODES)}
_AXIS_CODES = (GCode.G_28, GCode.G_30, GCode.G_92, GCode.G_10)
"""The non-modal codes that use the axis words (so no motion may share their line)."""
_ARCS = (GCode.G_2, GCode.G_3)
_G92_CODES = (GCode.G_92, GCode.G_92_1, GCode.G_92_2, GCode.G_92_3)
_PECKS = (GCode.G_73, GCode.G_83)


class _ToolState:
    """The tool table, the selected tool (T) and the tool in the spindle (M6, M61)."""

    __slots__ = ("selected", "spindle", "table")

    def __init__(self, table: ToolTable) -> None:
        self.table = table
        self.selected = 0
        self.spindle = 0

    def pocket(self, tool: int) -> int:
        entry = self.table.tools.get(tool)
        return entry.pocket if entry is not None else 0


class _CycleSeries:
    """What a series of canned cycle blocks keeps (until G80 or another motion mode):
    the initial level along the drill axis (program mm; ``None`` outside a series) and
    the last R, bottom (as written: incremental in G91), Q and P."""

    __slots__ = ("bottom_word_mm", "dwell_s", "level", "peck_mm", "r_word_mm")

    def __init__(self) -> None:
        self.level: float | None = None
        self.r_word_mm = 0.0
        self.bottom_word_mm = 0.0
        self.peck_mm = 0.0
        self.dwell_s = 0.0


def _blocks(text: str, file: str, rules: DialectRules) -> Iterator[Block]:
    """The blocks of ``text`` as the dialect of ``rules`` reads its lines."""
    return tokenize(text, file=file, commands=rules.controller_commands,
                    messages=rules.message_codes, flags=rules.flags,
                    line_limit=rules.line_limit)


def _point(values: list[float]) -> Point:
    """A position (a coordinate per axis, mm) as a point."""
    return tuple(values)


def _feed_lengths(axes: str) -> tuple[tuple[int, ...], ...] | None:
    """The indices of the X Y Z, the U V W and the A B C axes of ``axes`` (LinuxCNC measures
    a feed along the first group that moves); None when ``axes`` are X Y Z only."""
    if all(letter in "XYZ" for letter in axes):
        return None
    return tuple(tuple(i for i, letter in enumerate(axes) if letter in group)
                 for group in ("XYZ", "UVW", ROTARY_AXES))


def _feed_and_path_lengths(
        start: Sequence[float], end: Sequence[float], axes: str,
        groups: tuple[tuple[int, ...], ...] | None,
        arc: tuple[Plane, Sequence[float], int, bool] | None) -> tuple[float, float]:
    """A move's length as LinuxCNC measures its feed (along X Y Z, an arc's helix; else
    U V W; else A B C) and its length along its path, every axis alike (the planner's)."""
    lengths = [math.sqrt(sum((end[i] - start[i]) ** 2 for i in group))
               for group in groups or (tuple(range(len(axes))), (), ())]
    if arc is not None:
        plane, centre, turns, clockwise = arc
        first, second, normal = plane.indices(axes)
        r0 = math.hypot(start[first] - centre[first], start[second] - centre[second])
        r1 = math.hypot(end[first] - centre[first], end[second] - centre[second])
        theta0 = math.atan2(start[second] - centre[second], start[first] - centre[first])
        theta1 = math.atan2(end[second] - centre[second], end[first] - centre[first])
        sweep = (theta0 - theta1) if clockwise else (theta1 - theta0)
        sweep %= 2.0 * math.pi
        if sweep <= 1e-12:
            sweep = 2.0 * math.pi
        sweep += 2.0 * math.pi * (turns - 1)
        planar = sweep * 0.5 * (r0 + r1)
        normal_travel = end[normal] - start[normal] if normal >= 0 else 0.0
        lengths[0] = math.hypot(planar, normal_travel)
    total = math.sqrt(sum(length * length for length in lengths))
    return next((length for length in lengths if length > 0.0), 0.0), total


def programmed_feed(move: Linear | Arc, axes: str) -> float:
    """The feed of a move as LinuxCNC states it (its canonical feed rate): units per
    minute along the length it measures the feed on (:func:`_feed_and_path_lengths`),
    where ``move.feed_mm_min`` is along the planner's all-axes path; the same on a machine
    of X Y Z alone."""
    groups = _feed_lengths(axes)
    if groups is None:
        return move.feed_mm_min
    arc = None
    if isinstance(move, Arc):
        arc = (move.plane, move.centre, abs(move.rotation), move.rotation < 0)
    primary, total = _feed_and_path_lengths(move.start, move.end, axes, groups, arc)
    return move.feed_mm_min * primary / total if total > 0.0 and primary > 0.0 else (
        move.feed_mm_min)


def _unwrap(here: float, value: float) -> float:
    """Where a wrapped rotary axis at ``here`` (degrees, program coordinates, counted on
    across turns) goes for the absolute word ``value`` (-360 < value < 360), as LinuxCNC's
    interpreter unwraps it: to the angle ``|value|`` of the turn it is on, the sign the way
    it turns (positive: up from ``here``, negative: down), so never a whole turn or more."""
    target = abs(value) + 360.0 * math.floor(here / 360.0)
    if math.copysign(1.0, value) > 0.0:
        return target + 360.0 if target < here else target
    return target - 360.0 if target > here else target


def _plane_indices(axes: str) -> dict[Plane, tuple[int, int, int] | str]:
    """Each plane's axis indices in ``axes`` (the normal -1 when absent), or why an arc in
    it is impossible there."""
    planes: dict[Plane, tuple[int, int, int] | str] = {}
    for plane in Plane:
        missing = [letter for letter in plane.letters[:2] if letter not in axes]
        if missing:
            planes[plane] = (f"an arc needs both axes {plane.letters[0]} and "
                             f"{plane.letters[1]}, and the machine has no axis {missing[0]}"
                             f" (its axes are {', '.join(axes)})")
        else:
            planes[plane] = plane.indices(axes)
    return planes


def _letter_tables(axes: str, rules: DialectRules) -> tuple[dict[str, str], dict[str, str]]:
    """The letters refused (letter -> reason) and those ignored (letter -> meaning) for a
    machine of ``axes`` in a dialect; ``$`` is among the refused when the dialect has
    controller commands (the interpreter reads them there)."""
    where = f"its axes are {', '.join(axes)}"
    refused = dict(_LETTERS_UNSUPPORTED)
    for letter in AXIS_ORDER:
        if letter not in axes:
            refused[letter] = f"the machine has no axis {letter} ({where})"
    ignored = dict(_LETTERS_IGNORED) | rules.letter_meanings
    for letter, meaning in rules.letters.items():
        refused.pop(letter, None)
        ignored[letter] = meaning
    if rules.controller_commands:
        refused["$"] = "controller commands"
    return refused, ignored


def _code_tables(
    rules: DialectRules,
) -> tuple[dict[int, tuple[ModalGroup, int, str]], dict[int, tuple[int, str]]]:
    """The G and M codes a dialect accepts: LinuxCNC's, less what it lacks or refuses,
    with its own M codes (each its own modal group, numbered past LinuxCNC's)."""
    if rules.dialect is Dialect.LINUXCNC:
        return _G_CODES, _M_CODES
    g_codes = {code: entry for code, entry in _G_CODES.items() if code not in rules.g_refused}
    m_codes = {code: entry for code, entry in _M_CODES.items() if code not in rules.m_removed}
    for code, extra in rules.m_codes.items():
        group = m_codes[code][0] if code in m_codes else _DIALECT_M_GROUP + code
        m_codes[code] = (group, extra.meaning)
    return g_codes, m_codes


def _first_of(where: dict[str, int], letters: str) -> int:
    """The index of the first word in the block among ``letters``; -1 when none."""
    return min((where[letter] for letter in letters if letter in where), default=-1)


def _m_reason(code: int) -> str:
    reason = _M_UNSUPPORTED.get(code)
    if reason is not None:
        return reason
    if code in _USER_M_CODES:
        return "user-defined M codes (M100-M199) are not supported"
    return "it is not an M code LinuxCNC knows"


def _m_group_description(group: int, code: int) -> str:
    """How a message names M group ``group``: LinuxCNC's name, or a dialect's own code."""
    return MGroup(group).description if group in _M_GROUPS else f"M{code}"
