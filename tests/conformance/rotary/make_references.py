"""Make the references of the rotary-axis cases with LinuxCNC's own interpreter.

Each folder here holds a ``test.ngc`` (written for usbmotion's tests) and, for a wrapped
rotary axis, a ``test.ini`` saying so (``[AXIS_A] WRAPPED_ROTARY = 1``). This script runs
LinuxCNC's standalone interpreter on it, as ``../shared/gcode-conformance``'s references
were made::

    rs274 -g [-i test.ini] test.ngc > expected

(Debian 12's ``linuxcnc-uspace`` 2.9.0~pre1+git20230208: ``apt-get install
linuxcnc-uspace``), then turns that canonical-call trace into ``motion.jsonl``: one record a
move in the conformance schema (``rapid``, ``linear``, ``arc``; ``start``, ``end`` and arc
``centre`` as machine positions, mm for X Y Z and degrees for A B C, for the axes in
``axes``; no ``line``: a trace numbers its calls, not the program's lines). A trace
prints program positions in the program's units with four decimals, and the offsets as
separate calls; machine = program + G92 offset + G5x offset (no XY rotation,
no tool offset in these cases). Every coordinate of these programs is exact at four
decimals (inches are whole multiples of 25.4 mm), so the records are exact.

Run: ``python3 tests/conformance/rotary/make_references.py`` (each folder's ``axes`` file
names the machine's axes, e.g. ``XYZA``).
"""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
ALL = "XYZABC"
CALL = re.compile(r"^\s*\d+\s+N\.\.\.\.\.\s+([A-Z_0-9]+)\((.*)\)\s*$")
PLANES = {"CANON_PLANE_XY": ("XY", "X", "Y", "Z"), "CANON_PLANE_XZ": ("XZ", "Z", "X", "Y"),
          "CANON_PLANE_YZ": ("YZ", "Y", "Z", "X")}


def numbers(text: str) -> list[float]:
    return [float(value) for value in text.replace(" ", "").split(",") if value]


def convert(trace: str, axes: str) -> list[dict[str, object]]:
    """The moves of an ``rs274 -g`` trace as machine-position records for ``axes``."""
    scale = 1.0
    g5x = [0.0] * 6
    g92 = [0.0] * 6
    plane = PLANES["CANON_PLANE_XY"]
    feed = 0.0
    here = [0.0] * 6  # machine, X Y Z A B C
    records: list[dict[str, object]] = []
    for text in trace.splitlines():
        match = CALL.match(text)
        if match is None:
            continue
        name, args = match.groups()
        if name == "USE_LENGTH_UNITS":
            scale = 25.4 if "INCHES" in args else 1.0
        elif name == "SET_G5X_OFFSET":
            g5x = [v * (scale if i < 3 else 1.0) for i, v in enumerate(numbers(args)[1:7])]
        elif name == "SET_G92_OFFSET":
            g92 = [v * (scale if i < 3 else 1.0) for i, v in enumerate(numbers(args)[:6])]
        elif name == "SELECT_PLANE":
            plane = PLANES[args.strip()]
        elif name == "SET_FEED_RATE":
            feed = numbers(args)[0] * scale
        elif name in ("STRAIGHT_TRAVERSE", "STRAIGHT_FEED"):
            program = numbers(args)[:6]
            end = [program[i] * (scale if i < 3 else 1.0) + g92[i] + g5x[i] for i in range(6)]
            record: dict[str, object] = {
                "type": "rapid" if name == "STRAIGHT_TRAVERSE" else "linear",
                "start": pick(here, axes), "end": pick(end, axes)}
            if name == "STRAIGHT_FEED":
                record["feed"] = feed
            records.append(record)
            here = end
        elif name == "ARC_FEED":
            values = numbers(args)
            first_end, second_end, first_centre, second_centre = values[:4]
            rotation = int(values[4])
            normal_end, a, b, c = values[5:9]
            label, first, second, normal = plane
            end = list(here)
            centre = list(here)
            for letter, value, point in ((first, first_end, end), (second, second_end, end),
                                         (normal, normal_end, end), (first, first_centre, centre),
                                         (second, second_centre, centre)):
                index = ALL.index(letter)
                point[index] = value * scale + g92[index] + g5x[index]
            for index, value in zip((3, 4, 5), (a, b, c), strict=True):
                end[index] = value + g92[index] + g5x[index]
            shown_centre: list[float | None] = pick(centre, axes)  # type: ignore[assignment]
            shown_centre[axes.index(normal)] = None
            records.append({"type": "arc", "start": pick(here, axes),
                            "end": pick(end, axes), "plane": label,
                            "direction": "cw" if rotation < 0 else "ccw",
                            "rotation": rotation, "centre": shown_centre, "feed": feed})
            here = end
    return records


def pick(point: list[float], axes: str) -> list[float]:
    return [point[ALL.index(letter)] for letter in axes]


def main() -> int:
    for folder in sorted(path for path in HERE.iterdir() if (path / "test.ngc").is_file()):
        command = ["rs274", "-g"]
        if (folder / "test.ini").is_file():
            command += ["-i", "test.ini"]
        done = subprocess.run([*command, "test.ngc"], cwd=folder, capture_output=True,
                              text=True, check=False)
        trace = done.stdout + done.stderr
        if "PROGRAM_END()" not in trace:
            print(f"{folder.name}: LinuxCNC did not read it to its end:\n{trace[-600:]}")
            return 1
        (folder / "expected").write_text(trace)
        axes = (folder / "axes").read_text().strip()
        records = convert(trace, axes)
        (folder / "motion.jsonl").write_text("".join(json.dumps(r) + "\n" for r in records))
        print(f"{folder.name}: {len(records)} moves ({axes})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
