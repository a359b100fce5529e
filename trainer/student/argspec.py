"""argparse from frozen dataclasses: one ``--flag`` per field, the field's docstring as its help."""

from __future__ import annotations

import argparse
import dataclasses
import typing

from trainer.config_docs import field_docs


def add_dataclass_args(parser: argparse.ArgumentParser, cls: type) -> None:
    """One ``--field`` per dataclass field; the field docstring (from the class source) is the help text."""
    docs = field_docs(cls)
    hints = typing.get_type_hints(cls)
    for f in dataclasses.fields(cls):
        flag = "--" + f.name.replace("_", "-")
        default = f.default if f.default is not dataclasses.MISSING else None
        kind = hints[f.name]
        if typing.get_origin(kind) is tuple:
            parser.add_argument(flag, type=int, nargs="+", default=default, help=docs.get(f.name, ""))
        elif kind is bool:
            parser.add_argument(flag, action=argparse.BooleanOptionalAction, default=default,
                                help=docs.get(f.name, ""))
        else:
            parser.add_argument(flag, type=kind if kind in (int, float, str) else str, default=default,
                                help=f"{docs.get(f.name, '')} (default {default})")


def from_args(cls: type, args: argparse.Namespace, **extra: object) -> object:
    names = {f.name for f in dataclasses.fields(cls)}
    values = {k: v for k, v in vars(args).items() if k in names}
    values = {k: tuple(v) if isinstance(v, list) else v for k, v in values.items()}
    return cls(**values, **extra)
