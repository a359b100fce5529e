"""Frozen config dataclasses <-> argparse: each field becomes ``--field-name`` and its docstring the help."""

from __future__ import annotations

import argparse
import dataclasses
from typing import Any, get_args, get_origin, get_type_hints

from trainer.config_docs import field_docs


def add_dataclass_args(parser: argparse.ArgumentParser, cls: type, skip: tuple[str, ...] = ()) -> None:
    docs, hints = field_docs(cls), get_type_hints(cls)
    for f in dataclasses.fields(cls):
        if f.name in skip:
            continue
        kind = hints[f.name]
        flag = "--" + f.name.replace("_", "-")
        help_ = f"{docs.get(f.name, '')} (default: {f.default})".replace("%", "%%")
        if kind is bool:
            parser.add_argument(flag, action=argparse.BooleanOptionalAction, default=f.default, help=help_)
        elif get_origin(kind) is tuple:
            parser.add_argument(flag, type=_elem_type(kind), nargs="+", default=f.default, help=help_)
        else:
            parser.add_argument(flag, type=_scalar_type(kind), default=f.default, help=help_)


def from_args(cls: type, ns: argparse.Namespace, **overrides: Any) -> Any:
    values = {f.name: getattr(ns, f.name) for f in dataclasses.fields(cls) if hasattr(ns, f.name)}
    values = {k: tuple(v) if isinstance(v, list) else v for k, v in values.items()}
    return cls(**{**values, **overrides})


def _elem_type(kind: Any) -> type:
    return get_args(kind)[0]


def _scalar_type(kind: Any) -> type:
    args = [a for a in get_args(kind) if a is not type(None)]
    return args[0] if args else kind
