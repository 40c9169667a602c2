"""The ``sim://`` URL: ``sim://NAME[?world=W&latency_us=N]`` names a simulated device.

The host opens it as any pyserial URL and never reads it; the simulator parses it when
the port is opened (:mod:`usbmotion.sim.urlhandler`) and when it wires a machine file's
simulated axes to their devices. :data:`URL_CHECKS` is what a loader of machine files
passes to :func:`usbmotion.host.config.load_config` so a bad ``sim://`` URL is refused
with the file, the key and the line.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from urllib.parse import parse_qs, unquote, urlsplit

from serial.serialutil import SerialException


def parse_sim_url(url: str) -> tuple[str, str, int]:
    """Split a ``sim://`` URL into (device name, world name, latency in us).

    Raises:
        SerialException: not a sim URL, an unknown option, or a bad value.
    """
    parts = urlsplit(url)
    if parts.scheme.lower() != "sim":
        raise SerialException(f"expected a URL of the form sim://NAME[?world=W], got {url!r}")
    name = unquote(parts.netloc + parts.path)
    if not name:
        raise SerialException(f"URL {url!r} names no device: use sim://NAME")
    world = "default"
    latency_us = 0
    for option, values in parse_qs(parts.query, keep_blank_values=True).items():
        value = values[-1]
        if option == "world":
            world = value
        elif option == "latency_us":
            try:
                latency_us = int(value)
            except ValueError:
                latency_us = -1
            if latency_us < 0:
                raise SerialException(
                    f"latency_us {value!r} in {url!r} is not an integer >= 0"
                ) from None
        else:
            raise SerialException(
                f"unknown option {option!r} in {url!r}; known options are world, latency_us"
            )
    return name, world, latency_us


def machine_url_problem(url: str) -> str | None:
    """Why a machine file's ``sim://`` URL is wrong, or ``None``: it must parse, and it
    names no world (the machine chooses the world its simulated devices live in)."""
    try:
        parse_sim_url(url)
    except SerialException as error:
        return str(error)
    if "world=" in url.split("?", 1)[-1]:
        return (f"{url!r} names a world; the machine chooses the world its simulated devices"
                " live in (SimulatedMachine.connect(world=...))")
    return None


URL_CHECKS: Mapping[str, Callable[[str], str | None]] = {"sim": machine_url_problem}
"""The simulator's URL schemes and how a machine file's URL of each is checked."""
