"""Named virtual-time worlds, so a ``sim://`` URL can find its device."""

from __future__ import annotations

from usbmotion.sim.world import SimWorld

_WORLDS: dict[str, SimWorld] = {}


def get_world(name: str = "default") -> SimWorld:
    """The world of this name, made on first use."""
    world = _WORLDS.get(name)
    if world is None:
        world = _WORLDS[name] = SimWorld()
    return world


def set_world(name: str, world: SimWorld) -> None:
    """Make ``sim://...?world=name`` URLs open devices of ``world``."""
    _WORLDS[name] = world


def registered_worlds() -> tuple[str, ...]:
    """The names of the worlds registered now (made by :func:`get_world` or :func:`set_world`)."""
    return tuple(_WORLDS)


def drop_world(name: str) -> None:
    """Forget a world (its devices stop being reachable by URL)."""
    _WORLDS.pop(name, None)
