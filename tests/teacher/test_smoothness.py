"""``teacher smoothness``: success with its interval and eq. 7's mean squared joint acceleration."""

from __future__ import annotations

from trainer.teacher.smoothness import measure


def test_scripted_expert_grasps_and_moves_its_joints():
    result = measure("scripted", ("cube",), 3, workers=1)
    assert result["success_rate"] == 1.0 and result["per_object"] == {"cube": 1.0}
    lo, hi = result["ci95"]
    assert 0.3 < lo < 1.0 == hi
    mean, p99 = result["mean_sq_joint_accel"], result["p99_sq_joint_accel"]
    assert 0.0 < mean <= p99
    assert 20 < result["mean_steps"] < 150
