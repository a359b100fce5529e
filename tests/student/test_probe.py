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
