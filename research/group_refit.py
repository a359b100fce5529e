"""A recipe's student refitted on all its stores with chosen shares of each batch per object group, then
composed with a privileged head and exported: does weighting a scarce group (say, tall boxes as wide as the
can) teach the readout what one round at its natural share did not?

    PYTHONPATH=. python research/group_refit.py s_r192s --init $R/recipe/s_r192s/fit/round6/ckpt.pt \
        --extra $R/research/sc/round7.zarr --shares seen=0.4 scaled=0.25 squares=0.15 --steps 1200 \
        --head $R/recipe/m0_sq/fit/round0/ckpt.pt --out $R/research/sc/fit

A folder whose cache was lost has no ``recipe.json``: ``--settings`` gives the recipe's flags instead (the
readout's recorded command, ``python -m export.recover`` for its weights), and ``--extra`` all the stores.

Groups are named as ``hil_sim.objects`` names them (``DistillConfig.shares``, which a recipe's later rounds
can also set); the fit is ``trainer.student.distill`` at the recipe's other settings. Until 2026-11-30 this
script matched kinds by prefix too (``square=0.15``; the removed ``wide`` kinds): the same groups.
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

import torch

from trainer.argspec import add_dataclass_args, from_args
from trainer.sim.env import EnvConfig
from trainer.student.checkpoint import TrainingInfo
from trainer.student.distill import device, distill
from trainer.student.recipe import RecipeConfig, default_home, export, stored_settings
from trainer.student.steps import LabelledSteps
from trainer.student.train import CKPT_NAME


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("recipe", help="recipe name or folder: its stores and settings")
    parser.add_argument("--init", type=Path, required=True, help="the checkpoint to refit from")
    parser.add_argument("--shares", nargs="+", required=True, help="group=share, e.g. scaled=0.25")
    parser.add_argument("--extra", type=Path, nargs="*", default=[], help="more labelled stores to fit on")
    parser.add_argument("--steps", type=int, default=1500)
    parser.add_argument("--head", type=Path, help="a privileged head to compose the export with")
    parser.add_argument("--settings", help="the recipe's flags, where its folder has no recipe.json")
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args()
    folder = Path(args.recipe) if Path(args.recipe).is_dir() else default_home() / "recipe" / args.recipe
    cfg = settings(folder, args.settings)
    if cfg.threads:
        torch.set_num_threads(cfg.threads)
    stores = sorted(p for p in (folder / "data").glob("*.zarr") if not p.name.startswith("held_out"))
    stores += args.extra
    student = cfg.student()
    data = LabelledSteps(stores, student.obs_horizon, student.action_horizon, depth=True,
                         device=device())
    env = EnvConfig()
    info = TrainingInfo(depth_spec=data.spec, action_scale=env.action_scale,
                        control_rate_hz=env.control_rate_hz, trained=True,
                        data={"recipe": str(folder), "shares": args.shares, "steps": len(data)})
    fit = replace(cfg.distill(args.steps), shares=tuple(args.shares))
    summary = distill(data, args.out, student, fit, info, args.init)
    print(summary)
    export(args.out / CKPT_NAME, args.out / "student.onnx", cfg.ddim_steps, args.head)


def settings(folder: Path, flags: str | None) -> RecipeConfig:
    """The recipe's settings: as its folder stored them, else parsed from ``flags``."""
    if flags is None:
        return from_args(RecipeConfig, argparse.Namespace(**stored_settings(folder / "recipe.json")))
    parser = argparse.ArgumentParser(prog="--settings")
    add_dataclass_args(parser, RecipeConfig)
    return from_args(RecipeConfig, parser.parse_args(flags.split()))


if __name__ == "__main__":
    main()
