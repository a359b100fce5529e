"""Dataclass <-> argparse (trainer.argspec): flags, help wording, round trip, one-config commands."""

from __future__ import annotations

import argparse
from dataclasses import dataclass

import pytest

from trainer.argspec import add_dataclass_args, from_args, run_config


@dataclass(frozen=True)
class Toy:
    out: str
    """Where to write."""
    steps: int = 10
    """Steps; 100 % of them."""
    rate: float | None = None
    """Rate."""
    fast: bool = False
    """Go fast."""
    sizes: tuple[int, ...] = (1, 2)
    """Sizes."""
    names: tuple[str, ...] = ("a",)
    """Names."""

    def __post_init__(self) -> None:
        if self.steps < 0:
            raise ValueError(f"--steps must be >= 0, got {self.steps}")


def _helps(defaults: str) -> dict[str, str]:
    p = argparse.ArgumentParser()
    add_dataclass_args(p, Toy, skip=("names",), defaults=defaults)
    return {a.dest: a.help for a in p._actions if a.dest != "help"}


def test_helps_name_the_defaults_in_either_wording_and_survive_a_percent_sign() -> None:
    assert _helps("every") == {"out": "Where to write. (default: None)",
                               "steps": "Steps; 100 %% of them. (default: 10)",
                               "rate": "Rate. (default: None)", "fast": "Go fast. (default: False)",
                               "sizes": "Sizes. (default: (1, 2))"}
    assert _helps("values") == {"out": "Where to write. (default None)",
                                "steps": "Steps; 100 %% of them. (default 10)",
                                "rate": "Rate. (default None)", "fast": "Go fast.", "sizes": "Sizes."}
    p = argparse.ArgumentParser()
    add_dataclass_args(p, Toy)
    assert "100 % of them" in p.format_help()


def test_flags_round_trip_to_the_config_and_overrides_win() -> None:
    p = argparse.ArgumentParser()
    add_dataclass_args(p, Toy)
    ns = p.parse_args(["--out", "x", "--steps", "3", "--rate", "0.5", "--fast", "--sizes", "4", "5",
                       "--names", "b", "c"])
    assert from_args(Toy, ns) == Toy("x", 3, 0.5, True, (4, 5), ("b", "c"))
    assert from_args(Toy, ns, steps=7).steps == 7
    assert from_args(Toy, p.parse_args(["--out", "y", "--no-fast"])) == Toy("y")


def run_toy(cfg: Toy) -> dict:
    print(cfg)
    return {"ignored": True}


def test_a_one_config_command_parses_its_runners_config(capsys) -> None:
    assert run_config(run_toy, ["--out", "z", "--steps", "2"], "python -m toy run", "run a toy") is None
    assert capsys.readouterr().out.strip() == str(Toy("z", 2))
    with pytest.raises(SystemExit):
        run_config(run_toy, ["--help"], "python -m toy run", "run a toy")
    out = capsys.readouterr().out
    assert out.startswith("usage: python -m toy run") and "run a toy" in out and "(default: 10)" in out
    with pytest.raises(ValueError, match="--steps must be >= 0"):
        run_config(run_toy, ["--out", "z", "--steps", "-1"], "python -m toy run", "run a toy")
