"""A recipe folder branched at round R with settings changed, for an A/B on the same data and seeds.

Rounds 0..R-1 (their stores, fits and curve rows), round R's store (collected by round R-1's learner), the
hover store and the held-out stores of rounds before R are copied into a new recipe folder whose
``recipe.json`` holds the changed settings; the recipe command with the same changes then refits round R
there, and ``trainer compare`` pairs the two rounds' evaluations episode by episode.

    python research/recipe_branch.py s_dev s_dev_long --round 7 --set round_steps=4500
    python -m trainer student recipe --name s_dev_long --round-steps 4500 ... --rounds 7
"""

from __future__ import annotations

import argparse
import json
import shutil
from pathlib import Path

from trainer.student.recipe import default_home, stored_settings


def branch(source: Path, target: Path, round_: int, changes: dict) -> None:
    if target.exists():
        raise SystemExit(f"error: {target} exists; branch into a new folder")
    data = source / "data"
    if not ((source / "fit" / f"round{round_ - 1}").is_dir() and (data / f"round{round_}.zarr").is_dir()):
        raise SystemExit(f"error: {source} lacks round {round_ - 1}'s fit or round {round_}'s store")
    settings = stored_settings(source / "recipe.json")
    unknown = set(changes) - set(settings)
    if unknown:
        raise SystemExit(f"error: no such recipe setting: {', '.join(sorted(unknown))}")
    (target / "fit").mkdir(parents=True)
    stores = [f"round{r}" for r in range(round_ + 1)] + [f"held_out_round{r}" for r in range(round_)]
    stores.append("hover")
    for name in stores:
        if (data / f"{name}.zarr").is_dir():
            shutil.copytree(data / f"{name}.zarr", target / "data" / f"{name}.zarr")
    for r in range(round_):
        shutil.copytree(source / "fit" / f"round{r}", target / "fit" / f"round{r}")
    log = [line for line in (source / "log.jsonl").read_text().splitlines()
           if not any(f'"round {r} ' in line for r in range(round_, settings["rounds"] + 1))]
    (target / "log.jsonl").write_text("\n".join(log) + "\n")
    curve = (source / "learning_curve.csv").read_text().splitlines()[:round_ + 1]  # header + rounds 0..R-1
    (target / "learning_curve.csv").write_text("\n".join(curve) + "\n")
    (target / "recipe.json").write_text(json.dumps({**settings, **changes}, indent=1))
    print(f"{target}: rounds 0-{round_ - 1} and round {round_}'s store of {source}, with {changes}")


def folder(name: str) -> Path:
    """A recipe's folder from its name (as ``--name`` takes it) or its path."""
    return Path(name) if "/" in name else default_home() / "recipe" / name


def parse_setting(text: str) -> tuple[str, object]:
    key, sep, value = text.partition("=")
    if not sep:
        raise argparse.ArgumentTypeError(f"--set wants KEY=VALUE, got {text!r}")
    try:
        return key, json.loads(value)
    except json.JSONDecodeError:
        return key, value


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("source", help="recipe name (under the cache's recipe/) or folder")
    p.add_argument("target", help="the new recipe's name or folder")
    p.add_argument("--round", type=int, required=True, help="the round to refit in the branch (>= 1)")
    p.add_argument("--set", type=parse_setting, action="append", default=[], metavar="KEY=VALUE",
                   help="a recipe.json setting to change (JSON value), repeatable")
    a = p.parse_args()
    if a.round < 1:
        p.error("--round must be >= 1: round 0 has nothing to branch from")
    branch(folder(a.source), folder(a.target), a.round, dict(a.set))


if __name__ == "__main__":
    main()
