"""A device's parameters by name: each one a call of the command table, read and written
through the client's validated methods, in the units the table gives.

``kp`` is calls 9 (with 10 and 11 alongside: the client sets the gains together),
``watchdog_ms`` call 28, ``name`` call 18 as text, ``default_mode`` call 19 as a word
(``position``, ``velocity``, ``curve``). A parameter lives in flash (it persists across
a power cycle: the device name, the default mode) or in RAM (lost at power-off, and set
again from the machine file whenever a host takes the machine over).

The RAM parameters the machine file also sets (the gains, the watchdog, the
following-error limit, the servo interval and the motion scalar) map onto its keys
(:func:`machine_file_change`), so a value can be checked by the file's own rules before it
is sent: a watchdog shorter than a full motion queue lasts is refused as the file would
refuse it.
"""

from __future__ import annotations

import difflib
import math
from collections.abc import Callable
from dataclasses import dataclass
from enum import Enum

from usbmotion.errors import ArgumentError, ConfigError
from usbmotion.host.config import AxisConfig, MachineConfig, UrlChecks
from usbmotion.host.config_file import Key, Value, changed_config
from usbmotion.host.device import DeviceClient, to_sci
from usbmotion.protocol import (
    BY_NUMBER,
    DEVICE_NAME_MAX,
    CallNumber,
    ControlMode,
    device_name_problem,
)


class Storage(Enum):
    """Where a device keeps a parameter."""

    RAM = "RAM"
    """Lost at power-off; a host taking the machine over sets it from the machine file."""
    FLASH = "flash"
    """Kept across power cycles."""


@dataclass(frozen=True, slots=True)
class Parameter:
    """One named device parameter.

    Fields:
        name: its name (snake_case, with its unit: ``watchdog_ms``).
        call: the executive call that sets and queries it.
        unit: its unit, as the output shows it ("" for words and text).
        storage: flash or RAM.
        meaning: what it is, in a phrase.
        allowed: the values it takes, as a message shows them.
        read: its value on a device, as text.
        write: set it on a device from text (raises ArgumentError or OutOfRangeError
            naming the parameter, the value and what is allowed).
    """

    name: str
    call: CallNumber
    unit: str
    storage: Storage
    meaning: str
    allowed: str
    read: Callable[[DeviceClient], str]
    write: Callable[[DeviceClient, str], None]
    check: Callable[[str], float | int | str | ControlMode]
    """The value ``write`` would send, from text, without sending it (raises as ``write``)."""


def _range(call: CallNumber) -> tuple[int, int]:
    param = BY_NUMBER[call].params[0]
    return param.minimum, param.maximum


def _integer(name: str, text: str, allowed: str) -> int:
    try:
        return int(text, 10)
    except ValueError:
        raise ArgumentError(f"{name} {text!r} is not a whole number; allowed {allowed}",
                            reason=name) from None


