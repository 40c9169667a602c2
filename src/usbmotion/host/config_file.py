"""Changing a machine file: values set by their dotted keys in the TOML text, its comments
and layout kept (tomlkit), and the result validated as :func:`~usbmotion.host.config.load_config`
validates a file before anything takes it.
"""

from __future__ import annotations

from collections.abc import Mapping
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


def changed_config(config: MachineConfig, text: str, changes: Mapping[Key, Value], *,
                   url_checks: UrlChecks | None = None) -> tuple[MachineConfig, str]:
    """The machine ``config`` (read from ``text``) with ``changes``: the new configuration
    and the file's new text, checked as a file is when it loads (a velocity or an
    acceleration beyond what the motor reaches, a home position outside the travel, ...).

    Raises:
        ConfigError: the changed file would be refused (the message names the key and what
            is allowed).
    """
    changed = edit_config_text(text, changes)
    return parse_config(changed, path=config.path, url_checks=url_checks), changed


__all__ = ["Key", "Value", "changed_config", "edit_config_text"]
