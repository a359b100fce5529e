import numpy as np
import pytest

from trainer.student.data import DemoDataset
from trainer.student.probe import main, probe


def test_probe_compares_the_policy_with_the_demo_actions(untrained_student_onnx, tiny_demos):
    got = probe(str(untrained_student_onnx), str(tiny_demos), "gt", every=5)
    data = DemoDataset(tiny_demos, "gt", 3, 16)
    steps = np.arange(0, len(data), 5)
    zero = np.mean([np.abs(data.action[data.action_indices(int(i))][:8, :7]).mean() for i in steps])
    assert got["steps"] == len(steps)
    assert got["zero_predictor_err"] == pytest.approx(zero, rel=1e-6)
    # random weights: off by a clearly non-zero amount, and the gripper sign is a fraction
    assert got["joint_abs_err"] > 0.01 and 0.0 <= got["gripper_sign_agreement"] <= 1.0
    # another step's depth changes what even a random network does ...
    assert got["shuffled_depth_err"] > 0.01 and got["shuffled_depth_err"] != got["joint_abs_err"]


def test_probe_reports_no_gap_for_a_depth_blind_policy(untrained_student_onnx, tiny_demos, monkeypatch):
    """... and a policy that ignores its depth gets the same error with swapped depth (paired noise)."""
    from runtime.policy import Policy

    original = Policy.__call__
    monkeypatch.setattr(Policy, "__call__", lambda self, depth, state, noise=None:
                        original(self, np.zeros_like(depth), state, noise))
    got = probe(str(untrained_student_onnx), str(tiny_demos), "gt", every=5)
    assert got["shuffled_depth_err"] == pytest.approx(got["joint_abs_err"], rel=1e-6)


def test_probe_refuses_a_zero_stride(untrained_student_onnx, tiny_demos):
    with pytest.raises(SystemExit):
        main(["--policy", str(untrained_student_onnx), "--demos", str(tiny_demos), "--every", "0"])


def test_probe_of_an_absolute_student_reads_steps_from_the_current_state(tiny_demos, tmp_path):
    """Targets are compared as steps from the probed step's state, so "stay where you are" is the zero
    predictor in both modes: its first step is the demo's own (clipped) action."""
    from export.__main__ import main as export_main
    from tests.conftest import TINY_STUDENT
    from trainer.student.cli import main as student_main

    ckpt, onnx_path = tmp_path / "abs.pt", tmp_path / "abs.onnx"
    assert student_main(["init", "--out", str(ckpt), *TINY_STUDENT, "--action-mode", "absolute"]) == 0
    assert export_main([str(ckpt), "--ddim-steps", "2", "--out", str(onnx_path)]) == 0
    got = probe(str(onnx_path), str(tiny_demos), "gt", every=5)
    data = DemoDataset(tiny_demos, "gt", 3, 16, action_mode="absolute")
    s = data.action_scale
    steps = np.arange(0, len(data), 5)
    zero = np.mean([np.abs(data.action[data.action_indices(int(i))][:8, :7] - data.state[i, :7]).mean() / s
                    for i in steps])
    assert got["zero_predictor_err"] == pytest.approx(zero, rel=1e-5)
    first = DemoDataset(tiny_demos, "gt", 3, 16).action[steps, :7]
    np.testing.assert_allclose((data.action[steps, :7] - data.state[steps, :7]) / s, np.clip(first, -1, 1),
                               atol=1e-4)
    assert got["joint_abs_err"] > 0.01
