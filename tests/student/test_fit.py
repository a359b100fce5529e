"""``trainer student fit``: checkpoints, resume, loss curve, and torchrun (= python -m torch.distributed.run)
data parallelism with 2 gloo ranks."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest
import torch
import zarr

from runtime.preprocess import DepthSpec
from tests.conftest import write_synthetic_demos
from trainer.student import checkpoint
from trainer.student.data import DemoDataset
from trainer.student.train import DenoisingLoss, FitError, warm_start
from trainer.student.train import main as fit_main

# A reduced policy resolution keeps these runs to seconds; the model takes any H x W.
SMALL_SPEC = DepthSpec(out_height=24, out_width=32)
TINY = ["--width", "8", "--head-dims", "16", "32", "--state-features", "16", "--step-features", "16",
        "--threads", "1"]


@pytest.fixture(scope="module")
def small_demos(tmp_path_factory):
    return write_synthetic_demos(tmp_path_factory.mktemp("fit") / "demos.zarr", spec=SMALL_SPEC)


def fit_args(demos, out, steps: int) -> list[str]:
    return ["--demos", str(demos), "--out", str(out), "--steps", str(steps), "--batch", "4",
            "--ckpt-every", "2", *TINY]


def test_fit_writes_checkpoint_and_resumes(small_demos, tmp_path):
    out = tmp_path / "run"
    assert fit_main(fit_args(small_demos, out, 3)) == 0
    first = checkpoint.load(out / "ckpt.pt")
    assert first.step == 3 and len(first.losses) == 3 and first.info.trained
    assert (out / "loss.png").stat().st_size > 0
    assert first.info.data["depth_source"] == "gt" and first.info.depth_spec == SMALL_SPEC
    demos = DemoDataset(small_demos, "gt", 3, 16)
    np.testing.assert_allclose(first.policy().action_norm.summary()["low"], demos.action.min(0), atol=1e-6)
    assert fit_main(fit_args(small_demos, out, 5)) == 0
    resumed = checkpoint.load(out / "ckpt.pt")
    assert resumed.step == 5 and resumed.losses[:3] == first.losses
    assert json.loads((out / "summary.json").read_text())["steps_this_run"] == 2


def test_episodes_trains_on_the_first_episodes_and_standardises_over_them(small_demos, tmp_path):
    from trainer.student.data import DemoDataError, training_targets

    out = tmp_path / "first"
    assert fit_main([*fit_args(small_demos, out, 1), "--episodes", "1", "--hand-target"]) == 0
    data = checkpoint.load(out / "ckpt.pt").info.data
    assert data["episodes"] == 1 and data["steps"] == 12  # the store holds two 12-step episodes
    first = DemoDataset(small_demos, "gt", 3, 16, True, episodes=1)
    every = DemoDataset(small_demos, "gt", 3, 16, True)
    np.testing.assert_array_equal(first.depth, every.depth[:12])
    np.testing.assert_array_equal(first.raw_targets, every.raw_targets[:12])
    np.testing.assert_array_equal(training_targets(data, True), first.raw_targets)  # probe's reference
    assert not np.allclose(first.targets, every.targets[:12])  # standardised over the first episode alone
    with pytest.raises(DemoDataError, match="--episodes 3: .* holds 2 episodes"):
        DemoDataset(small_demos, "gt", 3, 16, episodes=3)
    with pytest.raises(FitError, match="--episodes must be >= 0"):
        fit_main([*fit_args(small_demos, out, 1), "--episodes", "-1"])


def test_resume_with_another_model_is_refused(small_demos, tmp_path):
    out = tmp_path / "run"
    assert fit_main(fit_args(small_demos, out, 1)) == 0
    with pytest.raises(FitError, match="another --out"):
        fit_main([*fit_args(small_demos, out, 2), "--width", "16"])
    with pytest.raises(FitError, match="depth_source 'gt'"):
        fit_main([*fit_args(small_demos, out, 2), "--depth-source", "randnoise"])


def test_a_missing_store_or_a_file_that_is_no_checkpoint_is_one_error_line(small_demos, tmp_path, capsys):
    bad = tmp_path / "x.pt"
    bad.write_text("not a checkpoint")  # torch.load's UnpicklingError was a 49-line traceback
    assert fit_main([*fit_args(small_demos, tmp_path / "a", 1), "--init", str(bad)]) == 2
    err = capsys.readouterr().err
    assert err == f"error: {bad} is not a student checkpoint (torch.load: UnpicklingError)\n"
    assert fit_main(fit_args(tmp_path / "none.zarr", tmp_path / "b", 1)) == 2
    assert capsys.readouterr().err.startswith("error: no demo store at ")


def test_init_starts_a_new_run_from_another_students_weights(small_demos, tmp_path):
    gt = tmp_path / "gt" / "ckpt.pt"
    assert fit_main(fit_args(small_demos, gt.parent, 3)) == 0
    source = checkpoint.load(gt)
    start = warm_start(gt, source.config, checkpoint.TrainingInfo(), DemoDataset(small_demos, "gt", 3, 16))
    assert start.step == 0 and start.optimizer is None
    assert start.info.data["init_sha256"] == checkpoint.sha256(gt)
    for name, value in source.ema.items():
        assert torch.equal(start.model[name], value) and torch.equal(start.ema[name], value), name
    tuned = tmp_path / "tuned"
    assert fit_main([*fit_args(small_demos, tuned, 1), "--depth-source", "randnoise", "--init", str(gt)]) == 0
    run = checkpoint.load(tuned / "ckpt.pt")
    assert run.step == 1 and run.info.data["depth_source"] == "randnoise" and "init_sha256" in run.info.data
    for other in (["--width", "16"], ["--hand-pose"], ["--obs-horizon", "1"]):  # a student of another shape
        with pytest.raises(FitError, match="--init"):
            fit_main([*fit_args(small_demos, tmp_path / "other", 1), *other, "--init", str(gt)])


def test_object_offset_decodes_the_object_head_in_the_demos_units(small_demos, tmp_path):
    """--object-offset: the object head's standardised estimate is turned back into metres with the same
    statistics the training targets were standardised with, and the offset from the hand enters the state
    MLP; it needs the hand pose and the object loss."""
    from trainer.student.config import StudentConfigError
    from trainer.student.model import hand_pose

    out = tmp_path / "offset"
    assert fit_main([*fit_args(small_demos, out, 1), "--hand-pose", "--object-offset"]) == 0
    net = checkpoint.load(out / "ckpt.pt").policy()
    data = DemoDataset(small_demos, "gt", 3, 16)
    decoded = net.object_norm.unnormalise(torch.from_numpy(data.targets[:, :2]))
    np.testing.assert_allclose(decoded.numpy(), data.raw_targets[:, :2], atol=1e-5)
    with torch.no_grad():
        offsets = data.raw_targets[:, :2] - hand_pose(torch.from_numpy(data.state))[:, :2].numpy()
    np.testing.assert_allclose(net.offset_norm.summary()["low"], offsets.min(0), atol=1e-5)
    assert net.state_mlp[0].in_features == 8 + 9 + 2
    with pytest.raises(FitError, match="object-loss"):
        fit_main([*fit_args(small_demos, tmp_path / "blind", 1), "--hand-pose", "--object-offset",
                  "--object-loss", "0"])
    with pytest.raises(StudentConfigError, match="hand_pose"):
        fit_main([*fit_args(small_demos, tmp_path / "handless", 1), "--object-offset"])


def test_seen_offset_feeds_the_object_heads_own_offset_reading(small_demos, tmp_path):
    """--seen-offset: the object head's estimate of object minus hand (its outputs 2:4, standardised as the
    hand-target loss is) enters the state MLP after the other inputs; it needs --hand-target."""
    from trainer.student.config import StudentConfigError

    out = tmp_path / "seen"
    assert fit_main([*fit_args(small_demos, out, 1), "--hand-target", "--hand-pose", "--seen-offset"]) == 0
    net = checkpoint.load(out / "ckpt.pt").policy()
    assert net.state_mlp[0].in_features == 8 + 9 + 2
    data = DemoDataset(small_demos, "gt", 3, 16, hand_target=True)
    batch = data.batch(np.arange(4))
    with torch.no_grad():
        features = net.encoder(batch.depth)
        torch.testing.assert_close(net.state_input(features, batch.state)[:, -2:],
                                   net.object_head(features)[:, 2:4], rtol=0, atol=0)
    with pytest.raises(StudentConfigError, match="hand_target"):
        fit_main([*fit_args(small_demos, tmp_path / "headless", 1), "--seen-offset"])


def test_torchrun_two_gloo_processes(small_demos, tmp_path):
    out = tmp_path / "ddp"
    cmd = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node", "2",
           "-m", "trainer", "student", "fit", *fit_args(small_demos, out, 3)]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=300,
                          env={**os.environ, "OMP_NUM_THREADS": "1"})
    assert proc.returncode == 0, proc.stderr[-2000:]
    summary = json.loads(proc.stdout.strip().splitlines()[-1])
    assert summary["world_size"] == 2 and len(summary["peak_rss_mb_per_rank"]) == 2
    assert summary["ranks_in_sync"] is True
    assert checkpoint.load(out / "ckpt.pt").step == 3


def test_object_loss_trains_the_object_head_and_needs_object_xy(small_demos, tmp_path):
    """The auxiliary loss reaches the object head (and through it the encoder); without it the head is
    untouched; a store that does not record object_xy is refused unless the loss is off."""
    with_aux, without = tmp_path / "aux", tmp_path / "plain"
    assert fit_main([*fit_args(small_demos, with_aux, 3), "--ema-max", "0"]) == 0
    assert fit_main([*fit_args(small_demos, without, 3), "--ema-max", "0", "--object-loss", "0"]) == 0
    trained = checkpoint.load(with_aux / "ckpt.pt")
    fresh = checkpoint.fresh(trained.config, trained.info)  # same seed: the weights the runs started from
    head = "object_head.weight"
    assert not np.allclose(trained.model[head], fresh.model[head])
    np.testing.assert_array_equal(checkpoint.load(without / "ckpt.pt").model[head], fresh.model[head])

    unplaced = write_synthetic_demos(tmp_path / "unplaced.zarr", spec=SMALL_SPEC)
    store = zarr.open_group(str(unplaced), mode="r+")
    store["meta/randomisation"][:] = np.array(["{}"] * store["meta/randomisation"].shape[0])
    with pytest.raises(FitError, match="object_xy"):
        fit_main(fit_args(unplaced, tmp_path / "refused", 1))
    assert fit_main([*fit_args(unplaced, tmp_path / "ok", 1), "--object-loss", "0"]) == 0


def test_probe_locates_with_the_object_head(small_demos, tmp_path):
    """`probe --checkpoint`'s object error is in cm against the truth, beside the training-mean answer."""
    from trainer.student.probe import locate

    out = tmp_path / "run"
    assert fit_main(fit_args(small_demos, out, 2)) == 0
    got = locate(str(out / "ckpt.pt"), str(small_demos), "gt", every=1)
    xy = np.array([[json.loads(str(r))["object_xy"]] * 12 for r in
                   zarr.open_group(str(small_demos), mode="r")["meta/randomisation"][:]]).reshape(-1, 2)
    expected = np.linalg.norm(xy - xy.mean(0), axis=1).mean() * 100
    assert got["mean_position_err_cm"] == pytest.approx(expected, rel=1e-5)
    assert 0 < got["object_err_cm"]["median"] < 1e4 and np.isfinite(got["object_err_cm"]["mean"])
    untrained = tmp_path / "untrained.pt"
    config = checkpoint.load(out / "ckpt.pt").config
    checkpoint.save(untrained, checkpoint.fresh(config, checkpoint.TrainingInfo()))
    with pytest.raises(ValueError, match="records no training demos"):
        locate(str(untrained), str(small_demos), "gt", every=1)


