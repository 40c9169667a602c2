"""The three demo programs shipped with the package (seed 003's console loads them by number)."""

from __future__ import annotations

from importlib import resources
from pathlib import Path

from usbmotion.errors import ArgumentError

DEMOS: dict[int, tuple[str, str]] = {
    1: ("rounded square", "1-rounded-square.ngc"),
    2: ("star", "2-star.ngc"),
    3: ("spiral", "3-spiral.ngc"),
}
"""Demo number -> (title, file name)."""


def demo_path(number: int) -> Path:
    """The file of demo ``number`` (1..3).

    Raises:
        ArgumentError: no such demo.
    """
    if number not in DEMOS:
        raise ArgumentError(
            f"demo {number!r} does not exist; choose 1..{len(DEMOS)}"
            f" ({', '.join(f'{n} {t}' for n, (t, _) in DEMOS.items())})",
            reason="demo",
        )
    resource = resources.files("usbmotion") / "data" / "demos" / DEMOS[number][1]
    return Path(str(resource))


def demo_text(number: int) -> str:
    """The G-code of demo ``number``."""
    return demo_path(number).read_text(encoding="ascii")
