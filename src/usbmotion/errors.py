"""Every error the package raises.

Each class also subclasses the builtin a caller would expect (a bad value is a
``ValueError``, a timeout a ``TimeoutError``), and carries the context a caller
needs to act on it: the call number, the G-code line, the axis.
"""

from __future__ import annotations


class UsbMotionError(Exception):
    """Base of every error raised by usbmotion."""


# --- numbers -------------------------------------------------------------------------------


class SciMathError(UsbMotionError, ValueError):
    """A scientific-notation number could not be built or computed."""


# --- host arguments ------------------------------------------------------------------------


class ArgumentError(UsbMotionError, ValueError):
    """An argument given to the host library is not allowed: a timeout, a period, a
    watermark, a distance, a demo number. Values bound for the wire that the protocol
    cannot carry are :class:`OutOfRangeError` instead.

    ``reason`` names the parameter.
    """

    def __init__(self, message: str, *, reason: str = "") -> None:
        super().__init__(message)
        self.reason = reason


class NoSuchDeviceError(UsbMotionError, KeyError):
    """A simulated world holds no device by that key."""

    def __str__(self) -> str:
        return str(self.args[0]) if self.args else ""


# --- the wire protocol ---------------------------------------------------------------------


class ProtocolError(UsbMotionError, ValueError):
    """A line on the wire is malformed.

    ``call`` is the executive call number when it could be read, else ``None``;
    ``reason`` is the short text the device puts in its ``ERR <call> <reason>`` reply.
    """

    def __init__(self, message: str, *, call: int | None = None, reason: str = "") -> None:
        super().__init__(message)
        self.call = call
        self.reason = reason or message


class EmptyLineError(ProtocolError):
    """The line holds no tokens."""


class LineTooLongError(ProtocolError):
    """The line is longer than the device's line buffer."""


class NonIntegerTokenError(ProtocolError):
    """A token is not a decimal integer."""


class UnknownCallError(ProtocolError):
    """The executive call number is not in the command table."""


class WrongCountError(ProtocolError):
    """The call has the wrong number of supporting inputs."""


class OutOfRangeError(ProtocolError):
    """A supporting input is outside the range the call allows."""


class UnexpectedReplyError(ProtocolError):
    """A reply line does not match any reply the call can give."""


# --- the device link -----------------------------------------------------------------------


class DeviceError(UsbMotionError, RuntimeError):
    """A device refused or failed a call.

    ``device`` names the device (its name or URL), ``call`` the executive call.
    """

    def __init__(self, message: str, *, device: str = "", call: int | None = None) -> None:
        super().__init__(message)
        self.device = device
        self.call = call


class ErrReplyError(DeviceError):
    """The device answered ``ERR <call> <reason>``."""


class QueueFullError(DeviceError):
    """The device refused setpoints or keyframes (``E0``, ``E1``, ``E25``)."""


class DeviceFaultError(DeviceError):
    """The device reports a fault (watchdog, following error, limit switch)."""


class QueueUnderrunError(DeviceError):
    """A device's motion queue ran dry while setpoints meant to follow were still unsent: the
    host fell behind, the axis stood still, and what followed would have run late, out of
    step. ``confirmed`` is how many setpoints the device had confirmed queued."""

    def __init__(self, message: str, *, device: str = "", call: int | None = None,
                 confirmed: int = 0) -> None:
        super().__init__(message, device=device, call=call)
        self.confirmed = confirmed


class StartMissedError(DeviceError):
    """A device confirmed its armed start (call 31) only after the start's tick: it may
    have started on its own, when the arming came, out of step with the others."""


class DeviceTimeoutError(UsbMotionError, TimeoutError):
    """A device did not answer in time."""

    def __init__(self, message: str, *, device: str = "", call: int | None = None) -> None:
        super().__init__(message)
        self.device = device
        self.call = call


class LinkLostError(UsbMotionError, ConnectionError):
    """The serial link closed or vanished.

    ``confirmed`` is how many setpoints the device had confirmed when it was lost.
    """

    def __init__(self, message: str, *, device: str = "", confirmed: int = 0) -> None:
        super().__init__(message)
        self.device = device
        self.confirmed = confirmed


