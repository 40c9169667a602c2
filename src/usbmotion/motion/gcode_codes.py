"""G codes, M codes and their modal groups, named as LinuxCNC's interpreter names them.

LinuxCNC keys a G code by ten times its number, so that G90 and G90.1 are two integers
(``interp_internal.hh``: ``G_90 = 900``, ``G_90_1 = 901``), and numbers the modal groups as
RS274/NGC does (``ModalGroups``: 0 the non-modal codes, 1 motion, ...). :class:`GCode` and
:class:`ModalGroup` keep those names and numbers. M codes are their plain numbers there;
:class:`MCode` names the ones the interpreter acts on and :class:`MGroup` their groups
(``interp_array.cc``).

The interpreter (:mod:`usbmotion.motion.gcode`) re-exports these names.
"""

from __future__ import annotations

from enum import IntEnum

__all__ = ["GCode", "MCode", "MGroup", "ModalGroup", "g_code_text"]


class GCode(IntEnum):
    """A G code: ten times its number (``G_92_3`` is G92.3, 923), as LinuxCNC names it."""

    G_0 = 0
    G_1 = 10
    G_2 = 20
    G_3 = 30
    G_4 = 40
    G_5 = 50
    G_5_1 = 51
    G_5_2 = 52
    G_5_3 = 53
    G_7 = 70
    G_8 = 80
    G_10 = 100
    G_17 = 170
    G_17_1 = 171
    G_18 = 180
    G_18_1 = 181
    G_19 = 190
    G_19_1 = 191
    G_20 = 200
    G_21 = 210
    G_28 = 280
    G_28_1 = 281
    G_30 = 300
    G_30_1 = 301
    G_33 = 330
    G_33_1 = 331
    G_38_2 = 382
    G_38_3 = 383
    G_38_4 = 384
    G_38_5 = 385
    G_40 = 400
    G_41 = 410
    G_41_1 = 411
    G_42 = 420
    G_42_1 = 421
    G_43 = 430
    G_43_1 = 431
    G_43_2 = 432
    G_49 = 490
    G_52 = 520
    G_53 = 530
    G_54 = 540
    G_55 = 550
    G_56 = 560
    G_57 = 570
    G_58 = 580
    G_59 = 590
    G_59_1 = 591
    G_59_2 = 592
    G_59_3 = 593
    G_61 = 610
    G_61_1 = 611
    G_64 = 640
    G_70 = 700
    G_71 = 710
    G_71_1 = 711
    G_72 = 720
    G_72_1 = 721
    G_73 = 730
    G_74 = 740
    G_76 = 760
    G_80 = 800
    G_81 = 810
    G_82 = 820
    G_83 = 830
    G_84 = 840
    G_85 = 850
    G_86 = 860
    G_87 = 870
    G_88 = 880
    G_89 = 890
    G_90 = 900
    G_90_1 = 901
    G_91 = 910
    G_91_1 = 911
    G_92 = 920
    G_92_1 = 921
    G_92_2 = 922
    G_92_3 = 923
    G_93 = 930
    G_94 = 940
    G_95 = 950
    G_96 = 960
    G_97 = 970
    G_98 = 980
    G_99 = 990

    @property
    def text(self) -> str:
        """The code as written in a program: ``"G92.3"``."""
        return g_code_text(self)


def g_code_text(code: int) -> str:
    """A G code, given as ten times its number (a :class:`GCode` or any other), as written:
    ``923`` -> ``"G92.3"``, ``120`` -> ``"G12"``."""
    whole, tenth = divmod(int(code), 10)
    return f"G{whole}.{tenth}" if tenth else f"G{whole}"


class ModalGroup(IntEnum):
    """A modal group of G codes, numbered and named as LinuxCNC's ``ModalGroups`` (9 and 11
    are unused there too). A line holds at most one code of each group."""

    MODAL_0 = 0
    """The non-modal codes: G4, G10, G28, G30, G52, G53, G92."""
    MOTION = 1
    SET_PLANE = 2
    DISTANCE_MODE = 3
    IJK_DISTANCE_MODE = 4
    FEED_MODE = 5
    LENGTH_UNITS = 6
    CUTTER_COMP = 7
    TOOL_LENGTH_OFFSET = 8
    RETRACT_MODE = 10
    COORD_SYSTEM = 12
    CONTROL_MODE = 13
    SPINDLE_MODE = 14
    LATHE_DIAMETER_MODE = 15
    G92_IS_APPLIED = 16
    """G92.1, G92.2, G92.3 (LinuxCNC 2.9: a group of their own, carried out after group 0)."""

    @property
    def description(self) -> str:
        """What the group is, for messages: ``"arc distance mode"``."""
        return _GROUP_DESCRIPTIONS[self]


_GROUP_DESCRIPTIONS = {
    ModalGroup.MODAL_0: "non-modal codes",
    ModalGroup.MOTION: "motion",
    ModalGroup.SET_PLANE: "plane selection",
    ModalGroup.DISTANCE_MODE: "distance mode",
    ModalGroup.IJK_DISTANCE_MODE: "arc distance mode",
    ModalGroup.FEED_MODE: "feed mode",
    ModalGroup.LENGTH_UNITS: "units",
    ModalGroup.CUTTER_COMP: "cutter compensation",
    ModalGroup.TOOL_LENGTH_OFFSET: "tool length offset",
    ModalGroup.RETRACT_MODE: "retract mode",
    ModalGroup.COORD_SYSTEM: "coordinate system",
    ModalGroup.CONTROL_MODE: "path control",
    ModalGroup.SPINDLE_MODE: "spindle mode",
    ModalGroup.LATHE_DIAMETER_MODE: "lathe diameter mode",
    ModalGroup.G92_IS_APPLIED: "G92 applied",
}


class MCode(IntEnum):
    """An M code the interpreter knows by name (its number, as LinuxCNC keys M codes)."""

    M_0 = 0
    M_1 = 1
    M_2 = 2
    M_3 = 3
    M_4 = 4
    M_5 = 5
    M_6 = 6
    M_7 = 7
    M_8 = 8
    M_9 = 9
    M_19 = 19
    M_30 = 30
    M_48 = 48
    M_49 = 49
    M_50 = 50
    M_51 = 51
    M_52 = 52
    M_53 = 53
    M_60 = 60
    M_61 = 61
    M_98 = 98
    M_99 = 99


class MGroup(IntEnum):
    """A modal group of M codes, as LinuxCNC numbers them (``interp_array.cc``)."""

    STOPPING = 4
    IO = 5
    TOOL_CHANGE = 6
    SPINDLE = 7
    COOLANT = 8
    OVERRIDES = 9
    USER_DEFINED = 10

    @property
    def description(self) -> str:
        """What the group is, for messages: ``"coolant"``."""
        return _M_GROUP_DESCRIPTIONS[self]


_M_GROUP_DESCRIPTIONS = {
    MGroup.STOPPING: "stopping",
    MGroup.IO: "input and output",
    MGroup.TOOL_CHANGE: "tool change",
    MGroup.SPINDLE: "spindle",
    MGroup.COOLANT: "coolant",
    MGroup.OVERRIDES: "overrides",
    MGroup.USER_DEFINED: "user-defined",
}
