"""The command-line reference, made from the argument parser itself: every subcommand and every option, with its
default and its help (docs/src/cli.md holds it; ``python docs/generate.py`` writes it and a test keeps it equal)."""

from __future__ import annotations

import argparse

from stewart_gym.cli.common import Parser

__all__ = ["cli_reference"]


def cli_reference(parser: Parser | None = None) -> str:
    """Markdown: a section per subcommand, in the order ``--help`` lists them, each with what it does and a table
    of its arguments (name, default, meaning)."""
    from stewart_gym.cli import build_parser

    parser = parser or build_parser()
    sections = []
    for name, command in parser.subcommands().items():
        rows = [_row(action, command.prog) for action in command.arguments()
                if action.help != argparse.SUPPRESS and action.dest not in ("help", "debug")]  # fmt: skip
        table = "\n".join(["| argument | default | meaning |", "|---|---|---|", *rows]) if rows else ""
        sections.append(f"### `stewart-gym {name}`\n\n{_text(command.description or '')}\n\n{table}".rstrip() + "\n")
    return "\n".join(sections)


def _row(action: argparse.Action, prog: str) -> str:
    if action.option_strings:
        name = ", ".join(action.option_strings)
        if action.nargs != 0:
            name += " " + _metavar(action)
    else:
        name = _metavar(action)
    params = {**vars(action), "prog": prog, "default": action.default}
    if action.choices is not None:
        params["choices"] = ", ".join(map(str, action.choices))
    meaning = (action.help or "") % params if "%" in (action.help or "") else (action.help or "")
    default = "" if action.default in (None, False, argparse.SUPPRESS) or action.nargs == 0 else f"`{action.default}`"
    if isinstance(action.default, (list, tuple)):
        default = f"`{' '.join(map(str, action.default))}`"
    if action.choices is not None and "{" not in meaning:
        meaning += f" (one of: {', '.join(map(str, action.choices))})"
    if action.required and action.option_strings:
        default = "required"
    return f"| `{name}` | {default} | {_text(meaning)} |"


def _metavar(action: argparse.Action) -> str:
    if action.metavar is not None:
        name = action.metavar if isinstance(action.metavar, str) else " ".join(action.metavar)
    elif action.choices is not None and not action.option_strings:
        name = "{" + ",".join(map(str, action.choices)) + "}"
    else:
        name = action.dest.upper() if action.option_strings else action.dest
    if action.nargs in ("*", "+"):
        return f"{name} …"
    if isinstance(action.nargs, int) and action.nargs > 1 and not isinstance(action.metavar, tuple):
        return " ".join([name] * action.nargs)
    if action.nargs == "?":
        return f"[{name}]"
    return name


def _text(text: str) -> str:
    """One line of Markdown: whitespace runs collapsed, table bars escaped."""
    return " ".join(text.split()).replace("|", "\\|")
