"""A recipe's student refitted on all its stores with chosen shares of each batch per object group, then
composed with a privileged head and exported: does weighting a scarce group (say, tall boxes as wide as the
can) teach the readout what one round at its natural share did not?

    PYTHONPATH=. python research/group_refit.py s_r192ws --init $R/recipe/s_r192ws/fit/round7/ckpt.pt \
        --shares seen=0.4 wide=0.25 square=0.15 --steps 1500 --head $R/recipe/m0_sq/fit/round0/ckpt.pt \
        --out $R/research/wfit

Groups are named as ``hil_sim.objects`` names them or by a kind's prefix; every step of a group not named
shares what is left. The fit is ``trainer.student.distill`` with only its batch weights replaced, at the
recipe's settings.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch

from hil_sim.objects import GROUPS, SEEN
from trainer.sim.env import EnvConfig
from trainer.student import distill as distill_module
from trainer.student.checkpoint import TrainingInfo
from trainer.student.recipe import RecipeConfig, default_home, export, stored_settings
from trainer.student.steps import LabelledSteps
from trainer.student.train import CKPT_NAME


def group_of(kind: str, names: list[str]) -> str:
    """``seen``, else the first name that is a group of ``hil_sim.objects`` holding the kind or the kind's
    prefix (the stores keep kinds that a later commit may have removed), else ``rest``."""
    if kind in SEEN:
        return "seen"
    named = (n for n in names if n != "seen" and (kind in GROUPS.get(n, ()) or kind.startswith(n)))
    return next(named, "rest")


def group_weights(kinds: np.ndarray, shares: dict[str, float]) -> torch.Tensor:
    """Each step's chance of being drawn: a named group holds its share of a batch, the rest what is left."""
    groups = np.array([group_of(k, list(shares)) for k in kinds])
    left = 1.0 - sum(shares.values())
    weights = np.zeros(len(kinds))
    for name in set(groups):
        share = shares.get(name, left)
        members = groups == name
        weights[members] = share / members.sum()
        print(f"group {name}: {members.sum()} steps, share {share:.2f}")
    missing = set(shares) - set(groups)
    if missing:
        raise SystemExit(f"error: no steps of the groups {sorted(missing)}")
    return torch.from_numpy(weights)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("recipe", help="recipe name or folder: its stores and settings")
    parser.add_argument("--init", type=Path, required=True, help="the checkpoint to refit from")
    parser.add_argument("--shares", nargs="+", required=True, help="group=share, e.g. wide=0.25")
    parser.add_argument("--extra", type=Path, nargs="*", default=[], help="more labelled stores to fit on")
    parser.add_argument("--steps", type=int, default=1500)
    parser.add_argument("--head", type=Path, help="a privileged head to compose the export with")
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args()
    folder = Path(args.recipe) if Path(args.recipe).is_dir() else default_home() / "recipe" / args.recipe
    cfg = RecipeConfig(**{k: (tuple(v) if isinstance(v, list) else v)
                          for k, v in stored_settings(folder / "recipe.json").items()})
    if cfg.threads:
        torch.set_num_threads(cfg.threads)
    shares = {name: float(v) for name, _, v in (s.partition("=") for s in args.shares)}
    stores = sorted(p for p in (folder / "data").glob("*.zarr") if not p.name.startswith("held_out"))
    stores += args.extra
    student = cfg.student()
    data = LabelledSteps(stores, student.obs_horizon, student.action_horizon, depth=True,
                         device=distill_module.device())
    distill_module.batch_weights = lambda kinds, _share: group_weights(kinds, shares)
    env = EnvConfig()
    info = TrainingInfo(depth_spec=data.spec, action_scale=env.action_scale,
                        control_rate_hz=env.control_rate_hz, trained=True,
                        data={"recipe": str(folder), "shares": shares, "steps": len(data)})
    summary = distill_module.distill(data, args.out, student, cfg.distill(args.steps), info, args.init)
    print(summary)
    export(args.out / CKPT_NAME, args.out / "student.onnx", cfg.ddim_steps, args.head)


if __name__ == "__main__":
    main()
