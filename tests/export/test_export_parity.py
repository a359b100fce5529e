"""Export parity: the unrolled ONNX graph equals diffusers' DDIM loop over the torch network, through
onnxruntime, for several step counts; the file is self-describing and passes onnx.checker."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import onnx
import pytest

from export import reference
from export.__main__ import main as export_main
from export.check import CheckError, run_check
from export.graph import INPUT_NAMES, OUTPUT_NAMES, portable, read_metadata

REPO = Path(__file__).resolve().parents[2]


def test_fixture_is_a_valid_untrained_policy(untrained_student_onnx):
    model = onnx.load(str(untrained_student_onnx))
    onnx.checker.check_model(model, full_check=True)
    meta = read_metadata(model)
    assert meta.trained is False and meta.ddim_steps == 4
    assert [i.name for i in model.graph.input] == list(INPUT_NAMES)
    assert [o.name for o in model.graph.output] == list(OUTPUT_NAMES)
    shapes = {i.name: [d.dim_value for d in i.type.tensor_type.shape.dim] for i in model.graph.input}
    assert shapes == meta.input_shapes()
    assert [d.dim_value for d in model.graph.output[0].type.tensor_type.shape.dim] == [1, 16, 8]


@pytest.mark.parametrize("steps, spacing", [(1, "leading"), (4, "leading"), (8, "leading"), (16, "leading"),
                                            (4, "trailing")])
def test_onnx_matches_torch_ddim_loop(untrained_student_checkpoint, tmp_path, steps, spacing):
    out = tmp_path / f"k{steps}.onnx"
    ckpt = str(untrained_student_checkpoint)
    assert export_main([ckpt, "--ddim-steps", str(steps), "--ddim-spacing", spacing, "--out", str(out)]) == 0
    report = run_check(out, repeats=1, trials=2, threads=1)
    assert (report["ddim_steps"], report["ddim_spacing"]) == (steps, spacing)
    assert report["max_abs_err"] <= 1e-5


@pytest.mark.parametrize("inputs", [["--hand-pose"], ["--hand-pose", "--object-offset"],
                                    ["--hand-target", "--seen-offset"]])
def test_hand_pose_student_exports_with_its_kinematics_in_the_graph(tmp_path, inputs):
    """The forward kinematics (and with --object-offset the object head) are traced into the graph."""
    from tests.conftest import TINY_STUDENT
    from trainer.student.cli import main as student_main

    ckpt, out = tmp_path / "posed.pt", tmp_path / "posed.onnx"
    assert student_main(["init", "--out", str(ckpt), *inputs, *TINY_STUDENT]) == 0
    assert export_main([str(ckpt), "--ddim-steps", "2", "--out", str(out)]) == 0
    assert run_check(out, repeats=1, trials=2, threads=1)["max_abs_err"] <= 1e-5
    config = read_metadata(onnx.load(str(out))).training_data["student_config"]
    assert json.loads(config)["hand_pose"] is ("--hand-pose" in inputs)


@pytest.mark.parametrize("spacing", ["leading", "trailing"])
def test_velocity_student_exports(tmp_path, spacing):
    """A --prediction v_prediction student's graph reads its output as the velocity, as diffusers' DDIM."""
    from tests.conftest import TINY_STUDENT
    from trainer.student.cli import main as student_main

    ckpt, out = tmp_path / "v.pt", tmp_path / "v.onnx"
    assert student_main(["init", "--out", str(ckpt), "--prediction", "v_prediction", *TINY_STUDENT]) == 0
    assert export_main([str(ckpt), "--ddim-steps", "4", "--ddim-spacing", spacing, "--out", str(out)]) == 0
    assert run_check(out, repeats=1, trials=2, threads=1)["max_abs_err"] <= 1e-5
    config = read_metadata(onnx.load(str(out))).training_data["student_config"]
    assert json.loads(config)["prediction"] == "v_prediction"


def test_check_cli_json(untrained_student_onnx):
    proc = subprocess.run([sys.executable, "-m", "export.check", str(untrained_student_onnx), "--json",
                           "--repeats", "2", "--threads", "1"], capture_output=True, text=True, check=True,
                          timeout=300)
    report = json.loads(proc.stdout)
    assert {"max_abs_err", "ort_ms", "torch_ms", "speedup", "metadata"} <= set(report)
    assert report["metadata"]["schema"] == "diffudepgrasp.policy/1"
    assert np.isfinite(report["speedup"]) and report["max_abs_err"] <= 1e-5


def test_check_refuses_a_foreign_checkpoint(untrained_student_onnx, tmp_path):
    other = tmp_path / "other.pt"
    from trainer.student.cli import main as student_main
    assert student_main(["init", "--out", str(other), "--width", "8", "--head-dims", "16", "32"]) == 0
    with pytest.raises(CheckError, match="sha256"):
        run_check(untrained_student_onnx, other, repeats=1, trials=1, threads=1)


def _check_cli(*argv: str, **env: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "export.check", *argv], capture_output=True, text=True,
                          timeout=300, cwd=REPO, env={**os.environ, **env})


def test_check_on_the_shipped_file_passes_parity_on_a_clone_without_its_checkpoint(tmp_path):
    """The README's command where the checkpoint is not (a home folder without the recipe's cache): parity
    against the torch actions recorded in the file at export, never skipped; its record names no absolute
    path."""
    proc = _check_cli("models/student.onnx", "--json", "--repeats", "2", "--threads", "1", HOME=str(tmp_path))
    assert proc.returncode == 0, proc.stderr
    report = json.loads(proc.stdout)
    assert report["ort_ms"] > 0 and report["metadata"]["trained"]
    assert report["parity_against"] == "reference recorded at export" and report["max_abs_err"] <= 1e-5
    recorded = json.dumps(report["metadata"]["training_data"])
    assert not re.findall(r"(?<![\w~.])/[\w./-]+", recorded), "an absolute path in the shipped file's record"


@pytest.mark.parametrize("content, needle", [(None, "no such policy file"),
                                             (b"not a model", "not a loadable ONNX model")])
def test_check_on_a_missing_or_corrupt_file_is_one_error_line(tmp_path, content, needle):
    path = tmp_path / "student.onnx"
    if content is not None:
        path.write_bytes(content)
    proc = _check_cli(str(path), "--json")
    assert proc.returncode == 2 and proc.stdout == ""
    assert proc.stderr.count("\n") == 1 and needle in proc.stderr


def test_export_of_a_file_that_is_not_a_checkpoint_is_one_error_line(tmp_path, capsys):
    bad = tmp_path / "ckpt.pt"
    bad.write_text("not a checkpoint")  # torch.load raised an UnpicklingError with a 30-line traceback
    assert export_main([str(bad), "--ddim-steps", "4", "--out", str(tmp_path / "s.onnx")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"{bad} is not a student checkpoint" in err


def test_check_without_the_checkpoint_compares_with_the_reference_recorded_at_export(
        untrained_student_checkpoint, tmp_path):
    """A clone has the policy file but not its checkpoint: parity is still measured, against the torch
    actions recorded in the file, and a wrong record is caught."""
    ckpt, out = tmp_path / "gone.pt", tmp_path / "student.onnx"
    ckpt.write_bytes(untrained_student_checkpoint.read_bytes())
    assert export_main([str(ckpt), "--ddim-steps", "4", "--out", str(out)]) == 0
    ckpt.unlink()
    report = run_check(out, repeats=1, threads=1)
    assert report["parity_against"] == "reference recorded at export" and report["parity_skipped"] is None
    assert report["max_abs_err"] <= 1e-5 and report["torch_ms"] is None

    model = onnx.load(str(out))
    entry = next(p for p in model.metadata_props if p.key == reference.REFERENCE_KEY)
    doc = json.loads(entry.value)
    entry.value = json.dumps(doc | {"actions": (np.asarray(doc["actions"]) + 0.5).tolist()})
    onnx.save(model, out)
    assert run_check(out, repeats=1, threads=1)["max_abs_err"] == pytest.approx(0.5, abs=1e-4)


def test_metadata_names_no_absolute_path_under_the_working_or_home_folder(monkeypatch, tmp_path):
    monkeypatch.chdir(tmp_path)
    home = Path.home()
    text = f"{tmp_path}/runs/ckpt.pt --init {home}/.cache/x.pt /elsewhere/y.pt"
    assert portable(text) == "runs/ckpt.pt --init ~/.cache/x.pt /elsewhere/y.pt"
    nested = {"composed": {"head": {"recipe": f"{home}/.cache/m0", "round": 0}}, "argv": [f"{tmp_path}/a.pt"]}
    assert portable(nested) == {"composed": {"head": {"recipe": "~/.cache/m0", "round": 0}}, "argv": ["a.pt"]}