def test_hand_target_is_the_hand_relative_to_the_object(small_demos):
    """The hand target is the grasp site as the simulated arm puts it at each recorded joint state (a
    World posed at those joints, not the kinematic copy), relative to the episode's object position."""
    import mujoco

    from hil_sim.world import TABLE_Z, World
    from trainer.dataset import DemoStore
    from trainer.student.data import privileged_targets

    store = DemoStore.open(small_demos)
    targets = privileged_targets(store, hand_target=True)
    np.testing.assert_array_equal(targets[:, :2], privileged_targets(store, hand_target=False))
    state = np.asarray(store.root["data/state"][:])
    world = World(kinds=())
    try:
        for i in (0, 7, len(state) - 1):
            world.data.qpos[:7] = state[i, :7]
            mujoco.mj_kinematics(world.model, world.data)
            hand = world.ee_pose()[0]
            expected = [*(targets[i, :2] - hand[:2]), hand[2] - TABLE_Z]
            np.testing.assert_allclose(targets[i, 2:], expected, atol=1e-5)
    finally:
        world.close()
    assert np.ptp(targets[:, 4]) > 0.01  # the arm moves through these demos: the targets are not constant


def test_hand_target_widens_the_object_head_and_probe_reports_it(small_demos, tmp_path):
    from trainer.student.probe import locate

    out = tmp_path / "hand"
    assert fit_main([*fit_args(small_demos, out, 2), "--hand-target"]) == 0
    ckpt = checkpoint.load(out / "ckpt.pt")
    assert ckpt.config.hand_target and ckpt.model["object_head.weight"].shape[0] == 5
    got = locate(str(out / "ckpt.pt"), str(small_demos), "gt", every=1)
    assert np.isfinite(got["hand_offset_err_cm"]["median"]) and "object_err_cm" in got
    plain = tmp_path / "plain"
    assert fit_main(fit_args(small_demos, plain, 1)) == 0
    assert "hand_offset_err_cm" not in locate(str(plain / "ckpt.pt"), str(small_demos), "gt", every=1)


