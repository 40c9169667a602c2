"""Serve the fake machine in real time, to try a G-code sender by hand:
``.venv/bin/python -m tests.grbl.serve_fake --link /tmp/grbl`` (a pseudo-terminal), or
``--tcp 2323``; Ctrl-C ends it."""

from __future__ import annotations

import argparse
import time

from tests.grbl.fake_machine import FakeMachine

from usbmotion.grbl.server import serve


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    parser.add_argument("--link", help="a symbolic link to make to the pseudo-terminal")
    parser.add_argument("--tcp", type=int, help="serve on this TCP port instead")
    parser.add_argument("--axes", default="XYZ", help="the axis letters (default XYZ)")
    options = parser.parse_args()
    machine = FakeMachine(time.monotonic, axes=tuple(options.axes.upper()))
    return serve(machine, pty=options.tcp is None, link=options.link, tcp_port=options.tcp)


if __name__ == "__main__":
    raise SystemExit(main())
