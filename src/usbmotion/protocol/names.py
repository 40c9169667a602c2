"""The protocol's numbers by name: its calls, its control modes and its fault codes.

Each is defined here once. The command table (:mod:`usbmotion.protocol.table`) gives every
:class:`CallNumber` its inputs and replies; host code, the Python device and the firmware's
generated table all say ``CallNumber.STATUS``, never ``20``.
"""

from __future__ import annotations

from enum import IntEnum


class CallNumber(IntEnum):
    """The executive calls: each member's name is the call's name in ``PROTOCOL.md``."""

    ADD_SINGLE = 0
    ADD_MULTIPLE = 1
    MOTION_QUEUE = 2
    SET_SERVO_ENABLE = 3
    CLEAR_MOTION_QUEUE = 4
    SET_SERVO_UPDATE_INTERVAL = 5
    SET_MOTION_UPDATE_INTERVAL_SCALAR = 6
    SET_CONTROL_MODE = 7
    SET_DEBUG_FLAG = 8
    SET_PROPORTIONAL_GAIN = 9
    SET_INTEGRAL_GAIN = 10
    SET_DERIVATIVE_GAIN = 11
    SET_SIM_UPDATE_INTERVAL = 12
    SET_SIM_SOURCE_VOLTAGE = 13
    SET_SIM_TORQUE_CONSTANT = 14
    SET_SIM_WINDING_RESISTANCE = 15
    SET_SIM_COUNTS_PER_REVOLUTION = 16
    SET_SIM_INERTIA = 17
    SET_DEVICE_NAME = 18
    SET_DEFAULT_CONTROL_MODE = 19
    STATUS = 20
    SET_DIAGNOSTICS_INTERVAL = 21
    CLOCK = 22
    SET_POSITION = 23
    LIMITS = 24
    APPEND_KEYFRAME = 25
    CLEAR_KEYFRAMES = 26
    CURVE_BUFFER = 27
    SET_WATCHDOG = 28
    SET_FOLLOWING_ERROR_LIMIT = 29
    CLEAR_FAULT = 30
    START_AT = 31
    SET_SIM_VISCOUS_FRICTION = 32
    SET_SIM_LOAD_TORQUE = 33
    SET_SIM_TRAVEL = 34
    MOTION_STATS = 35
    SWITCH_EDGE = 36
    SHIFT_POSITION = 37
    REPLACE_FROM = 38
    SET_MOTOR = 39
    SET_SIM_PROBE = 40
    PROBE = 41
    SET_OUTPUT_AT = 42
    OUTPUTS = 43
    SET_DRIVE = 44
    SET_STEPPER = 45
    SET_STEP_TIMING = 46
    SET_SIM_STEPPER = 47
    STEPS = 48
    SET_ENCODER = 49
    STOP_FROM = 50


class ControlMode(IntEnum):
    """What the motion queue's values are (calls 7 and 19)."""

    POSITION = 1
    """Positions in counts."""
    VELOCITY = 2
    """Velocities in counts/s."""
    CURVE = 3
    """Hermite keyframes (calls 25-27) instead of queue values."""

    @property
    def word(self) -> str:
        """The mode in one lower-case word (``position``, ``velocity``, ``curve``)."""
        return self.name.lower()


class Drive(IntEnum):
    """What the device drives (call 44)."""

    DC = 0
    """A brushed DC motor through an H-bridge, its PID output in volts (power-up)."""
    STEP_OPEN = 1
    """A stepper driver's step and direction inputs, open loop: the position is the steps
    issued."""
    STEP_CLOSED = 2
    """A stepper driver's step and direction inputs, closed loop: an encoder measures the
    shaft and the PID's output leads it by at most one full step."""

    @property
    def stepper(self) -> bool:
        """True for the two step/direction drives."""
        return self is not Drive.DC

    @property
    def words(self) -> str:
        """``DC motor``, ``stepper, open loop``, ``stepper, closed loop``."""
        return {Drive.DC: "DC motor", Drive.STEP_OPEN: "stepper, open loop",
                Drive.STEP_CLOSED: "stepper, closed loop"}[self]


class FaultCode(IntEnum):
    """Fault codes of call 20 (``STATUS``), call 30's query and ``ALARM`` lines."""

    NONE = 0
    WATCHDOG = 1
    FOLLOWING_ERROR = 2
    LIMIT_SWITCH = 3
    INTERNAL = 4
    #: the RP2040's absolute encoder on the pins gave no angle (the Python device has none)
    ENCODER_LOST = 5

    @property
    def words(self) -> str:
        """The fault in words (``none``, ``following error``, ``internal error``)."""
        return "internal error" if self is FaultCode.INTERNAL else self.name.lower().replace(
            "_", " ")


def fault_words(code: int) -> str:
    """A fault code in words; a code the protocol does not define reads ``fault N``."""
    try:
        return FaultCode(code).words
    except ValueError:
        return f"fault {code}"
