"""Changing a machine file: values set by their dotted keys in the TOML text, its comments
and layout kept (tomlkit), and the result validated as :func:`~usbmotion.host.config.load_config`
validates a file before anything takes it; written back whole or not at all.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import tomlkit
from tomlkit.exceptions import TOMLKitError

from usbmotion.errors import ConfigError
from usbmotion.host.config import MachineConfig, UrlChecks, parse_config

Key = tuple[str, ...]
"""A dotted key as its parts: ``("axes", "X", "homing", "pull_off_mm")``."""
Value = float | int | bool | list[float]


def edit_config_text(text: str, changes: Mapping[Key, Value]) -> str:
    """``text`` (a machine file) with each key set to its value, added where the file
    leaves it to its default; everything else, comments included, as it was.

    Raises:
        ConfigError: the text is not TOML, or a key's parent is missing or not a table.
    """
    try:
        document = tomlkit.parse(text)
    except TOMLKitError as error:
        raise ConfigError(f"the machine file is not valid TOML: {error}") from error
    for key, value in changes.items():
        table: Any = document
        for part in key[:-1]:
            if part not in table or not isinstance(table[part], Mapping):
                raise ConfigError(f"{'.'.join(key)}: the machine file has no table"
                                  f" {part!r} to hold it")
            table = table[part]
        table[key[-1]] = value
    return tomlkit.dumps(document)


def changed_config(config: MachineConfig, changes: Mapping[Key, Value], *,
                   url_checks: UrlChecks | None = None) -> tuple[MachineConfig, str]:
    """The machine ``config`` was read from, with ``changes``: the new configuration and the
    file's new text, checked as a file is when it loads (a velocity or an acceleration
    beyond what the motor reaches, a home position outside the travel, ...).

    Raises:
        ConfigError: the file cannot be read, or the changed file would be refused (the
            message names the key and what is allowed).
    """
    path = Path(config.path)
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as error:
        raise ConfigError(f"{path}: cannot read the machine file: {error}",
                          path=str(path)) from error
    changed = edit_config_text(text, changes)
    return parse_config(changed, path=path, url_checks=url_checks), changed


def write_config_text(path: str | Path, text: str) -> None:
    """Replace the file at ``path`` with ``text`` at once (a temporary file beside it,
    renamed over it): a reader sees the old file or the new one, never part of either.

    Raises:
        OSError: it cannot be written.
    """
    target = Path(path)
    handle, temporary = tempfile.mkstemp(prefix=f".{target.name}.", dir=target.parent)
    try:
        with os.fdopen(handle, "w", encoding="utf-8") as file:
            file.write(text)
            file.flush()
            os.fsync(file.fileno())
        if target.exists():
            os.chmod(temporary, target.stat().st_mode & 0o7777)
        os.replace(temporary, target)
    except BaseException:
        Path(temporary).unlink(missing_ok=True)
        raise


__all__ = ["Key", "Value", "changed_config", "edit_config_text", "write_config_text"]