class LinkCorruptedError(DeviceError):
    """The device acknowledged values other than those sent: the link changed bytes.

    ``confirmed`` is how many setpoints had been confirmed intact before the mismatch.
    """

    def __init__(
        self, message: str, *, device: str = "", call: int | None = None, confirmed: int = 0
    ) -> None:
        super().__init__(message, device=device, call=call)
        self.confirmed = confirmed


class DeviceNotFoundError(UsbMotionError, LookupError):
    """A configured device name was not found on any searched port."""

    def __init__(self, message: str, *, name: str = "", searched: tuple[str, ...] = ()) -> None:
        super().__init__(message)
        self.name = name
        self.searched = searched


class FlashError(UsbMotionError, OSError):
    """The device's flash store could not be read or written."""


class DeviceParameterError(UsbMotionError, ValueError):
    """A simulated device was built with a parameter outside its range (names the field)."""


# --- configuration -------------------------------------------------------------------------


class ConfigError(UsbMotionError, ValueError):
    """A machine configuration file is invalid.

    ``path`` is the file, ``key`` the dotted key, ``line`` the line (when known).
    """

    def __init__(
        self, message: str, *, path: str = "", key: str = "", line: int | None = None
    ) -> None:
        super().__init__(message)
        self.path = path
        self.key = key
        self.line = line


# --- motion --------------------------------------------------------------------------------


class GCodeError(UsbMotionError, ValueError):
    """A G-code program could not be interpreted.

    ``file``, ``line`` (1-based) and ``column`` (1-based, 0 when unknown) locate the
    problem; ``word`` is the offending word when there is one.
    """

    def __init__(
        self,
        message: str,
        *,
        file: str = "<string>",
        line: int = 0,
        column: int = 0,
        word: str = "",
    ) -> None:
        super().__init__(message)
        self.message = message
        self.file = file
        self.line = line
        self.column = column
        self.word = word

    def __str__(self) -> str:
        where = f"{self.file}:{self.line}"
        if self.column:
            where += f":{self.column}"
        return f"{where}: {self.message}"


class UnsupportedGCodeError(GCodeError):
    """A word that would change the geometry is not supported; ``reason`` says why."""

    def __init__(
        self,
        message: str,
        *,
        file: str = "<string>",
        line: int = 0,
        column: int = 0,
        word: str = "",
        reason: str = "",
    ) -> None:
        super().__init__(message, file=file, line=line, column=column, word=word)
        self.reason = reason or message


class FeedRateError(GCodeError):
    """A feed move (G1, G2, G3) with no feed rate set."""


class PlanningError(UsbMotionError, ValueError):
    """Moves could not be planned within the machine's limits."""


class SoftLimitError(PlanningError):
    """A program leaves an axis's travel: refused before anything moves.

    ``line`` is the G-code line of the move, ``axis`` the axis letter, ``coordinate_mm``
    the machine coordinate it would reach and ``limit_mm`` the end of the travel it passes.
    """

    def __init__(self, message: str, *, line: int, axis: str, coordinate_mm: float,
                 limit_mm: float) -> None:
        super().__init__(message)
        self.line = line
        self.axis = axis
        self.coordinate_mm = coordinate_mm
        self.limit_mm = limit_mm


class ProfileError(UsbMotionError, ValueError):
    """A motion profile (trapezoid, jerk-limited, Hermite) could not be built."""


# --- automation ----------------------------------------------------------------------------


class SequenceFaultError(UsbMotionError, RuntimeError):
    """An automation sequence ended in a fault. ``axis`` names the axis, when one did."""

    def __init__(self, message: str, *, axis: str = "", reason: str = "") -> None:
        super().__init__(message)
        self.axis = axis
        self.reason = reason or message


class StopRequestedError(UsbMotionError, InterruptedError):
    """The operator asked the machine to stop (Ctrl-C, SIGTERM, a front's stop): what was
    running was brought to rest along its deceleration. ``reason`` says who asked."""

    def __init__(self, message: str, *, reason: str = "") -> None:
        super().__init__(message)
        self.reason = reason or message


# --- the machine session -------------------------------------------------------------------


class MachineStateError(UsbMotionError, RuntimeError):
    """The machine cannot do that in its present state (``state``): running before homing,
    homing while a program runs, anything but a reset in Alarm."""

    def __init__(self, message: str, *, state: str = "") -> None:
        super().__init__(message)
        self.state = state
