import json
from pathlib import Path

import numpy as np
import pytest

from trainer.ddg.data import (
    HOLDOUT_FRAMES,
    RealDataError,
    crop_spec,
    load_real_dir,
    metres_to_mm,
    policy_crop,
    source_of,
    split,
)

SHARED = str(Path(__file__).resolve().parents[2].parent / "shared" / "data" / "real_depth")  # beside the repo


def _save(path, **arrays):
    np.savez(path, **arrays)


def test_empty_directory_is_a_clear_error(tmp_path):
    with pytest.raises(RealDataError, match="no .npz depth frames"):
        load_real_dir(tmp_path)
    with pytest.raises(RealDataError, match="no .npz depth frames"):
        load_real_dir(tmp_path / "missing")


def test_frame_without_depth_is_a_clear_error(tmp_path):
    _save(tmp_path / "a.npz", rgb=np.zeros((4, 4, 3), np.uint8))
    with pytest.raises(RealDataError, match="a.npz: no 'depth_m'"):
        load_real_dir(tmp_path, "all")


def test_nans_are_a_clear_error(tmp_path):
    d = np.ones((120, 160), np.float32)
    d[3, 3] = np.nan
    _save(tmp_path / "nan.npz", depth_m=d)
    with pytest.raises(RealDataError, match="nan.npz: depth holds 1 NaN"):
        load_real_dir(tmp_path, "all")


def test_mismatched_resolutions_are_a_clear_error(tmp_path):
    _save(tmp_path / "x.npz", depth_m=np.ones((120, 160), np.float32), rgb=np.zeros((100, 160, 3), np.uint8))
    with pytest.raises(RealDataError, match=r"rgb \(100, 160\) and depth \(120, 160\)"):
        load_real_dir(tmp_path, "all")


def test_mismatched_resolutions_within_a_sequence_are_a_clear_error(tmp_path):
    _save(tmp_path / "s0.npz", depth_m=np.ones((120, 160), np.float32))
    _save(tmp_path / "s1.npz", depth_m=np.ones((240, 320), np.float32))
    frames = [{"file": f"s{i}.npz", "sequence_id": "seq", "frame_index": i, "sensor": "x"} for i in range(2)]
    (tmp_path / "MANIFEST.json").write_text(json.dumps({"frames": frames}))
    with pytest.raises(RealDataError, match="differs from the rest of sequence seq"):
        load_real_dir(tmp_path, "all")


def test_directory_without_d4xx_frames_is_a_clear_error(tmp_path):
    _save(tmp_path / "k.npz", depth_m=np.ones((120, 160), np.float32))
    entry = {"file": "k.npz", "sensor": "Kinect v1"}
    (tmp_path / "MANIFEST.json").write_text(json.dumps({"frames": [entry]}))
    assert len(load_real_dir(tmp_path, "all")) == 1
    with pytest.raises(RealDataError, match="no d4xx frames in"):
        load_real_dir(tmp_path)


def test_infinite_and_negative_depth_are_clear_errors(tmp_path):
    for name, value in (("inf", np.inf), ("neg", -0.5)):
        d = np.ones((120, 160), np.float32)
        d[0, 0] = value
        _save(tmp_path / f"{name}.npz", depth_m=d)
        with pytest.raises(RealDataError, match=f"{name}.npz: depth holds"):
            load_real_dir(tmp_path, "all")
        (tmp_path / f"{name}.npz").unlink()


def test_held_out_sources_are_refused(tmp_path):
    _save(tmp_path / "m.npz", depth_m=np.ones((120, 160), np.float32))
    entry = {"file": "m.npz", "source_repo": "NVlabs/M2T2", "sensor": "Intel RealSense D415"}
    (tmp_path / "MANIFEST.json").write_text(json.dumps({"frames": [entry]}))
    with pytest.raises(RealDataError, match="held-out source"):
        load_real_dir(tmp_path)


def test_metres_to_mm_keeps_holes():
    mm = metres_to_mm(np.array([[0.0, 0.5004, 1.2]], np.float32))
    assert mm.dtype == np.uint16 and mm.tolist() == [[0, 500, 1200]]


@pytest.mark.parametrize("hw", [(720, 1280), (480, 640), (360, 640), (386, 516), (480, 848)])
def test_crops_keep_the_policy_aspect_and_share_of_the_stream(hw):
    s = crop_spec(*hw)
    assert abs(s.crop_width / s.crop_height - 4 / 3) < 0.01
    assert abs(s.crop_height / hw[0] - 300 / 480) < 0.01
    crop, _, window = policy_crop(np.ones(hw, np.uint16), np.random.default_rng(0))
    assert crop.shape == (96, 128) and crop.dtype == np.uint16


def test_policy_crop_of_a_d455_frame_is_the_runtime_crop():
    from runtime.preprocess import DepthSpec, crop_resize

    raw = np.random.default_rng(0).integers(0, 3000, (480, 848)).astype(np.uint16)
    assert np.array_equal(policy_crop(raw)[0], crop_resize(raw, DepthSpec()))


def test_a_source_left_out_is_held_out_whole_and_an_unknown_one_is_named():
    """Leave-one-source-out: every frame of the source leaves training (the usual held-out frames too)."""
    frames = load_real_dir(SHARED)
    train, held = split(frames, leave_out="ucn_demo")
    assert {source_of(f.name) for f in frames} == {"anygrasp_tracking", "ucn_demo", "cleargrasp_d435",
                                                   "d3roma_d415"}
    assert not [f for f in train if source_of(f.name) == "ucn_demo"]
    ucn = {f.name for f in frames if f.name.startswith("ucn_demo")}
    assert {f.name for f in held} == set(HOLDOUT_FRAMES) | ucn
    assert len(train) + len(held) == len(frames) == 44
    with pytest.raises(RealDataError, match="no frames of source 'kinect'; the sources are any"):
        split(frames, leave_out="kinect")


def test_shared_data_split_keeps_holdout_out_of_training():
    frames = load_real_dir(SHARED)
    train, held = split(frames)
    assert len(frames) == 44 and {f.sensor for f in frames} == {"d4xx"}
    assert {f.name for f in held} == set(HOLDOUT_FRAMES)
    assert not {f.name for f in train} & set(HOLDOUT_FRAMES)
    assert len(list(Path(SHARED).glob("*.npz"))) == 121  # 77 other-sensor frames, filtered by the manifest
