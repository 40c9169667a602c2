"""Writing what ``tune --auto`` found into a machine file: the axis's gains and its
identified model (the ``model`` table ``usbmotion run --predict`` plays programs on) as
keys, the record of the identification (uncertainties, the SI figures, the loop's
margins) as a block of comments at the end of the axis's table, every other line and
comment kept (tomlkit)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import tomlkit
from tomlkit.exceptions import TOMLKitError
from tomlkit.items import Whitespace

from usbmotion.errors import ConfigError
from usbmotion.host.config import MotorModelConfig, PidGains

MARK = "tune --auto"
"""The first words of the comment block; a new block replaces the axis's old one."""


def _without_old_block(text: str, axis: str) -> str:
    """``text`` without the comment block an earlier run wrote for ``axis`` (and the blank
    line after it)."""
    lines = text.splitlines(keepends=True)
    kept: list[str] = []
    inside = False
    head = f"# {MARK} axis {axis}:"
    for line in lines:
        stripped = line.strip()
        if stripped.startswith(head):
            inside = True
            continue
        if inside and stripped.startswith("#   "):
            continue
        if inside and not stripped:
            inside = False
            continue  # the blank line written after the block
        inside = False
        kept.append(line)
    return "".join(kept)


def _set_table(table: Any, key: str, values: Mapping[str, float]) -> None:
    """``table[key]`` holding ``values``: its keys changed where it is a table already, a new
    inline table otherwise."""
    if isinstance(table.get(key), Mapping):
        for name, value in values.items():
            table[key][name] = value
    else:
        inline = tomlkit.inline_table()
        inline.update(values)
        table[key] = inline


def write_tuning(text: str, axis: str, gains: PidGains, model_lines: Sequence[str],
                 model: MotorModelConfig | None = None) -> str:
    """``text`` (a machine file) with ``axes.<axis>.gains`` set to ``gains``,
    ``axes.<axis>.model`` to ``model`` (when given) and ``model_lines`` as a comment block
    at the end of the axis's table (replacing an earlier one); the rest as it was.

    Raises:
        ConfigError: the text is not TOML or has no ``[axes.<axis>]`` table.
    """
    try:
        document = tomlkit.parse(_without_old_block(text, axis))
    except TOMLKitError as error:
        raise ConfigError(f"the machine file is not valid TOML: {error}") from error
    axes: Any = document.get("axes")
    if not isinstance(axes, Mapping) or not isinstance(axes.get(axis), Mapping):
        raise ConfigError(f"the machine file has no [axes.{axis}] table", key=f"axes.{axis}")
    table: Any = axes[axis]
    _set_table(table, "gains", {"kp": gains.kp, "ki": gains.ki, "kd": gains.kd})
    if model is not None:
        _set_table(table, "model", {
            "time_constant_s": float(f"{model.time_constant_s:.6g}"),
            "speed_per_volt_counts_s": float(f"{model.speed_per_volt_counts_s:.6g}"),
            "coulomb_v": float(f"{max(0.0, model.coulomb_v):.6g}"),
            "supply_v": float(f"{model.supply_v:.6g}")})
    container = getattr(table, "value", None)
    body = getattr(container, "body", None)
    trailing: list[Any] = []
    if isinstance(body, list):
        while body and body[-1][0] is None and isinstance(body[-1][1], Whitespace):
            trailing.insert(0, body.pop())
    first, *rest = model_lines
    table.add(tomlkit.comment(f"{MARK} axis {axis}: {first}"))
    for line in rest:
        table.add(tomlkit.comment(f"  {line}"))
    if isinstance(body, list):
        body.extend(trailing)
    text = tomlkit.dumps(document)
    block_end = f"#   {rest[-1]}\n" if rest else f"# {MARK} axis {axis}: {first}\n"
    at = text.find(block_end)
    after = at + len(block_end)
    if at >= 0 and after < len(text) and text[after] != "\n":
        text = text[:after] + "\n" + text[after:]  # a blank line before the next table
    return text


__all__ = ["MARK", "write_tuning"]