def _fitted(demos, tmp_path):
    path = tmp_path / "one" / "ckpt.pt"
    assert fit_main(fit_args(demos, path.parent, 1)) == 0
    return path


def test_velocity_prediction_is_trained_on_the_velocity(small_demos, tmp_path):
    """--prediction v_prediction: the denoising loss is the MSE to sqrt(a) noise - sqrt(1 - a) actions, on the
    same draws as the epsilon loss; an unknown prediction is refused."""
    from trainer.student.config import StudentConfigError

    out = tmp_path / "velocity"
    assert fit_main([*fit_args(small_demos, out, 1), "--prediction", "v_prediction"]) == 0
    net = checkpoint.load(out / "ckpt.pt").policy()
    assert net.config.prediction == "v_prediction"
    batch = DemoDataset(small_demos, "gt", 3, 16).batch(np.arange(4))
    loss = DenoisingLoss(net)
    with torch.no_grad():
        _, got = loss(batch, torch.Generator().manual_seed(3))
        g = torch.Generator().manual_seed(3)  # the loss's own draws, in its order
        clean = net.action_norm.normalise(batch.action)
        noise = torch.randn(clean.shape, generator=g)
        k = torch.randint(0, 100, (4,), generator=g)
        a = loss.scheduler.alphas_cumprod[k][:, None, None]
        velocity = a.sqrt() * noise - (1 - a).sqrt() * clean
        noisy = a.sqrt() * clean + (1 - a).sqrt() * noise
        want = torch.nn.functional.mse_loss(net(noisy, k, net.fuse(net.encoder(batch.depth), batch.state)),
                                            velocity)
    torch.testing.assert_close(got, want, atol=1e-5, rtol=1e-4)
    with pytest.raises(StudentConfigError, match="prediction"):
        fit_main([*fit_args(small_demos, tmp_path / "x0", 1), "--prediction", "sample"])


def test_a_student_is_not_fed_depth_of_another_resolution(small_demos, tiny_demos, tmp_path):
    """The encoder pools over any H x W, so a mismatch would run silently: a warm start and a dataset read
    for a trained student are refused when the demos' resolution is not the one the student learnt."""
    from trainer.student.data import DemoDataError

    plain = _fitted(small_demos, tmp_path)
    with pytest.raises(FitError, match="trained on 32x24 depth .* holds 128x96 depth"):
        fit_main([*fit_args(tiny_demos, tmp_path / "finer", 1), "--init", str(plain)])
    ckpt = checkpoint.load(plain)
    with pytest.raises(DemoDataError, match="holds 128x96 depth of a 400x300 crop; the policy reads 32x24"):
        DemoDataset.stacked_as(tiny_demos, "gt", ckpt.config, ckpt.info.depth_spec)
    assert DemoDataset.stacked_as(small_demos, "gt", ckpt.config, ckpt.info.depth_spec).spec == SMALL_SPEC
