"""Running simulated devices: worlds on a virtual clock, in-process links, the ``sim://``
URL, pty and TCP servers, and machines whose axes are simulated.

Importing this package only registers the ``sim://`` URL handler with pyserial, by its
package name (:data:`~usbmotion.sim.registry.HANDLER_PACKAGE`): the handler, the worlds and
the devices are imported when a ``sim://`` URL is first opened or a name below is first
used.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

import serial

if TYPE_CHECKING:
    from usbmotion.sim.registry import drop_world, get_world, set_world
    from usbmotion.sim.world import LinkFaults, SimLink, SimWorld, VirtualClock

HANDLER_PACKAGE = "usbmotion.sim.urlhandler"
"""The package pyserial looks in for ``protocol_sim`` when it opens a ``sim://`` URL."""

_EXPORTS = {
    "LinkFaults": "usbmotion.sim.world",
    "SimLink": "usbmotion.sim.world",
    "SimWorld": "usbmotion.sim.world",
    "VirtualClock": "usbmotion.sim.world",
    "drop_world": "usbmotion.sim.registry",
    "get_world": "usbmotion.sim.registry",
    "set_world": "usbmotion.sim.registry",
}


def register_url_handler() -> None:
    """Let ``serial.serial_for_url`` open ``sim://`` URLs (idempotent)."""
    if HANDLER_PACKAGE not in serial.protocol_handler_packages:
        serial.protocol_handler_packages.append(HANDLER_PACKAGE)


register_url_handler()


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'usbmotion.sim' has no attribute {name!r}")
    return getattr(importlib.import_module(module), name)


__all__ = [
    "HANDLER_PACKAGE",
    "LinkFaults",
    "SimLink",
    "SimWorld",
    "VirtualClock",
    "drop_world",
    "get_world",
    "register_url_handler",
    "set_world",
]
