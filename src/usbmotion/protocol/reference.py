"""Render the command table as the Markdown call reference inside ``PROTOCOL.md``.

``python -m usbmotion.protocol.reference --write PROTOCOL.md`` rewrites the generated
part of the file (between the two marker comments); a test fails when the file and the
table disagree.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from usbmotion.protocol.table import ALARM, CALLS, DIAGNOSTICS, ERR, CallSpec, Param

BEGIN = "<!-- BEGIN CALL TABLE: generated from usbmotion.protocol.table; do not edit -->"
END = "<!-- END CALL TABLE -->"


def _range(param: Param) -> str:
    if param.minimum == param.maximum:
        return f"`{param.minimum}`"
    return f"{param.minimum} .. {param.maximum}"


def _inputs(call: CallSpec) -> str:
    names = [p.name for p in call.params]
    if call.counted:
        assert call.item is not None
        names = [*names, f"{call.item.name}1 .. {call.item.name}N"]
    return " ".join(f"`{n}`" for n in names) if names else "none"


def render_call(call: CallSpec) -> str:
    """The Markdown section of one call."""
    lines = [f"### Call {call.number}: {call.name}", "", call.summary, ""]
    lines.append(f"Form: `{call.number} {' '.join(p.name for p in call.params)}`"
                 + (f" then {call.item.name}1 .. {call.item.name}N" if call.item else ""))
    lines.append("")
    lines.append("| input | range | meaning |")
    lines.append("| --- | --- | --- |")
    for param in (*call.params, *((call.item,) if call.item else ())):
        lines.append(f"| `{param.name}` | {_range(param)} | {param.doc} |")
    lines.append("")
    if call.query is not None and call.query_reply is not None:
        form = " ".join("N" if q is None else str(q) for q in call.query)
        lines.append(f"Query: `{call.number} {form}` answers `{call.query_reply.text}`.")
        lines.append("")
    elif call.query_reply is not None:
        lines.append(f"Reply: `{call.query_reply.text}`.")
        lines.append("")
    for flag, template in sorted(call.debug.items()):
        lines.append(f"Debug flag {flag} (call 8 `8 {call.number} {flag}`): `{template.text}`.")
        lines.append("")
    if call.refusal is not None:
        lines.append(f"Refusal: `{call.refusal}`.")
        lines.append("")
    if call.notes:
        lines.append(call.notes)
        lines.append("")
    return "\n".join(lines)


def render_reference() -> str:
    """The whole generated block, markers included."""
    summary = ["| call | name | inputs | query reply |", "| --- | --- | --- | --- |"]
    for call in CALLS:
        reply = f"`{call.query_reply.text}`" if call.query_reply else ""
        summary.append(f"| {call.number} | {call.name} | {_inputs(call)} | {reply} |")
    parts = [
        BEGIN,
        "",
        "## Calls at a glance",
        "",
        *summary,
        "",
        f"Malformed lines are answered `{ERR.text}`. "
        f"Diagnostics lines (call 21) read `{DIAGNOSTICS.text}`. "
        f"A fault that latches is announced unasked with `{ALARM.text}`.",
        "",
        "## Every call",
        "",
        *(render_call(call) for call in CALLS),
        END,
    ]
    return "\n".join(parts)


def splice(document: str, block: str) -> str:
    """Replace the generated block inside ``document``.

    Raises:
        ValueError: the markers are missing or out of order.
    """
    start = document.find(BEGIN)
    stop = document.find(END)
    if start < 0 or stop < start:
        raise ValueError(f"document lacks the markers {BEGIN!r} ... {END!r}")
    return document[:start] + block + document[stop + len(END) :]


def main(argv: list[str] | None = None) -> int:
    """Print the generated block, or rewrite it inside a file with ``--write``."""
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--write", type=Path, help="file whose generated block to rewrite")
    args = parser.parse_args(argv)
    block = render_reference()
    if args.write is None:
        sys.stdout.write(block + "\n")
        return 0
    path: Path = args.write
    path.write_text(splice(path.read_text(encoding="utf-8"), block), encoding="utf-8")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
