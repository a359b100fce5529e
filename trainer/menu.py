"""Subcommand menus, one table each: ``python -m trainer <command>``, ``python -m trainer ddg <command>``, ...

A menu maps a command name to its help line and the function that runs it, as "module:function": the module
loads only when its command runs, so ``ddg generate`` needs no training code. Asked-for help is output
(stdout, exit 0); a missing or unknown command is the usage and one error line naming it (stderr, exit 2).
"""

from __future__ import annotations

import importlib
import shlex
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path


def call_with_argv(function: Callable, argv: list[str], prog: str, description: str) -> int | None:
    """How a menu runs a command by default: its function takes the rest of the command line."""
    return function(argv)


@dataclass(frozen=True)
class Menu:
    prog: str
    """How the menu is invoked, e.g. "python -m trainer ddg"."""
    commands: dict[str, tuple[str, str]]
    """Command -> (help line, "module:function")."""
    errors: tuple[type[Exception], ...] = ()
    """Errors a command may end with on bad input: printed as one ``error:`` line, exit status 2."""
    call: Callable[[Callable, list[str], str, str], int | None] = call_with_argv
    """(function, the rest of the command line, the command's prog, its help line) -> exit status."""

    def main(self, argv: list[str] | None = None) -> int:
        argv = sys.argv[1:] if argv is None else argv
        if argv[:1] in (["-h"], ["--help"]):
            print(self.usage())
            return 0
        if not argv or argv[0] not in self.commands:
            problem = f"unknown command {argv[0]!r}" if argv else "no command given"
            print(f"{self.usage()}\n{self.prog}: error: {problem}", file=sys.stderr)
            return 2
        name, rest = argv[0], argv[1:]
        help_, target = self.commands[name]
        try:
            return self.call(load(target), rest, f"{self.prog} {name}", help_) or 0
        except self.errors as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2

    def usage(self) -> str:
        width = max(map(len, self.commands))
        listing = "\n".join(f"  {name:<{width}}  {help_}" for name, (help_, _) in self.commands.items())
        return f"usage: {self.prog} <command> [--help]\n\ncommands:\n{listing}"


def load(target: str) -> Callable:
    """The function named "module:function"."""
    module, _, function = target.partition(":")
    return getattr(importlib.import_module(module), function)


def command_line(argv: list[str] | None = None) -> str:
    """The running command as a user would type it again, for a result's record: ``python -m trainer ...``,
    not the path of the package's ``__main__.py`` that ``sys.argv[0]`` holds under ``-m``."""
    argv = sys.argv if argv is None else argv
    program = Path(argv[0])
    if program.name == "__main__.py":
        return shlex.join(["python", "-m", program.parent.name, *argv[1:]])
    return shlex.join(argv)
