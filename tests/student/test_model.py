"""Model shapes, configuration checks and checkpoint round trips."""

from __future__ import annotations

import json

import pytest
import torch

from trainer.student import checkpoint
from trainer.student.cli import main as student_main
from trainer.student.config import StudentConfig, StudentConfigError
from trainer.student.model import PerceptionStudent, StudentPolicy, hand_pose
from trainer.student.perception import GEOMETRY_GAIN, SpatialSoftmax, geometry, looked_at

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
    plain, posed = StudentPolicy(TINY), StudentPolicy(StudentConfig(**{**TINY.__dict__, "hand_pose": True}))
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


def test_geometry_reads_the_depth_under_each_keypoint():
    frame = torch.zeros(1, 1, 8, 8)
    frame[0, 0, :4, :4] = 0.2  # the object's cell (top left of 2 x 2)
    frame[0, 0, 4:, 4:] = 0.5  # the hand's (bottom right)
    attention = torch.zeros(1, 2, 4)
    attention[0, 0, 0] = attention[0, 1, 3] = 1.0
    fine = torch.tensor([[[-1.0, -1.0], [1.0, 1.0]]])
    got = geometry(fine, attention, frame, torch.Size([2, 2])) / GEOMETRY_GAIN
    torch.testing.assert_close(got, torch.tensor([[-2.0, -2.0, 0.2, 0.5, -0.3]]))


def test_each_keypoint_reports_its_own_values_where_it_looks():
    values = torch.arange(2 * 3 * 4, dtype=torch.float32).reshape(1, 2 * 3, 2, 2)  # K=2 keypoints, V=3
    attention = torch.zeros(1, 2, 4)
    attention[0, 0, 1] = 1.0  # keypoint 0 on cell 1
    attention[0, 1, 2] = attention[0, 1, 3] = 0.5  # keypoint 1 between cells 2 and 3
    expected = torch.tensor([[1.0, 5.0, 9.0, 14.5, 18.5, 22.5]])  # its channels 0-2 / 3-5 at those cells
    torch.testing.assert_close(looked_at(values, attention), expected)


@pytest.mark.parametrize("changes", [{"readout_global": False}, {"keypoint_values": 3},
                                     {"readout_global": False, "keypoint_values": 2, "geometric": True}])
def test_the_readout_reads_the_inputs_its_layout_names(changes):
    """Each block's columns move the readout; a dropped global average leaves it blind to that input."""
    net = PerceptionStudent(StudentConfig(perception="depth", width=8, **changes)).perception
    assert net.readout[0].in_features == sum(n for _, n in net.layout)
    names = [name for name, _ in net.layout]
    assert ("global" in names) == changes.get("readout_global", True)
    assert ("values" in names) == bool(changes.get("keypoint_values"))
    hand = net.columns("hand")
    with torch.no_grad():
        net.readout[0].weight.zero_()
        net.readout[0].weight[:, hand] = 1.0  # only the hand columns speak
        depth, pose = torch.rand(2, 3, 96, 128), torch.randn(2, 9)
        first = net(depth, pose)[1]
        torch.testing.assert_close(net(torch.rand(2, 3, 96, 128), pose)[1], first)
        assert not torch.allclose(net(depth, pose + 1.0)[1], first)
    with pytest.raises(KeyError, match="no 'nothing'"):
        net.columns("nothing")


@pytest.mark.parametrize("stride, cells", [(8, 16 * 12), (4, 32 * 24)])
def test_the_fine_keypoints_attend_over_the_map_of_their_stride(stride, cells):
    perception = PerceptionStudent(StudentConfig(perception="depth", width=8, fine_stride=stride,
                                                 geometric=True)).perception
    fine_map, _ = perception.maps(torch.rand(1, 3, 96, 128))
    assert perception.fine.locate(fine_map)[1].shape[-1] == cells


@pytest.mark.parametrize("kwargs, match", [
    ({"width": 12}, "width"),
    ({"fine_stride": 2}, "fine_stride"),
    ({"head_dims": (16, 20)}, "head_dims"),
    ({"action_horizon": 10, "head_dims": (16, 32, 64)}, "action_horizon"),
    ({"exec_horizon": 17}, "exec_horizon"),
    ({"keypoints": 0}, "keypoints"),
    ({"keypoint_values": -1}, "keypoint_values"),
])
def test_bad_config_is_refused(kwargs, match):
    with pytest.raises(StudentConfigError, match=match):
        StudentConfig(**kwargs)


def test_checkpoints_from_before_the_retired_options_load_unless_they_used_one():
    """Configurations saved while first_frame, seen_turn and seen_yaw existed record them: false is dropped,
    true refused."""
    saved = json.loads(TINY.to_json())
    for name in ("first_frame", "seen_turn", "seen_yaw"):
        assert StudentConfig.from_json(json.dumps(saved | {name: False})) == TINY
        with pytest.raises(StudentConfigError, match=f"trained with {name} are no longer supported"):
            StudentConfig.from_json(json.dumps(saved | {name: True}))


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
