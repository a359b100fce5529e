"""Model shapes, configuration checks and checkpoint round trips."""

from __future__ import annotations

import dataclasses
import json

import pytest
import torch

from trainer.student import checkpoint
from trainer.student.cli import main as student_main
from trainer.student.config import RETIRED, StudentConfig, StudentConfigError
from trainer.student.model import StudentPolicy, hand_pose
from trainer.student.perception import SpatialSoftmax

TINY = StudentConfig(width=8, head_dims=(16, 32), state_features=16, step_features=16)


def test_noise_prediction_shape_and_conditioning():
    torch.manual_seed(0)
    net = StudentPolicy(TINY).eval()
    depth, state = torch.rand(2, 3, 96, 128), torch.randn(2, 8)
    obs = net.encode(depth, state)
    assert obs.shape == (2, 2 * TINY.keypoints + TINY.state_features)
    x, k = torch.randn(2, 16, 8), torch.tensor([3, 70])
    eps = net(x, k, obs)
    assert eps.shape == x.shape
    # the prediction must depend on the observation and on the diffusion step
    assert not torch.allclose(eps, net(x, k, net.encode(depth.flip(-1), state)))
    assert not torch.allclose(eps, net(x, torch.tensor([50, 10]), obs))


def test_hand_pose_is_where_the_simulated_arm_puts_its_grasp_site():
    """The network's forward kinematics (the published DH chain, in torch, with the model's joint-6 offset)
    puts the hand where the simulated Panda's grasp site is, over poses around the ready pose."""
    import numpy as np

    from hil_sim.kinematics import ArmKinematics
    from hil_sim.world import HOME_Q, TABLE_Z

    kinematics = ArmKinematics()
    rng = np.random.default_rng(0)
    q = np.asarray(HOME_Q) + rng.uniform(-0.6, 0.6, (16, 7))
    state = torch.from_numpy(np.column_stack([q, np.full(16, 0.08)]).astype(np.float32))
    got = hand_pose(state).numpy()
    sites = np.array([kinematics.site(np.r_[qi, 0.0, 0.0])[0] for qi in q]) - [0.0, 0.0, TABLE_Z]
    np.testing.assert_allclose(got[:, :3], sites, atol=1e-3)
    axes = got[:, 3:].reshape(16, 2, 3)
    np.testing.assert_allclose(np.linalg.norm(axes, axis=-1), 1.0, atol=1e-5)
    np.testing.assert_allclose((axes[:, 0] * axes[:, 1]).sum(-1), 0.0, atol=1e-5)


def test_hand_pose_widens_the_state_input_only_when_asked():
    plain, posed = StudentPolicy(TINY), StudentPolicy(dataclasses.replace(TINY, hand_pose=True))
    assert plain.state_mlp[0].in_features == 8 and plain.hand_norm is None
    assert posed.state_mlp[0].in_features == 8 + 9 and "hand_norm.centre" in posed.state_dict()
    state = torch.randn(2, 8)
    assert posed.encode(torch.rand(2, 3, 96, 128), state).shape == plain.encode(torch.rand(2, 3, 96, 128),
                                                                                  state).shape


def test_spatial_softmax_reads_where_the_peak_is():
    pool = SpatialSoftmax(channels=1, keypoints=1)
    with torch.no_grad():
        pool.keypoints.weight.fill_(1.0)
        pool.keypoints.bias.zero_()
    fmap = torch.zeros(2, 1, 3, 5)
    fmap[0, 0, 0, 4] = 50.0  # top right
    fmap[1, 0, 2, 0] = 50.0  # bottom left
    torch.testing.assert_close(pool(fmap), torch.tensor([[1.0, -1.0], [-1.0, 1.0]]), atol=1e-4, rtol=0)


@pytest.mark.parametrize("kwargs, match", [
    ({"width": 12}, "width"),
    ({"head_dims": (16, 20)}, "head_dims"),
    ({"action_horizon": 10, "head_dims": (16, 32, 64)}, "action_horizon"),
    ({"exec_horizon": 17}, "exec_horizon"),
    ({"keypoints": 0}, "keypoints"),
])
def test_bad_config_is_refused(kwargs, match):
    with pytest.raises(StudentConfigError, match=match):
        StudentConfig(**kwargs)


def test_checkpoints_from_before_the_retired_options_load_unless_they_used_one():
    """Configurations saved while a retired option existed record it: its "off" value is dropped, any other
    refused."""
    saved = json.loads(TINY.to_json())
    on = {"first_frame": True, "seen_turn": True, "seen_yaw": True, "fine_stride": 4, "geometric": True,
          "readout_global": False, "keypoint_values": 4}
    assert on.keys() == RETIRED.keys()
    for name, off in RETIRED.items():
        assert StudentConfig.from_json(json.dumps(saved | {name: off})) == TINY
        with pytest.raises(StudentConfigError, match=f"trained with {name} are no longer supported"):
            StudentConfig.from_json(json.dumps(saved | {name: on[name]}))


def test_checkpoint_round_trip_is_weights_only(tmp_path):
    path = tmp_path / "c.pt"
    assert student_main(["init", "--out", str(path), "--width", "8", "--head-dims", "16", "32"]) == 0
    raw = torch.load(path, weights_only=True)  # no pickled objects: must load in the safe mode
    assert raw["format"] == checkpoint.FORMAT
    ckpt = checkpoint.load(path)
    assert ckpt.config.head_dims == (16, 32) and ckpt.info.trained is False and ckpt.step == 0
    net = ckpt.policy()
    assert torch.equal(net.action_norm.half_range, torch.ones(8))
    assert all(torch.equal(v, ckpt.ema[k]) for k, v in net.state_dict().items())


def test_not_a_checkpoint_is_named(tmp_path):
    bad = tmp_path / "x.pt"
    torch.save({"weights": torch.zeros(1)}, bad)
    with pytest.raises(checkpoint.CheckpointError, match="x.pt"):
        checkpoint.load(bad)
