"""How the ``usbmotion`` command's help reads: flags without a ``<bool>`` placeholder,
arguments and values named in capitals (``PROGRAM``, ``PATH``), never a type in angle
brackets, and each paragraph of a docstring flowed to the terminal's width (its source's
line breaks are not kept; an indented line or a list item keeps its own).

:class:`UsbMotionTyper` is the ``typer.Typer`` of the command and its groups: every
command registered on it gets these rules, so a new sub-command reads like the others
without repeating them.
"""

from __future__ import annotations

import inspect
import re
from collections.abc import Callable
from typing import Any

import typer
from typer.core import TyperArgument, TyperCommand, TyperGroup, TyperOption
from typer.models import CommandFunctionType

_NAMED_TYPES = {"path": "PATH", "int": "N", "float": "NUMBER", "str": "TEXT"}
"""The placeholder of an option's value by its type, when the option names none."""


def _clean(params: list[Any]) -> list[Any]:
    for param in params:
        if param.metavar is not None:
            continue
        if isinstance(param, TyperOption):
            if param.is_flag or param.count:
                param.metavar = ""
            else:
                bare = param.bare_type() if not param.type_descriptor.is_path else "path"
                param.metavar = _NAMED_TYPES.get(bare.removeprefix("list[").removesuffix("]"),
                                                 "VALUE")
        elif isinstance(param, TyperArgument) and param.name:
            param.metavar = param.name.upper()
            param.__class__ = _NamedArgument
    return params


class _NamedArgument(TyperArgument):
    """An argument whose name says what it is: typer would add its type (``<path>``)."""

    def display_type_rich(self, ctx: Any) -> str | None:
        return None


def _usage(pieces: list[str]) -> list[str]:
    """``PROGRAM`` for a required argument, as usage lines write it, not ``{PROGRAM}``."""
    return [re.sub(r"^\{(.*)\}((?:\.\.\.)?)$", r"\1\2", piece) for piece in pieces]


def reflow(text: str) -> str:
    """``text`` with each paragraph on one line: lines joined by spaces, except those that
    start a list item (``- ``) or are indented, which stay on lines of their own."""
    paragraphs: list[str] = []
    for paragraph in inspect.cleandoc(text).split("\n\n"):
        lines: list[str] = []
        for line in paragraph.splitlines():
            if lines and not line.startswith((" ", "- ")):
                lines[-1] = f"{lines[-1]} {line.strip()}"
            else:
                lines.append(line)
        paragraphs.append("\n".join(lines))
    return "\n\n".join(paragraphs)


class UsbMotionCommand(TyperCommand):
    """A command whose help follows the module's rules."""

    def __init__(self, *args: Any, **settings: Any) -> None:
        super().__init__(*args, **settings)
        if self.help:
            self.help = reflow(self.help)

    def get_params(self, ctx: Any) -> list[Any]:
        return _clean(super().get_params(ctx))

    def collect_usage_pieces(self, ctx: Any) -> list[str]:
        return _usage(super().collect_usage_pieces(ctx))


class UsbMotionGroup(TyperGroup):
    """A group whose own help follows the module's rules."""

    def get_params(self, ctx: Any) -> list[Any]:
        return _clean(super().get_params(ctx))


class UsbMotionTyper(typer.Typer):
    """``typer.Typer`` whose group and commands follow the module's rules."""

    def __init__(self, **settings: Any) -> None:
        settings.setdefault("cls", UsbMotionGroup)
        super().__init__(**settings)

    def command(self, name: str | None = None, **settings: Any
                ) -> Callable[[CommandFunctionType], CommandFunctionType]:
        settings.setdefault("cls", UsbMotionCommand)
        return super().command(name, **settings)
