"""Command-line mistakes answered before anything heavy is imported.

The full parser is built from the components' settings, which needs torch (several seconds).
:data:`TABLE` (``flag_table.json`` beside this file, generated from the full parser by
:func:`flag_table`; a test keeps them equal) lists every command's flags, how many values each
takes and its choices, so a typo (``train --epcohs 5``), an unknown command or choice, or a
``--data`` path that does not exist is answered in a fraction of a second, with the closest
match. Standard library only.
"""

from __future__ import annotations

import argparse
import difflib
import json
from pathlib import Path
from typing import Any

TABLE_FILE = Path(__file__).with_name("flag_table.json")
#: flags whose value is a path that must exist, per command
EXISTING_PATHS = {"train": ("--data", "--config"), "evaluate": ("--data",)}
HELP = ("-h", "--help")


class QuickError(Exception):
    """A command-line mistake: ``command`` (or None) and the message argparse would print."""

    def __init__(self, command: str | None, message: str) -> None:
        super().__init__(message)
        self.command = command


def flag_table(parser: argparse.ArgumentParser) -> dict[str, Any]:
    """``{"commands": {name: {flag: [nargs, choices]}}}`` of the full parser; ``nargs`` is 0 for
    a switch, 1 for one value, 2 for an optional value, -1 for one or more; ``choices`` a
    sorted list or None."""
    out: dict[str, Any] = {"top": _flags(parser), "commands": {}}
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                entry = _flags(sub)
                if any(isinstance(a, argparse._SubParsersAction) for a in sub._actions):
                    entry = {"": None}  # a command with its own sub-commands (bench): not checked
                out["commands"][name] = entry
    return out


def _flags(parser: argparse.ArgumentParser) -> dict[str, Any]:
    table: dict[str, Any] = {}
    for a in parser._actions:
        nargs = a.nargs
        n = {0: 0, "?": 2, "+": -1, "*": -1}.get(nargs, 1)  # type: ignore[arg-type]
        choices = sorted(map(str, a.choices)) if a.choices and not isinstance(
            a, argparse._SubParsersAction) else None  # fmt: skip
        for flag in a.option_strings:
            if flag.startswith("--"):
                table[flag] = [n, choices]
    return dict(sorted(table.items()))


def check(argv: list[str], table: dict[str, Any] | None = None) -> None:
    """Raise :class:`QuickError` for what the full parser would refuse anyway: an unknown
    command, flag or choice, a missing value, or a path (``--data``) that does not exist.
    Anything this check does not understand is left to the full parser."""
    if any(tok in HELP for tok in argv) or "--version" in argv:
        return
    if table is None:
        try:
            table = json.loads(TABLE_FILE.read_text())
        except (OSError, ValueError):
            return
    args = [tok for tok in argv if tok not in ("-v", "--verbose")]
    if not args or args[0].startswith("-"):
        return
    command, rest = args[0], args[1:]
    commands = table["commands"]
    if command not in commands:
        if command in ("train.py",):
            return
        guess = difflib.get_close_matches(command, list(commands), n=1)
        hint = f" (did you mean {guess[0]}?)" if guess else ""
        raise QuickError(None, f"argument command: invalid choice: {command!r}{hint}")
    flags = commands[command]
    if "" in flags:
        return
    i = 0
    while i < len(rest):
        tok = rest[i]
        i += 1
        if not tok.startswith("--") or tok == "--":
            if tok == "--":
                return
            continue
        name, eq, value = tok.partition("=")
        flag = _resolve(name, flags, command)
        n, choices = flags[flag]
        values: list[str] = [value] if eq else []
        if n and not eq:
            while i < len(rest) and not (rest[i].startswith("--") and len(rest[i]) > 2):
                values.append(rest[i])
                i += 1
                if n in (1, 2):
                    break
            if not values and n != 2:
                raise QuickError(command, f"argument {flag}: expected "
                                 f"{'one argument' if n == 1 else 'at least one argument'}")  # fmt: skip
        if choices is not None:
            for v in values:
                if v not in choices:
                    guess = difflib.get_close_matches(v, choices, n=1)
                    hint = f"; did you mean {guess[0]}?" if guess else ""
                    raise QuickError(command, f"argument {flag}: invalid choice: {v!r} (choose "
                                     f"from {', '.join(choices)}{hint})")  # fmt: skip
        if flag in EXISTING_PATHS.get(command, ()) and values and not Path(values[0]).exists():
            raise QuickError(command, f"{flag} {values[0]}: no such file or folder")


def _resolve(name: str, flags: dict[str, Any], command: str) -> str:
    """``name`` or the one flag it abbreviates (as argparse allows), else a QuickError."""
    if name in flags:
        return name
    starts = [f for f in flags if f.startswith(name)]
    if len(starts) == 1:
        return starts[0]
    if len(starts) > 1:
        raise QuickError(command, f"ambiguous option: {name} could match {', '.join(starts)}")
    guess = difflib.get_close_matches(name, list(flags), n=1)
    hint = f" ({name}: did you mean {guess[0]}?)" if guess else ""
    raise QuickError(command, f"unrecognized arguments: {name}{hint}")
