"""How the ``usbmotion`` command reads: its help and its usage errors.

Help: flags without a ``<bool>`` placeholder, arguments and values named in capitals
(``PROGRAM``, ``PATH``), never a type in angle brackets, and each paragraph of a docstring
flowed to the terminal's width (its source's line breaks are not kept; an indented line or
a list item keeps its own).

Errors: a usage error (a missing argument, an unknown option or command, a value an
option cannot take) is one line on standard error, ``usbmotion run: missing argument
PROGRAM (usbmotion run --help)``, exit status 2; no boxed panel, no usage block. A file
argument (``PROGRAM``, ``FILE``) that cannot be read is refused the same way before the
command runs: ``usbmotion run: cannot read nofile.ngc: no such file or directory``.

:class:`UsbMotionTyper` is the ``typer.Typer`` of the command and its groups: every
command registered on it gets these rules, so a new sub-command reads like the others
without repeating them.
"""

from __future__ import annotations

import copy
import inspect
import re
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, NoReturn

import typer
from typer._click.exceptions import (
    MissingParameter,
    NoArgsIsHelpError,
    NoSuchOption,
    UsageError,
)
from typer._click.types import (
    FloatParamType,
    FloatRange,
    IntParamType,
    IntRange,
    ParamType,
    StringParamType,
)
from typer.core import TyperArgument, TyperCommand, TyperGroup, TyperOption
from typer.models import CommandFunctionType, TyperPath

from usbmotion.cli.exits import EXIT_BAD_INPUT, EXIT_FAULT, fail
from usbmotion.cli.machines import command_running, unreadable

_NAMED_TYPES = {"path": "PATH", "int": "N", "float": "NUMBER", "str": "TEXT"}
"""The placeholder of an option's value by its type, when the option names none."""


def _kind(param: Any) -> str:
    """What a parameter's value is: ``path``, ``int``, ``float``, ``str``, or another."""
    kind: ParamType = param.type
    if isinstance(kind, TyperPath):
        return "path"
    for family, name in ((IntParamType, "int"), (FloatParamType, "float"),
                         (StringParamType, "str")):
        if isinstance(kind, family):
            return name
    return kind.name


def _clean(params: list[Any]) -> list[Any]:
    for param in params:
        if param.metavar is not None:
            continue
        if isinstance(param, TyperOption):
            if param.is_flag or param.count:
                param.metavar = ""
            else:
                param.metavar = _NAMED_TYPES.get(_kind(param), "VALUE")
        elif isinstance(param, TyperArgument) and param.name:
            param.metavar = param.name.upper()
            param.__class__ = _NamedArgument
            param.type = _unnamed(param.type)
    return params


class _NamedArgument(TyperArgument):
    """An argument whose name says what it is: typer would add its type (``<path>``); one
    that takes many values says so in the usage line (``[AXES]...``)."""

    def make_metavar(self, ctx: Any, *, usage: bool = False) -> str:
        named = str(super().make_metavar(ctx, usage=usage))
        return f"{named}..." if usage and self.nargs != 1 else named


def _unnamed(kind: ParamType) -> ParamType:
    """``kind`` as an argument's type that the help does not name (typer's help shows an
    argument's type as ``<path>`` unless the type gives a metavar): a copy, since a type may
    be shared by many parameters."""
    if getattr(kind, "unnamed", False):
        return kind
    copied = copy.copy(kind)
    setattr(copied, "get_metavar", lambda param, ctx: "")  # noqa: B010 - on this copy alone
    setattr(copied, "unnamed", True)  # noqa: B010
    return copied


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


def _shown_as_written(text: str) -> str:
    """``text`` for rich's markup, which the help is rendered with: a word in square
    brackets (``[joints]``, ``[[t, ...], ...]``) would be taken for a style and dropped,
    so each bracket is escaped (and a backslash before one doubled)."""
    return re.sub(r"(\\*)\[", lambda found: found.group(1) * 2 + "\\[", text)


def _as_written(command: Any) -> None:
    """A command's or group's help, and its parameters', shown as written (under rich's
    markup; with typer's plain help, nothing is read as markup and nothing changes)."""
    if getattr(command, "rich_markup_mode", None) != "rich":
        return
    for name in ("help", "short_help", "epilog"):
        text = getattr(command, name, None)
        if text:
            setattr(command, name, _shown_as_written(text))
    for param in command.params:
        if getattr(param, "help", None):
            param.help = _shown_as_written(param.help)


