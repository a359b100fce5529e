"""``python -m trainer student fit|recipe|refit|readout|compose|init|probe ...``; fit also runs under
``torchrun --nproc_per_node N``."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from trainer.argspec import add_dataclass_args, from_args
from trainer.menu import Menu
from trainer.student import checkpoint
from trainer.student.config import StudentConfig


def init(argv: list[str]) -> int:
    """``student init``: write an untrained checkpoint."""
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


MENU = Menu("python -m trainer student", {
    "fit": ("train the student on demos (eq. 10, EMA, checkpoints, resume)", "trainer.student.train:main"),
    "recipe": ("the student that grasps: demos, DAgger rounds, export, evaluation",
               "trainer.student.recipe:main"),
    "refit": ("a depth student refitted on given labelled stores, with shares per object group",
              "trainer.student.refit:main"),
    "readout": ("a depth student's perception errors on labelled frames (M1)",
                "trainer.student.readout:main"),
    "compose": ("one depth student from a depth student's perception and a privileged head (M0)",
                "trainer.student.compose:main"),
    "init": ("write an untrained checkpoint (test fixtures)", "trainer.student.cli:init"),
    "probe": ("offline action error of an exported student against demos", "trainer.student.probe:main"),
})
main = MENU.main
