"""The policy depth's resolution is a choice of the demos (``collect --resolution``) and travels with the
student: the evaluator renders what the student file reads."""

from __future__ import annotations

import json

import numpy as np
import pytest

from runtime.preprocess import DepthSpec
from tests.conftest import TINY_STUDENT, write_synthetic_demos
from trainer.collect import main as collect_main
from trainer.dataset import DemoStore
from trainer.eval.success import main as evaluate_main
from trainer.policies import depth_spec

COARSE = DepthSpec(out_height=24, out_width=32)


def test_collect_stores_the_asked_resolution_and_resumes_only_at_it(tmp_path, capsys) -> None:
    out = tmp_path / "fine.zarr"
    args = ["--objects", "cube", "--out", str(out), "--workers", "1"]
    assert collect_main(["--episodes", "1", *args, "--resolution", "64x48"]) == 0
    store = DemoStore.open(out)
    assert store.depth_spec == DepthSpec(out_height=48, out_width=64)
    depth = store.episode(0)["depth"]
    assert depth.shape[1:] == (48, 64) and (depth > 0).mean() > 0.5
    assert collect_main(["--episodes", "2", *args]) == 2
    assert "keeps 64x48 depth of a 400x300 crop, not 128x96" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        collect_main(["--episodes", "1", *args, "--resolution", "64by48"])
    assert "resolution must be WIDTHxHEIGHT" in capsys.readouterr().err


def test_a_student_teacher_of_another_resolution_is_refused(untrained_student_onnx, tmp_path, capsys):
    out = tmp_path / "student.zarr"
    teacher = f"student:{untrained_student_onnx}"
    assert collect_main(["--episodes", "1", "--teacher", teacher, "--out", str(out), "--workers", "1",
                         "--resolution", "64x48"]) == 2
    assert "reads 128x96 depth of a 400x300 crop: pass its resolution" in capsys.readouterr().err
    assert not out.exists()


def test_evaluate_renders_the_depth_the_student_file_reads(tmp_path) -> None:
    """A student trained on 32x24 depth runs in the evaluator (96x128 frames would not fit its graph)."""
    from export.__main__ import main as export_main
    from trainer.student.train import main as fit_main

    demos = write_synthetic_demos(tmp_path / "coarse.zarr", spec=COARSE)
    assert fit_main(["--demos", str(demos), "--out", str(tmp_path / "run"), "--steps", "1", "--batch", "2",
                     *TINY_STUDENT, "--threads", "1"]) == 0
    onnx = tmp_path / "coarse.onnx"
    assert export_main([str(tmp_path / "run" / "ckpt.pt"), "--ddim-steps", "2", "--out", str(onnx)]) == 0
    assert depth_spec(f"student:{onnx}") == COARSE and depth_spec("scripted") == DepthSpec()
    result = tmp_path / "eval.json"
    assert evaluate_main(["--policy", f"student:{onnx}", "--objects", "cube", "--episodes", "1",
                          "--json", str(result)]) == 0
    report = json.loads(result.read_text())
    assert report["episodes"] == 1 and 0 <= report["success_rate"] <= 1
    assert np.isfinite(report["mean_steps"])
