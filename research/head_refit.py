"""The privileged head (M0) refitted on more labelled steps than its own recipe collected (issue 42).

M0 (``trainer student recipe --perception privileged``) learned from 400 expert demos and its own four DAgger
rounds. The depth students' recipes have since labelled many more states: 2000 expert demos and the composed
learner's own rounds, whose states come from a readout's errors, which M0's rounds never visit. Each step's
labels hold the true facts, so any store trains the head. This refits M0 from its weights (normalisers kept,
so it still composes with the depth readouts trained against it) on the given stores, then measures it as
``trainer evaluate --policy oracle:CKPT`` does on seen and unseen kinds. Writes ``OUT/result.json``.

    python research/head_refit.py --init M0.pt --stores S0 S1 ... --out DIR [--steps 12000] [--lr 1e-4] \\
        [--episodes 180] [--threads 1]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

import torch

from hil_sim.objects import GROUPS
from trainer.eval.success import evaluate
from trainer.student import checkpoint
from trainer.student.distill import DistillConfig, distill
from trainer.student.steps import LabelledSteps
from trainer.student.train import CKPT_NAME


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--init", type=Path, required=True, help="the privileged head to refit (M0's ckpt.pt)")
    p.add_argument("--stores", type=Path, nargs="+", required=True)
    p.add_argument("--steps", type=int, default=12000)
    p.add_argument("--batch", type=int, default=128)
    p.add_argument("--lr", type=float, default=1e-4)
    p.add_argument("--episodes", type=int, default=180, help="per group, seeds 10000..")
    p.add_argument("--workers", type=int, default=1)
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--out", type=Path, required=True)
    args = p.parse_args()
    torch.set_num_threads(args.threads)
    source = checkpoint.load(args.init)
    if source.config.perception != "privileged":
        raise SystemExit(f"{args.init} is a {source.config.perception} student, not a privileged head")
    cfg = source.config
    data = LabelledSteps(args.stores, cfg.obs_horizon, cfg.action_horizon, depth=False)
    provenance = {"init": str(args.init), "stores": [str(s) for s in args.stores]}
    info = dataclasses.replace(source.info, data={**provenance, "steps": len(data)})
    fit = distill(data, args.out, cfg, DistillConfig(steps=args.steps, batch=args.batch, lr=args.lr),
                  info, args.init)
    result = {**provenance, "fit": fit}
    for group in ("seen", "unseen"):
        run = evaluate(f"oracle:{args.out / CKPT_NAME}", GROUPS[group], args.episodes, workers=args.workers)
        result[group] = {k: run[k] for k in ("success_rate", "ci95", "per_object", "first_close",
                                             "failed_seeds")}
        print(group, json.dumps(result[group]), flush=True)
    (args.out / "result.json").write_text(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