def _number(name: str, text: str, allowed: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not math.isfinite(value):
        raise ArgumentError(f"{name} {text!r} is not a finite number; allowed {allowed}",
                            reason=name)
    return value


def _integer_parameter(name: str, call: CallNumber, unit: str, meaning: str,
                       read: Callable[[DeviceClient], int],
                       write: Callable[[DeviceClient, int], None],
                       *, scale: int = 1) -> Parameter:
    """A whole-number parameter whose range is the table's (times ``scale``: the servo
    interval is set in tenths of a millisecond and shown in microseconds)."""
    low, high = _range(call)
    allowed = f"{low * scale}..{high * scale} {unit}".rstrip()
    if scale != 1:
        allowed += f" in steps of {scale}"

    def check(text: str) -> int:
        value = _integer(name, text, allowed)
        if value % scale or not low <= value // scale <= high:
            raise ArgumentError(f"{name} {value!r} is out of range; allowed {allowed}",
                                reason=name)
        return value

    def set_from(client: DeviceClient, text: str) -> None:
        write(client, check(text) // scale)

    return Parameter(name, call, unit, Storage.RAM, meaning, allowed,
                     lambda client: str(read(client)), set_from, check)


_GAIN_COEFFICIENT = BY_NUMBER[CallNumber.SET_PROPORTIONAL_GAIN].params[0]
_GAIN_EXPONENT = BY_NUMBER[CallNumber.SET_PROPORTIONAL_GAIN].params[1]
_GAIN_ALLOWED = (f"0, or {10.0 ** _GAIN_EXPONENT.minimum:g}..{_GAIN_COEFFICIENT.maximum}e"
                 f"{_GAIN_EXPONENT.maximum} with at most 3 significant digits")


def _gain_parameter(index: int, name: str, call: CallNumber, unit: str,
                    meaning: str) -> Parameter:
    def read(client: DeviceClient) -> str:
        return f"{client.gains()[index]:.3g}"

    def check(text: str) -> float:
        value = _number(name, text, _GAIN_ALLOWED)
        if value < 0:
            raise ArgumentError(f"{name} {text!r} is negative; allowed {_GAIN_ALLOWED}",
                                reason=name)
        coefficient, exponent = to_sci(value, digits=3, parameter=name)
        if not math.isclose(coefficient * 10.0**exponent, value, rel_tol=1e-9):
            raise ArgumentError(f"{name} {text!r} has more than 3 significant digits; allowed"
                                f" {_GAIN_ALLOWED}", reason=name)
        return value

    def write(client: DeviceClient, text: str) -> None:
        value = check(text)
        gains = list(client.gains())
        gains[index] = value
        client.set_gains(kp=gains[0], ki=gains[1], kd=gains[2])

    return Parameter(name, call, unit, Storage.RAM, meaning, _GAIN_ALLOWED, read, write,
                     check)


_MODE_WORDS = ", ".join(mode.word for mode in ControlMode)


def _mode(name: str, text: str) -> ControlMode:
    for mode in ControlMode:
        if mode.word == text.strip().lower():
            return mode
    raise ArgumentError(f"{name} {text!r} is not a control mode; allowed {_MODE_WORDS}",
                        reason=name)


def _set_name(client: DeviceClient, text: str) -> None:
    client.set_name(text)


def _check_name(text: str) -> str:
    problem = device_name_problem(text, allow_empty=True)
    if problem is not None:
        raise ArgumentError(f"name {text!r}: {problem}", reason="name")
    return text


PARAMETERS: tuple[Parameter, ...] = (
    _gain_parameter(0, "kp", CallNumber.SET_PROPORTIONAL_GAIN, "V/count",
                    "proportional gain of the PID"),
    _gain_parameter(1, "ki", CallNumber.SET_INTEGRAL_GAIN, "V/(count s)",
                    "integral gain of the PID"),
    _gain_parameter(2, "kd", CallNumber.SET_DERIVATIVE_GAIN, "V s/count",
                    "derivative gain of the PID"),
    _integer_parameter("watchdog_ms", CallNumber.SET_WATCHDOG, "ms",
                       "no command for this long while enabled disables the servo (0 off)",
                       DeviceClient.watchdog_ms, DeviceClient.set_watchdog_ms),
    _integer_parameter("following_error_limit_counts", CallNumber.SET_FOLLOWING_ERROR_LIMIT,
                       "counts", "a larger following error faults the axis (0 off)",
                       DeviceClient.following_error_limit,
                       DeviceClient.set_following_error_limit),
    _integer_parameter("servo_interval_us", CallNumber.SET_SERVO_UPDATE_INTERVAL, "us",
                       "servo loop period; setting it clears the motion queue",
                       DeviceClient.servo_interval_us,
                       DeviceClient.set_servo_interval_dms, scale=100),
    _integer_parameter("motion_scalar", CallNumber.SET_MOTION_UPDATE_INTERVAL_SCALAR,
                       "ticks", "servo ticks per motion-queue value; setting it clears"
                       " the queue", DeviceClient.motion_scalar, DeviceClient.set_motion_scalar),
    _integer_parameter("diagnostics_interval_ticks", CallNumber.SET_DIAGNOSTICS_INTERVAL,
                       "ticks", "a diagnostics line every this many servo ticks (0 off)",
                       DeviceClient.diagnostics_interval,
                       DeviceClient.set_diagnostics_interval),
    Parameter("control_mode", CallNumber.SET_CONTROL_MODE, "", Storage.RAM,
              "what the motion queue's values are; setting it clears the queue",
              _MODE_WORDS, lambda client: client.control_mode().word,
              lambda client, text: client.set_control_mode(_mode("control_mode", text)),
              lambda text: _mode("control_mode", text)),
    Parameter("default_mode", CallNumber.SET_DEFAULT_CONTROL_MODE, "", Storage.FLASH,
              "control mode at power-up", _MODE_WORDS,
              lambda client: client.default_mode().word,
              lambda client, text: client.set_default_mode(_mode("default_mode", text)),
              lambda text: _mode("default_mode", text)),
    Parameter("name", CallNumber.SET_DEVICE_NAME, "", Storage.FLASH,
              "the device's name, which machine files find it by",
              f"up to {DEVICE_NAME_MAX} printable ASCII characters ('' restores the"
              " default name)", DeviceClient.device_name, _set_name, _check_name),
)
"""Every named parameter, in the order ``usbmotion get`` lists them."""

BY_PARAMETER_NAME = {parameter.name: parameter for parameter in PARAMETERS}


def parameter(name: str) -> Parameter:
    """The parameter called ``name``.

    Raises:
        ArgumentError: no such parameter (the message lists them).
    """
    try:
        return BY_PARAMETER_NAME[name]
    except KeyError:
        close = difflib.get_close_matches(name.lower(), list(BY_PARAMETER_NAME), n=1)
        hint = f"; did you mean {close[0]!r}?" if close else ";"
        raise ArgumentError(
            f"no parameter {name!r}{hint} the parameters are {', '.join(BY_PARAMETER_NAME)}",
            reason="name") from None


_GAIN_INDEX = {"kp": 0, "ki": 1, "kd": 2}


def machine_file_change(each: Parameter, axis: AxisConfig, text: str, *,
                        mode: ControlMode) -> dict[Key, Value]:
    """The machine-file keys that hold ``each`` set to ``text`` on ``axis`` (empty for a
    parameter the file does not set: the diagnostics interval, the modes, the name), in
    the file's units: ``watchdog_ms``, ``servo_interval_dms`` (from microseconds),
    ``axes.X.following_error_limit_mm`` (from counts), ``axes.X.gains.kp`` (or
    ``velocity_gains`` while the device is in velocity ``mode``, whose gains they are).

    Raises:
        ArgumentError: ``text`` is no value of the parameter (as :attr:`Parameter.write`).
    """
    value = each.check(text)
    if not isinstance(value, int | float):
        return {}
    letter = axis.name
    if each.name in _GAIN_INDEX:
        table = "velocity_gains" if mode is ControlMode.VELOCITY else "gains"
        return {("axes", letter, table, each.name): float(value)}
    if each.name == "watchdog_ms":
        return {("watchdog_ms",): int(value)}
    if each.name == "servo_interval_us":
        return {("servo_interval_dms",): int(value) // 100}
    if each.name == "motion_scalar":
        return {("motion_scalar",): int(value)}
    if each.name == "following_error_limit_counts":
        return {("axes", letter, "following_error_limit_mm"): value / axis.counts_per_mm}
    return {}


def machine_file_problem(config: MachineConfig, axis: AxisConfig, client: DeviceClient,
                         each: Parameter, text: str, *,
                         url_checks: UrlChecks | None = None) -> str | None:
    """Why the machine file would refuse ``text`` for ``each`` on ``axis`` (its own checks:
    a watchdog shorter than a full queue lasts, ...), or None. ``url_checks``: as the
    file is loaded with.

    Raises:
        ArgumentError: ``text`` is no value of the parameter.
        UsbMotionError: reading the device's control mode (for a gain) failed.
    """
    mode = client.control_mode() if each.name in _GAIN_INDEX else ControlMode.POSITION
    changes = machine_file_change(each, axis, text, mode=mode)
    if not changes:
        return None
    try:
        changed_config(config, config.path.read_text(encoding="utf-8"), changes,
                       url_checks=url_checks)
    except ConfigError as error:
        return str(error)
    except OSError as error:
        return f"cannot read the machine file {config.path}: {error.strerror or error}"
    return None
