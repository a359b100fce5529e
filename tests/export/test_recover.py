"""``python -m export.recover``: a policy file back into the checkpoints it was exported from."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import onnx
import pytest
import torch

from export.recover import main as recover_main
from trainer.student import checkpoint
from trainer.student.cli import main as student_main

TINY = ["--width", "8", "--head-dims", "16", "32", "--state-features", "16", "--prediction", "v_prediction",
        "--exec-horizon", "4"]
"""A small student of the recipe's other settings, so that the recipe can go on from it."""


def _drawn_students(folder: Path, kinds: dict[str, str]) -> dict[str, checkpoint.Checkpoint]:
    """Students of the given perceptions whose every tensor is drawn at random, as a fit leaves them, but the
    norms' scales and shifts, which stay ones and zeros as at initialisation: equal initializers that the
    exporter merges into one."""
    gen = torch.Generator().manual_seed(0)
    parts = {}
    for name, kind in kinds.items():
        assert student_main(["init", "--out", str(folder / f"{name}.pt"), *TINY, "--perception", kind]) == 0
        parts[name] = checkpoint.load(folder / f"{name}.pt")
        for key, value in parts[name].ema.items():
            if "norm" not in key.split(".")[-2] or key.endswith(("centre", "half_range")):
                value.copy_(torch.rand(value.shape, generator=gen) + 0.5)
    return parts


def _exported(folder: Path, ckpt: checkpoint.Checkpoint) -> Path:
    from export.__main__ import main as export_main

    checkpoint.save(folder / "composed.pt", ckpt)
    assert export_main([str(folder / "composed.pt"), "--out", str(folder / "student.onnx")]) == 0
    return folder / "student.onnx"


@pytest.fixture(scope="module")
def composed_file(tmp_path_factory):
    """A composed student exported to ONNX, the student and the head it was composed of."""
    from trainer.student.compose import compose

    folder = tmp_path_factory.mktemp("recover")
    parts = _drawn_students(folder, {"eye": "depth", "head": "privileged"})
    composed = compose(parts["eye"], parts["head"])
    return _exported(folder, composed), composed, parts["head"]


def test_a_composed_file_gives_back_its_student_and_its_head_exactly(composed_file, tmp_path):
    from trainer.student.compose import compose

    path, composed, head = composed_file
    assert sum(n.op_type == "Identity" for n in onnx.load(str(path)).graph.node) > 0  # merged ones are found
    assert recover_main([str(path), "--out", str(tmp_path)]) == 0
    student, recovered_head = checkpoint.load(tmp_path / "student.pt"), checkpoint.load(tmp_path / "head.pt")
    assert student.config == composed.config and student.ema.keys() == composed.ema.keys()
    assert all(torch.equal(student.ema[k], composed.ema[k]) for k in composed.ema)
    assert recovered_head.config.perception == "privileged" and recovered_head.ema.keys() == head.ema.keys()
    assert all(torch.equal(recovered_head.ema[k], head.ema[k]) for k in head.ema)
    assert student.info.depth_spec == composed.info.depth_spec
    assert student.info.data["recovered_from"]["sha256"] == checkpoint.sha256(path)
    again = compose(student, recovered_head)  # the pair composes back into the same student
    assert all(torch.equal(again.ema[k], composed.ema[k]) for k in composed.ema)


def test_a_file_of_two_perceptions_gives_back_each_and_they_compose_back_into_it(tmp_path, capsys):
    from trainer.student.compose import compose

    parts = _drawn_students(tmp_path, {"eye": "depth", "other": "depth", "head": "privileged"})
    pair = compose(parts["eye"], parts["head"], (parts["other"],))
    path = _exported(tmp_path, pair)
    capsys.readouterr()
    assert recover_main([str(path), "--out", str(tmp_path / "out")]) == 0
    assert set(json.loads(capsys.readouterr().out)["written"]) == {"student", "partner1", "head"}
    back = {name: checkpoint.load(tmp_path / "out" / f"{name}.pt") for name in ("student", "partner1",
                                                                                   "head")}
    assert back["student"].config.perceptions == back["partner1"].config.perceptions == 1
    assert back["head"].ema.keys() == parts["head"].ema.keys()
    alone = compose(parts["other"], parts["head"])  # the partner, recovered, is the other eye composed
    assert all(torch.equal(back["partner1"].ema[k], alone.ema[k]) for k in alone.ema)
    again = compose(back["student"], back["head"], (back["partner1"],))
    assert again.config == pair.config and again.ema.keys() == pair.ema.keys()
    assert all(torch.equal(again.ema[k], pair.ema[k]) for k in pair.ema)


