"""``python -m trainer student fit|recipe|readout|init|probe ...``; fit also runs under ``torchrun
--nproc_per_node N``."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from trainer.student import checkpoint
from trainer.student.argspec import add_dataclass_args, from_args
from trainer.student.config import StudentConfig


def cmd_init(argv: list[str]) -> int:
    p = argparse.ArgumentParser(prog="python -m trainer student init",
                                description="Write a freshly initialised (untrained) student checkpoint with "
                                "identity normalisation; export it for tests and demos of the plumbing.")
    p.add_argument("--out", type=Path, required=True, help="checkpoint file to write (.pt)")
    p.add_argument("--seed", type=int, default=0, help="weight initialisation seed")
    add_dataclass_args(p, StudentConfig)
    args = p.parse_args(argv)
    config = from_args(StudentConfig, args)
    checkpoint.save(args.out, checkpoint.fresh(config, checkpoint.TrainingInfo(), seed=args.seed))
    print(json.dumps({"out": str(args.out), "config": json.loads(config.to_json())}))
    return 0


def cmd_fit(argv: list[str]) -> int:
    from trainer.student.train import main as fit_main
    return fit_main(argv)


def cmd_recipe(argv: list[str]) -> int:
    from trainer.student.recipe import main as recipe_main
    return recipe_main(argv)


def cmd_readout(argv: list[str]) -> int:
    from trainer.student.readout import main as readout_main
    return readout_main(argv)


def cmd_probe(argv: list[str]) -> int:
    from trainer.student.probe import main as probe_main
    return probe_main(argv)


HANDLERS = {"fit": (cmd_fit, "train the student on demos (eq. 10, EMA, checkpoints, resume)"),
            "recipe": (cmd_recipe, "the student that grasps: demos, DAgger rounds, export, evaluation"),
            "readout": (cmd_readout, "a depth student's perception errors on labelled frames (M1)"),
            "init": (cmd_init, "write an untrained checkpoint (test fixtures)"),
            "probe": (cmd_probe, "offline action error of an exported student against demos")}


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if not argv or argv[0] not in HANDLERS:
        listing = "\n".join(f"  {name:<7} {help_}" for name, (_, help_) in HANDLERS.items())
        print(f"usage: python -m trainer student <command> [--help]\n\ncommands:\n{listing}", file=sys.stderr)
        return 0 if argv[:1] in (["-h"], ["--help"]) else 2
    return HANDLERS[argv[0]][0](argv[1:])
