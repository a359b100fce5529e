import numpy as np
import pytest

from runtime.policy import NanActionError, Policy, PolicyError
from tests.runtime import handmade


def _inputs(policy: Policy) -> tuple[np.ndarray, np.ndarray]:
    shapes = policy.metadata.input_shapes()
    return np.zeros(shapes["depth"][1:], np.float32), np.zeros(8, np.float32)


def test_loads_and_runs_the_contract(tmp_path):
    policy = Policy(handmade.build(tmp_path / "s.onnx"))
    actions = policy(*_inputs(policy))
    assert actions.shape == (16, 8) and actions.dtype == np.float32
    np.testing.assert_allclose(actions[:, :7], handmade.DELTA)


def test_start_noise_is_seeded(tmp_path):
    path = handmade.build(tmp_path / "s.onnx", noise_gain=1.0)
    a, b, c = (Policy(path, seed=s) for s in (7, 7, 8))
    x = _inputs(a)
    out_a, out_b, out_c = a(*x), b(*x), c(*x)
    np.testing.assert_array_equal(out_a, out_b)
    assert not np.allclose(out_a, out_c)
    assert not np.allclose(out_a, a(*x))  # fresh noise every call


def test_nan_output_is_refused(tmp_path):
    policy = Policy(handmade.build(tmp_path / "s.onnx", nan=True))
    with pytest.raises(NanActionError, match="non-finite"):
        policy(*_inputs(policy))


def test_untrained_policy_warns(tmp_path, capsys):
    Policy(handmade.build(tmp_path / "s.onnx"))
    assert "UNTRAINED" in capsys.readouterr().err


@pytest.mark.parametrize("make, match", [
    (lambda p: p, "no such policy file"),
    (lambda p: p.write_bytes(b"\x08\x07garbage-not-a-model" * 10) and p, "not a loadable ONNX model"),
    (lambda p: handmade.build(p, meta_json=""), "no 'diffudepgrasp' entry"),
    (lambda p: handmade.build(p, meta_json="{broken"), "not valid JSON"),
    (lambda p: handmade.build(p, meta_json=handmade.meta_dict(schema="diffudepgrasp.policy/0")), "schema"),
    (lambda p: handmade.build(p, meta_json=handmade.meta_dict(schema=None)), "schema"),
    (lambda p: handmade.build(p, meta_json=handmade.meta_dict(surprise=1)), "unknown"),
    (lambda p: handmade.build(p, meta=handmade.metadata(state_dim=9)), "state_dim=9"),
    (lambda p: handmade.build(p, meta=handmade.metadata(joint_offset_rad=(0.0,) * 6)), "6 angles"),
    (lambda p: handmade.build(p, horizon=8), "noise has shape"),
])
def test_bad_policy_files_are_refused_naming_file_and_problem(tmp_path, make, match):
    path = tmp_path / "student.onnx"
    make(path)
    with pytest.raises(PolicyError, match=match) as err:
        Policy(path)
    assert str(path) in str(err.value)


def test_truncated_file_is_refused(tmp_path):
    good = handmade.build(tmp_path / "good.onnx").read_bytes()
    bad = tmp_path / "cut.onnx"
    bad.write_bytes(good[: len(good) // 2])
    with pytest.raises(PolicyError, match="not a loadable ONNX model"):
        Policy(bad)


def test_exported_untrained_student_loads(untrained_student_onnx):
    policy = Policy(untrained_student_onnx)
    assert not policy.metadata.trained
    assert policy(*_inputs(policy)).shape == (policy.metadata.action_horizon, 8)
