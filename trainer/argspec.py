"""Frozen config dataclasses <-> argparse: each field becomes ``--field-name`` and its docstring the help."""

from __future__ import annotations

import argparse
import dataclasses
import inspect
from collections.abc import Callable
from typing import Any, Literal, get_args, get_origin, get_type_hints

from trainer.config_docs import field_docs


def add_dataclass_args(parser: argparse._ActionsContainer, cls: type, *, skip: tuple[str, ...] = (),
                       defaults: Literal["values", "every"] = "values") -> None:
    """One ``--field-name`` per field of ``cls`` except ``skip``: bools as --x/--no-x, tuples as lists.
    ``defaults``: the helps of flags that take one value end with its default, as "(default X)", or every
    help does, as "(default: X)" (the DDG menu's wording; each menu's --help reads as it did)."""
    docs, hints = field_docs(cls), get_type_hints(cls)
    for f in dataclasses.fields(cls):
        if f.name in skip:
            continue
        kind, default = hints[f.name], None if f.default is dataclasses.MISSING else f.default
        flag, doc = "--" + f.name.replace("_", "-"), docs.get(f.name, "")
        listed = get_origin(kind) is tuple
        if defaults == "every":
            help_ = f"{doc} (default: {default})"
        else:
            help_ = doc if kind is bool or listed else f"{doc} (default {default})"
        help_ = help_.replace("%", "%%")  # argparse formats help with %
        if kind is bool:
            parser.add_argument(flag, action=argparse.BooleanOptionalAction, default=default, help=help_)
        elif listed:
            parser.add_argument(flag, type=get_args(kind)[0], nargs="+", default=default, help=help_)
        else:
            parser.add_argument(flag, type=_scalar_type(kind), default=default, help=help_)


def from_args(cls: type, ns: argparse.Namespace, **overrides: Any) -> Any:
    """``cls`` from the parsed flags of its fields (lists back to tuples); ``overrides`` win."""
    values = {f.name: getattr(ns, f.name) for f in dataclasses.fields(cls) if hasattr(ns, f.name)}
    values = {k: tuple(v) if isinstance(v, list) else v for k, v in values.items()}
    return cls(**{**values, **overrides})


def _scalar_type(kind: Any) -> type:
    """``int`` of ``int | None``."""
    args = [a for a in get_args(kind) if a is not type(None)]
    return args[0] if args else kind


def run_config(runner: Callable[[Any], object], argv: list[str], prog: str, description: str) -> None:
    """``runner(config)`` with the config built from ``argv``: its class is what the runner's first parameter
    is annotated with (a ``trainer.menu.Menu``'s ``call`` for commands that take one config)."""
    first = next(iter(inspect.signature(runner).parameters))
    cls = get_type_hints(runner)[first]
    parser = argparse.ArgumentParser(prog=prog, description=description)
    add_dataclass_args(parser, cls, defaults="every")
    runner(from_args(cls, parser.parse_args(argv)))