def _command_path(context: Any) -> str:
    """``usbmotion gcode moves``: the command's names under the root, whatever the program
    was called (``python -m usbmotion``, a test runner)."""
    names: list[str] = []
    while context is not None and context.parent is not None:
        names.insert(0, context.info_name or "")
        context = context.parent
    return " ".join(["usbmotion", *names])


_QUOTED_NAME = re.compile(r"'(-{1,2}[A-Za-z][\w-]*|[A-Z][A-Z0-9_]*(?:\.\.\.)?)'")
"""An option or an argument's name in quotes (``'--pty'``, ``'PROGRAM'``)."""


def _plain(message: str) -> str:
    """A message of the command-line library as a clause: names without quotes, no
    capital to start, no full stop at the end, on one line."""
    text = " ".join(_QUOTED_NAME.sub(r"\1", message).split()).rstrip(".")
    return text[:1].lower() + text[1:] if text[1:2].islower() or text[1:2] == " " else text


def _names(param: Any) -> str:
    """An option by its long name (``--feed``), an argument by its metavar (``PROGRAM``)."""
    if isinstance(param, TyperOption):
        return max(param.opts, key=len)
    return str(param.metavar or param.human_readable_name).upper()


def usage_error_line(error: UsageError, *, args: Sequence[str] = (),
                     root: Any = None) -> str:
    """The one line a usage error is said in, ``usbmotion run: what (usbmotion run
    --help)``. ``args`` and the ``root`` group name the command when the error does not
    (an option's missing value is found before its command's context exists)."""
    where = (_command_path(error.ctx) if error.ctx is not None
             else _path_in_args(root, list(args)))
    if isinstance(error, MissingParameter) and error.param is not None:
        kind = "option" if isinstance(error.param, TyperOption) else "argument"
        what = f"missing {kind} {_names(error.param)}"
    elif isinstance(error, NoSuchOption):
        what = f"no such option {error.option_name}"
        if error.possibilities:
            what += f"; did you mean {' or '.join(sorted(error.possibilities))}?"
    elif isinstance(error, typer.BadParameter):
        what = _bad_value(error, list(args))
    else:
        what = _plain(error.format_message())
        context = error.ctx
        group = context.command if context is not None else None
        if (what.startswith("no such command") and context is not None
                and isinstance(group, TyperGroup)):
            unknown, _, close = what.replace("'", "").partition(". Did you mean ")
            commands = [name for name in group.list_commands(context)
                        if not getattr(group.get_command(context, name), "hidden", False)]
            hint = f"; did you mean {close}" if close else ";"
            what = f"{unknown}{hint} the commands are {', '.join(commands)}"
    return f"{where}: {what} ({where} --help)"


_NUMBER_WORDS = {"int": "a whole number", "float": "a number"}


def _bad_value(error: typer.BadParameter, args: list[str]) -> str:
    """``--pty 'abc' is not a whole number``, or the parameter and the message."""
    param = error.param
    hint = error.param_hint
    if hint is None and param is not None:
        hint = _names(param)
    named = " / ".join(hint) if isinstance(hint, Sequence) and not isinstance(
        hint, str) else hint
    if isinstance(param, TyperOption):
        kind = _kind(param)
        wanted = _NUMBER_WORDS.get(kind)
        given = _given(param.opts, args)
        if wanted is not None and given is not None and not _parses(given, kind):
            return f"{_names(param)} {given!r} is not {wanted}"
        allowed = _range_words(param.type)
        if allowed is not None and given is not None and "not in the range" in error.message:
            return f"{_names(param)} {given} is out of range; allowed: {allowed}"
    return f"{_plain(named)}: {_plain(error.message)}" if named else _plain(error.message)


def _range_words(kind: ParamType) -> str | None:
    """What a number option's range allows, in words (``1 or more``, ``1 to 16``), or None
    for a type with no range."""
    if not isinstance(kind, IntRange | FloatRange):
        return None
    low, high = kind.min, kind.max
    if low is not None and high is not None:
        return (f"{'above ' if kind.min_open else ''}{low} to"
                f" {'below ' if kind.max_open else ''}{high}")
    if low is not None:
        return f"more than {low}" if kind.min_open else f"{low} or more"
    if high is not None:
        return f"less than {high}" if kind.max_open else f"{high} or less"
    return None


