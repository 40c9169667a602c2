"""grbl 1.1's numbered errors (``error:N``) and alarms (``ALARM:N``), as its
``doc/csv`` tables number them."""

from __future__ import annotations

import enum


class GrblErrorCode(enum.IntEnum):
    """The number after ``error:``."""

    EXPECTED_COMMAND_LETTER = 1
    BAD_NUMBER_FORMAT = 2
    INVALID_STATEMENT = 3
    """A ``$`` command not recognised or not supported."""
    NEGATIVE_VALUE = 4
    SETTING_DISABLED = 5
    """Homing is not enabled in the settings."""
    SETTING_STEP_PULSE_MIN = 6
    SETTING_READ_FAIL = 7
    IDLE_ERROR = 8
    """A ``$`` command that needs the machine idle."""
    SYSTEM_GC_LOCK = 9
    """G-code refused while in alarm or jogging."""
    SOFT_LIMIT_ERROR = 10
    """Soft limits need homing enabled."""
    OVERFLOW = 11
    """A line longer than the line buffer."""
    MAX_STEP_RATE_EXCEEDED = 12
    CHECK_DOOR = 13
    LINE_LENGTH_EXCEEDED = 14
    TRAVEL_EXCEEDED = 15
    """A jog beyond the machine's travel."""
    INVALID_JOG_COMMAND = 16
    SETTING_DISABLED_LASER = 17
    UNSUPPORTED_COMMAND = 20
    MODAL_GROUP_VIOLATION = 21
    UNDEFINED_FEED_RATE = 22
    COMMAND_VALUE_NOT_INTEGER = 23
    AXIS_COMMAND_CONFLICT = 24
    WORD_REPEATED = 25
    NO_AXIS_WORDS = 26
    INVALID_LINE_NUMBER = 27
    VALUE_WORD_MISSING = 28
    UNSUPPORTED_COORD_SYS = 29
    G53_INVALID_MOTION_MODE = 30
    AXIS_WORDS_EXIST = 31
    NO_AXIS_WORDS_IN_PLANE = 32
    INVALID_TARGET = 33
    ARC_RADIUS_ERROR = 34
    NO_OFFSETS_IN_PLANE = 35
    UNUSED_WORDS = 36
    G43_DYNAMIC_AXIS_ERROR = 37
    MAX_VALUE_EXCEEDED = 38


class AlarmCode(enum.IntEnum):
    """The number after ``ALARM:``."""

    HARD_LIMIT = 1
    SOFT_LIMIT = 2
    ABORT_CYCLE = 3
    """A soft reset while in motion."""
    PROBE_FAIL_INITIAL = 4
    PROBE_FAIL_CONTACT = 5
    HOMING_FAIL_RESET = 6
    HOMING_FAIL_DOOR = 7
    HOMING_FAIL_PULLOFF = 8
    HOMING_FAIL_APPROACH = 9
    HOMING_FAIL_DUAL_APPROACH = 10
