"""The device's flash variables: device name and default control mode, with a write count.

Flash survives a power cycle; writing it wears it out, so every write is counted and the
count is stored with the data. :class:`FileFlash` keeps one JSON file per device and
replaces it atomically (temporary file in the same directory, flush, fsync, rename, fsync
of the directory): a crash at any point leaves either the old or the new contents, never a
mix. A file that exists but cannot be read or understood raises :class:`FlashError` when
the flash is opened, naming the file, so a device never starts on garbage.
"""

from __future__ import annotations

import contextlib
import json
import os
import tempfile
from abc import ABC, abstractmethod
from dataclasses import dataclass, replace
from pathlib import Path

from usbmotion.errors import FlashError
from usbmotion.protocol.codec import device_name_problem
from usbmotion.protocol.names import ControlMode
from usbmotion.protocol.table import DEFAULT_DEVICE_NAME

FORMAT = 1
"""Version of the JSON layout written by :class:`FileFlash`."""
_KEYS = frozenset({"format", "name", "default_control_mode", "motor", "writes"})
_MOTORS = (0, 1)
_MODES = tuple(int(mode) for mode in ControlMode)


def check_name(name: str) -> str | None:
    """Why ``name`` cannot be a device name, or None (call 18's rule; empty erases)."""
    return device_name_problem(name)


@dataclass(frozen=True, slots=True)
class FlashContents:
    """What the flash holds.

    ``name`` is ``""`` when erased (the device then answers to the default name);
    ``writes`` counts every write since the flash was new.
    """

    name: str = ""
    default_control_mode: int = 1
    motor: int = 0
    """Call 39: the motor the device runs at power-up, 0 simulated, 1 on the pins."""
    writes: int = 0

    @property
    def device_name(self) -> str:
        """The name the device answers to: the stored one, or the default when erased."""
        return self.name or DEFAULT_DEVICE_NAME


class Flash(ABC):
    """Persistent storage of the flash variables."""

    @abstractmethod
    def read(self) -> FlashContents:
        """The current contents."""

    @abstractmethod
    def _commit(self, contents: FlashContents) -> None:
        """Store ``contents`` durably (its ``writes`` already counts this write)."""

    def write(self, *, name: str | None = None, default_control_mode: int | None = None,
              motor: int | None = None) -> FlashContents:
        """Change one or both variables and count the write; returns the new contents.

        Raises:
            FlashError: the storage could not be written; the old contents are kept.
            ValueError: a bad name or mode (the device validates both before writing).
        """
        old = self.read()
        if name is not None:
            why = check_name(name)
            if why is not None:
                raise ValueError(why)
        if default_control_mode is not None and default_control_mode not in _MODES:
            raise ValueError(
                f"default control mode {default_control_mode!r} is not one of {_MODES}"
            )
        if motor is not None and motor not in _MOTORS:
            raise ValueError(f"motor {motor!r} is not one of {_MOTORS}")
        new = replace(
            old,
            name=old.name if name is None else name,
            default_control_mode=(
                old.default_control_mode
                if default_control_mode is None
                else default_control_mode
            ),
            motor=old.motor if motor is None else motor,
            writes=old.writes + 1,
        )
        self._commit(new)
        return new


class MemoryFlash(Flash):
    """Flash held in memory: survives :meth:`Device.restart`, not the process."""

    def __init__(self, contents: FlashContents | None = None) -> None:
        self._contents = contents or FlashContents()

    def read(self) -> FlashContents:
        return self._contents

    def _commit(self, contents: FlashContents) -> None:
        self._contents = contents


class FileFlash(Flash):
    """Flash kept in one JSON file, replaced atomically on every write.

    A missing file is blank flash (default name, mode 1, no writes); it is created by the
    first write.

    Raises:
        FlashError: the file exists but cannot be read, is not valid JSON, or holds
            unknown keys or bad values (the message names the file and the problem).
    """

    def __init__(self, path: Path | str) -> None:
        self._path = Path(path)
        self._contents = self._load()

    @property
    def path(self) -> Path:
        """The file."""
        return self._path

    def read(self) -> FlashContents:
        return self._contents

    def _load(self) -> FlashContents:
        try:
            text = self._path.read_text(encoding="ascii")
        except FileNotFoundError:
            return FlashContents()
        except (OSError, UnicodeDecodeError) as error:
            raise FlashError(f"flash file {str(self._path)!r} cannot be read: {error}") from error
        try:
            data = json.loads(text)
        except json.JSONDecodeError as error:
            raise FlashError(
                f"flash file {str(self._path)!r} is not valid JSON: {error}"
            ) from error
        return self._parse(data)

    def _parse(self, data: object) -> FlashContents:
        where = f"flash file {str(self._path)!r}"
        if not isinstance(data, dict):
            raise FlashError(f"{where} holds {type(data).__name__}; expected a JSON object")
        unknown = sorted(set(data) - _KEYS)
        if unknown:
            raise FlashError(f"{where} has unknown keys {unknown}; known: {sorted(_KEYS)}")
        if data.get("format") != FORMAT:
            raise FlashError(f"{where} has format {data.get('format')!r}; expected {FORMAT}")
        name = data.get("name", "")
        if not isinstance(name, str) or check_name(name) is not None:
            raise FlashError(f"{where}: bad name {name!r}; up to 25 printable ASCII characters")
        mode = data.get("default_control_mode", 1)
        if type(mode) is not int or mode not in _MODES:
            raise FlashError(f"{where}: bad default_control_mode {mode!r}; one of {_MODES}")
        motor = data.get("motor", 0)
        if type(motor) is not int or motor not in _MOTORS:
            raise FlashError(f"{where}: bad motor {motor!r}; one of {_MOTORS}")
        writes = data.get("writes", 0)
        if type(writes) is not int or writes < 0:
            raise FlashError(f"{where}: bad writes {writes!r}; a count >= 0")
        return FlashContents(name=name, default_control_mode=mode, motor=motor, writes=writes)

    def _commit(self, contents: FlashContents) -> None:
        text = json.dumps(
            {
                "format": FORMAT,
                "name": contents.name,
                "default_control_mode": contents.default_control_mode,
                "motor": contents.motor,
                "writes": contents.writes,
            },
            indent=1,
        )
        directory = self._path.parent
        temporary: str | None = None
        try:
            descriptor, temporary = tempfile.mkstemp(
                prefix=f".{self._path.name}.", suffix=".tmp", dir=directory
            )
            with os.fdopen(descriptor, "w", encoding="ascii") as handle:
                handle.write(text + "\n")
                handle.flush()
                os.fsync(handle.fileno())
            os.replace(temporary, self._path)
            temporary = None
            _fsync_directory(directory)
        except OSError as error:
            raise FlashError(
                f"flash file {str(self._path)!r} could not be written: {error}"
            ) from error
        finally:
            if temporary is not None:
                with contextlib.suppress(OSError):
                    os.unlink(temporary)
        self._contents = contents


def _fsync_directory(directory: Path) -> None:
    try:
        descriptor = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        with contextlib.suppress(OSError):
            os.fsync(descriptor)
    finally:
        os.close(descriptor)