def _parses(text: str, kind: str) -> bool:
    """Whether ``text`` reads as a number of ``kind`` (``int`` or ``float``): a value that
    does is refused for its range, and the message says so."""
    try:
        (int if kind == "int" else float)(text)
    except ValueError:
        return False
    return True


def _given(opts: Sequence[str], args: list[str]) -> str | None:
    """The value an option was given in ``args`` (its last), if it was."""
    found = None
    for index, arg in enumerate(args):
        name, equals, value = arg.partition("=")
        if name in opts:
            if equals:
                found = value
            elif index + 1 < len(args):
                found = args[index + 1]
    return found


def _path_in_args(root: Any, args: list[str]) -> str:
    """``usbmotion sim``: the commands ``args`` name under ``root``."""
    names: list[str] = []
    group = root
    for arg in args:
        commands = getattr(group, "commands", None)
        if not isinstance(commands, dict) or arg not in commands:
            continue
        names.append(arg)
        group = commands[arg]
    return " ".join(["usbmotion", *names])


def _unreadable_argument(context: Any, command: Any) -> tuple[str, str] | None:
    """The first file argument given that cannot be read: (path, why)."""
    for param in command.get_params(context):
        if not isinstance(param, TyperArgument) or _kind(param) != "path":
            continue
        value = context.params.get(param.name or "")
        for each in value if isinstance(value, list | tuple) else [value]:
            if isinstance(each, str | Path):
                problem = unreadable(Path(each))
                if problem is not None:
                    return str(each), problem
    return None


class UsbMotionCommand(TyperCommand):
    """A command whose help and errors follow the module's rules; while it runs it is the
    running command (:func:`usbmotion.cli.machines.command_running`: what it holds is
    released when it ends)."""

    def __init__(self, *args: Any, **settings: Any) -> None:
        super().__init__(*args, **settings)
        if self.help:
            self.help = reflow(self.help)
        _as_written(self)

    def get_params(self, ctx: Any) -> list[Any]:
        return _clean(super().get_params(ctx))

    def collect_usage_pieces(self, ctx: Any) -> list[str]:
        return _usage(super().collect_usage_pieces(ctx))

    def invoke(self, ctx: Any) -> Any:
        name = _command_path(ctx).removeprefix("usbmotion ")
        unread = _unreadable_argument(ctx, self)
        if unread is not None:
            fail(name, f"cannot read {unread[0]}: {unread[1]}", EXIT_BAD_INPUT)
        with command_running(name):
            return super().invoke(ctx)


class UsbMotionGroup(TyperGroup):
    """A group whose own help follows the module's rules, and which, run as the program
    (standalone), says every usage error in one line (:func:`usage_error_line`)."""

    def __init__(self, *args: Any, **settings: Any) -> None:
        super().__init__(*args, **settings)
        _as_written(self)

    def get_params(self, ctx: Any) -> list[Any]:
        return _clean(super().get_params(ctx))

    def main(self, args: Sequence[str] | None = None, prog_name: str | None = None,
             complete_var: str | None = None, standalone_mode: bool = True,
             windows_expand_args: bool = True, **settings: Any) -> Any:
        if not standalone_mode:
            return super().main(args, prog_name, complete_var, standalone_mode,
                                windows_expand_args, **settings)
        try:
            result = super().main(args, prog_name, complete_var, False, windows_expand_args,
                                  **settings)
        except NoArgsIsHelpError as error:
            typer.echo(error.format_message())
            _exit(EXIT_BAD_INPUT)
        except UsageError as error:
            given = sys.argv[1:] if args is None else args
            typer.echo(usage_error_line(error, args=given, root=self), err=True)
            _exit(error.exit_code)
        except typer.TyperException as error:
            typer.echo(f"usbmotion: {error.format_message()}", err=True)
            _exit(EXIT_FAULT)
        except typer.Abort:
            typer.echo("usbmotion: aborted", err=True)
            _exit(EXIT_FAULT)
        _exit(result if isinstance(result, int) else 0)


def _exit(code: int) -> NoReturn:
    sys.exit(code)


class UsbMotionTyper(typer.Typer):
    """``typer.Typer`` whose group and commands follow the module's rules."""

    def __init__(self, **settings: Any) -> None:
        settings.setdefault("cls", UsbMotionGroup)
        super().__init__(**settings)

    def command(self, name: str | None = None, **settings: Any
                ) -> Callable[[CommandFunctionType], CommandFunctionType]:
        settings.setdefault("cls", UsbMotionCommand)
        return super().command(name, **settings)
