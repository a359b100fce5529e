"""A tiny PPO teacher trained once per session through the CLI (DAgger: 8 short expert episodes and one
learner round of 2, then 128 PPO steps, 40-step episodes): the checkpoint the reload and improvement tests
use."""

from __future__ import annotations

from pathlib import Path

import pytest

TINY = ("--objects", "cube,can", "--max-steps", "40", "--n-envs", "1", "--vec", "dummy", "--n-steps", "64",
        "--batch-size", "64", "--n-epochs", "2", "--dagger-expert-episodes", "8", "--dagger-episodes", "2",
        "--dagger-rounds", "1", "--dagger-epochs", "100", "--checkpoint-every", "64")


@pytest.fixture(scope="session")
def tiny_teacher(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from trainer.teacher.cli import main

    out = tmp_path_factory.mktemp("teacher") / "tiny"
    assert main(["fit", "--out", str(out), "--steps", "128", *TINY]) == 0
    return out
