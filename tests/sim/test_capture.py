"""``trainer.sim.capture``: a scene sensor's frames as a real-capture directory the DDG can train on."""

from __future__ import annotations

import json

import numpy as np
import pytest

from runtime.preprocess import DepthSpec, crop_resize
from trainer.ddg.bank import fused_frames
from trainer.ddg.data import load_real_dir
from trainer.eval.realism import _crops
from trainer.sim.capture import CaptureError, capture, main
from trainer.sim.env import EnvConfig, GraspEnv
from trainer.sim.rollout import expert_scenes


def test_frames_read_back_as_d4xx_sequences_one_per_episode(tmp_path):
    n = capture("stereo", ("cube",), 2, (0, 5), 70_000, tmp_path / "a")
    frames = load_real_dir(tmp_path / "a")
    assert n == len(frames) == 4
    assert {f.sensor for f in frames} == {"d4xx"}
    assert sorted((f.sequence, f.index) for f in frames) == [("seed70000", 0), ("seed70000", 5),
                                                             ("seed70001", 0), ("seed70001", 5)]
    assert all(f.depth_mm.shape == (480, 848) for f in frames)
    holes = np.mean([np.mean(f.depth_mm == 0) for f in frames])
    assert 0.01 < holes < 0.9  # a stereo frame: depth with holes, neither empty nor complete
    assert len(fused_frames(frames)) == 4  # the DDG's temporal fusion runs over each episode's frames
    for f in frames:  # the renderer's exact depth of the same view, for `ddg fit --prior exact`
        both = (f.depth_mm > 0) & (f.exact_mm > 0)
        assert f.exact_mm.shape == f.depth_mm.shape and both.mean() > 0.3
        assert np.median(np.abs(f.depth_mm[both].astype(int) - f.exact_mm[both])) < 15
    manifest = json.loads((tmp_path / "a" / "MANIFEST.json").read_text())
    assert manifest["n_frames"] == 4 and "RealSense D455" in manifest["frames"][0]["sensor"]


def test_frames_keep_their_episode_policy_window_and_are_judged_there(tmp_path):
    capture("stereo", ("pear",), 1, (0,), 70_200, tmp_path / "w")
    (frame,) = load_real_dir(tmp_path / "w")
    env = GraspEnv(EnvConfig(objects=("pear",), render_depth=False))
    try:
        env.reset(seed=70_200, options={"kind": "pear"})
        window = env.world.episode.crop_window
    finally:
        env.close()
    assert frame.window == tuple(window)
    crops, _ = _crops([frame], np.zeros(3, int), np.random.default_rng(0))  # the metrics' reference crops
    for crop in crops:
        np.testing.assert_array_equal(crop, crop_resize(frame.depth_mm, DepthSpec(), window))


def test_same_seed_same_frames(tmp_path):
    for out in ("a", "b"):
        capture("stereo", ("apple",), 1, (3,), 70_100, tmp_path / out)
    (a,), (b,) = load_real_dir(tmp_path / "a"), load_real_dir(tmp_path / "b")
    np.testing.assert_array_equal(a.depth_mm, b.depth_mm)


def test_refuses_a_clean_sensor_and_an_existing_capture(tmp_path, capsys):
    with pytest.raises(CaptureError, match="scene sensor"):
        capture("clean", ("cube",), 1, (0,), 70_000, tmp_path / "c")
    capture("stereo", ("cube",), 1, (0,), 70_000, tmp_path / "d")
    assert main(["--episodes", "1", "--steps", "0", "--objects", "cube", "--out", str(tmp_path / "d")]) == 2
    assert "already holds a capture" in capsys.readouterr().err
    assert main(["--episodes", "0", "--out", str(tmp_path / "e")]) == 2


def test_expert_scenes_stop_at_the_end_of_an_episode():
    env = GraspEnv(EnvConfig(objects=("cube",), render_depth=False, max_steps=12))
    try:
        seen = [(ep, step) for ep, step, _ in expert_scenes(env, ("cube",), 2, (0, 11, 40), 0)]
    finally:
        env.close()
    assert seen == [(0, 0), (0, 11), (1, 0), (1, 11)]  # step 40 lies past the 12-step episodes
