"""Writing what ``tune --auto`` found into a machine file: the axis's gains and its
identified model (the ``model`` table ``usbmotion run --predict`` plays programs on) as
keys, the record of the identification (uncertainties, the SI figures, the loop's
margins) as a block of comments at the end of the axis's table, every other line and
comment kept (tomlkit)."""

from __future__ import annotations

import datetime
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import tomlkit
from tomlkit.exceptions import TOMLKitError
from tomlkit.items import Whitespace

from usbmotion.errors import ConfigError
from usbmotion.files import write_text_atomically
from usbmotion.host.config import MotorModelConfig, PidGains, UrlChecks, parse_config

if TYPE_CHECKING:
    from usbmotion.autotune.identify import Identification
    from usbmotion.autotune.model import PhysicalModel
    from usbmotion.autotune.verify import Placement

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


def identified_model(found: Identification) -> MotorModelConfig:
    """The machine file's ``model`` table of what ``found`` identified (a Coulomb voltage
    fitted below 0, friction the fit could not tell from none, as 0)."""
    model = found.fit.model
    return MotorModelConfig(model.time_constant_s, model.speed_per_volt_counts_s,
                            max(0.0, model.coulomb_v), model.supply_v)


def record_lines(found: Identification, placed: Placement,
                 physical: PhysicalModel | None) -> list[str]:
    """The comment block's lines: when, the model with its standard errors, the SI figures
    (given the file's torque constant and resistance), the loop's margins."""
    fit = found.fit
    model = fit.model
    margins = placed.design.margins
    today = datetime.datetime.now(tz=datetime.UTC).date().isoformat()
    lines = [
        f"identified {today}, the model as the drive sees it (1 sigma, {fit.uncertainty}):",
        f"time_constant_s = {model.time_constant_s:.5g} +- {fit.time_constant_sigma_s:.2g}",
        f"speed_per_volt_counts_s = {model.speed_per_volt_counts_s:.5g}"
        f" +- {fit.speed_per_volt_sigma_counts_s:.2g}",
        f"coulomb_v = {model.coulomb_v:.5g} +- {fit.coulomb_sigma_v:.2g}"
        f" (supply {model.supply_v:g} V, {fit.samples} ticks, fit RMS"
        f" {fit.rms_residual_counts:.2f} counts)",
    ]
    if physical is not None:
        lines.append(
            f"with Kt {physical.torque_constant_nm_per_a * 1000:.4g} mNm/A and R"
            f" {physical.resistance_ohm:.4g} ohm: inertia_kg_m2 = {physical.inertia_kg_m2:.4g},"
            f" viscous_friction_unm_per_rad_s = {physical.viscous_nm_s_per_rad * 1e6:.4g},"
            f" load_torque_mnm = {physical.load_torque_nm * 1000:.4g}")
    lines.append(f"gains for {placed.design.crossover_hz:g} Hz: phase margin"
                 f" {margins.phase_margin_deg:.1f} deg, gain margin"
                 f" {margins.gain_margin_db:.1f} dB")
    return lines


def write_tuning_file(path: Path, axis: str, found: Identification, placed: Placement,
                      physical: PhysicalModel | None, *,
                      url_checks: UrlChecks | None = None) -> None:
    """Write ``found``'s model and ``placed``'s gains into the machine file at ``path``
    (:func:`write_tuning`), the changed file checked as a file is when it loads before it
    replaces the old one (atomically, its mode kept).

    Raises:
        ConfigError: the file is not a machine file with that axis, or the change would
            not load; OSError: it cannot be read or written.
    """
    text = path.read_text(encoding="utf-8")
    changed = write_tuning(text, axis, placed.design.gains, record_lines(found, placed, physical),
                           identified_model(found))
    parse_config(changed, path=path, url_checks=url_checks)
    write_text_atomically(path, changed)


__all__ = ["MARK", "identified_model", "record_lines", "write_tuning", "write_tuning_file"]