def test_a_plain_depth_student_gives_back_one_checkpoint_and_an_earlier_student_is_refused(
        untrained_student_onnx, tmp_path, capsys):
    from export.__main__ import main as export_main

    source = tmp_path / "eye.pt"
    assert student_main(["init", "--out", str(source), *TINY, "--perception", "depth"]) == 0
    assert export_main([str(source), "--out", str(tmp_path / "eye.onnx")]) == 0
    capsys.readouterr()
    assert recover_main([str(tmp_path / "eye.onnx"), "--out", str(tmp_path / "out")]) == 0
    said = json.loads(capsys.readouterr().out)
    assert said["written"] == {"student": str(tmp_path / "out" / "student.pt")}
    assert said["max_abs_err"] <= 1e-5
    made, student = checkpoint.load(source), checkpoint.load(tmp_path / "out" / "student.pt")
    assert student.config == made.config and all(torch.equal(student.ema[k], made.ema[k]) for k in made.ema)
    assert recover_main([str(untrained_student_onnx), "--out", str(tmp_path / "old")]) == 2
    err = capsys.readouterr().err
    assert "only the recipe's depth students can be recovered" in err and err.count("\n") == 1


def test_a_wrongly_placed_weight_is_caught_by_parity_and_nothing_is_written(composed_file, tmp_path,
                                                                           monkeypatch, capsys):
    from export import recover

    real = recover._initializer_names

    def swapped(config, meta):
        names = real(config, meta)
        first, second = (n for n, k in names.items() if k in ("head.final.1.bias", "action_norm.centre"))
        names[first], names[second] = names[second], names[first]
        return names

    monkeypatch.setattr(recover, "_initializer_names", swapped)
    assert recover_main([str(composed_file[0]), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert "the recovered student's actions differ from the file's" in err and err.count("\n") == 1
    assert not (tmp_path / "out").exists()


def test_a_file_that_is_not_an_exported_student_is_refused_in_one_line(untrained_student_onnx, tmp_path,
                                                                        capsys):
    from export.graph import read_metadata, set_metadata

    text = tmp_path / "notes.onnx"
    text.write_text("not a graph")
    assert recover_main([str(text), "--out", str(tmp_path / "a")]) == 2
    assert "is not an ONNX file" in capsys.readouterr().err
    ddg = Path(__file__).parents[2] / "models" / "ddg" / "unet.onnx"  # an ONNX file, but not a policy
    assert recover_main([str(ddg), "--out", str(tmp_path / "a")]) == 2
    assert "is not a student policy file" in capsys.readouterr().err
    model = onnx.load(str(untrained_student_onnx))
    meta = read_metadata(model)
    data = {k: v for k, v in meta.training_data.items() if k != "student_config"}
    set_metadata(model, dataclasses.replace(meta, training_data=data), "{}")
    onnx.save(model, str(tmp_path / "bare.onnx"))
    assert recover_main([str(tmp_path / "bare.onnx"), "--out", str(tmp_path / "b")]) == 2
    err = capsys.readouterr().err
    assert "names no student_config" in err and err.count("\n") == 1
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()


@pytest.mark.slow
def test_the_recipe_goes_on_from_a_recovered_file(composed_file, tmp_path, short_episodes):
    """Round 0 starts from the recovered student (its head reads no depth features, hence
    ``--no-head-features``) and exports composed with the recovered head: at lr 0, the file's student."""
    from trainer.student.recipe import main as recipe_main

    path, composed, _ = composed_file
    assert recover_main([str(path), "--out", str(tmp_path / "rec")]) == 0
    rec = tmp_path / "rec"
    assert recipe_main(["--out", str(tmp_path / "r"), "--perception", "depth", "--demos", "1", "--rounds",
                        "0", "--fit-steps", "1", "--lr", "0", "--workers", "1", "--curve-episodes", "1",
                        "--eval-episodes", "1", "--width", "8", "--head-dims", "16", "32", "--state-features",
                        "16", "--batch", "2", "--init", str(rec / "student.pt"), "--no-head-features",
                        "--head", str(rec / "head.pt")]) == 0
    again = checkpoint.load(tmp_path / "r" / "fit" / "round0" / "composed.pt")
    assert again.config == composed.config
    assert all(torch.equal(again.ema[k], composed.ema[k]) for k in composed.ema)
