"""Running simulated devices: clocks, in-process links, the sim:// URL, pty and TCP servers."""

from usbmotion.clock import WALL_CLOCK, Clock, WallClock
from usbmotion.sim.registry import drop_world, get_world, register_url_handler, set_world
from usbmotion.sim.world import LinkFaults, SimLink, SimWorld, VirtualClock

register_url_handler()

__all__ = [
    "WALL_CLOCK",
    "Clock",
    "LinkFaults",
    "SimLink",
    "SimWorld",
    "VirtualClock",
    "WallClock",
    "drop_world",
    "get_world",
    "register_url_handler",
    "set_world",
]
