"""The grammar of the links a host opens that are not plain serial ports.

``sim://NAME[?world=W&latency_us=N]`` names a simulated device (``usbmotion.sim`` serves
it; the host only needs to read the URL); every other URL is pyserial's (``socket://``,
``loop://``) or a port path.
"""

from __future__ import annotations

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
