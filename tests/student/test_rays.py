"""Metric rays (``StudentConfig.rays``): the two channels are each pixel's camera-frame X, Y at its depth, a
student given them at zero weight reads as before, and a refit with ``--rays`` starts there and exports."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from runtime.preprocess import TRAINED_STREAM, DepthSpec, crop_resize, normalise
from trainer.sim.env import EnvConfig
from trainer.student import checkpoint
from trainer.student.dagger import RoundSpec, collect_round
from trainer.student.perception import RAY_SCALE, STEM_WEIGHT, add_ray_inputs, check_ray_spec, metric_rays

TINY = ["--width", "8", "--head-dims", "16", "32", "--state-features", "16", "--step-features", "16"]


def test_rays_are_each_pixels_camera_frame_position_at_its_depth():
    """X, Y of the policy pixel equal its depth times the ray through the stream pixel ``crop_resize`` takes
    for it (to half a stream pixel: the rays are the resize's continuous centres); no depth gives 0."""
    spec = DepthSpec(out_height=144, out_width=192)
    rows, cols = np.indices((spec.stream_height, spec.stream_width), dtype=np.uint16)
    taken_row, taken_col = (crop_resize(a, spec).astype(np.float64) for a in (rows, cols))
    metres = np.random.default_rng(0).uniform(0.5, 1.2, (spec.out_height, spec.out_width))
    depth = normalise(np.rint(metres * 1000).astype(np.uint16), 0.001, spec)
    depth[:5, :7] = spec.invalid_value
    stack = torch.from_numpy(np.stack([np.zeros_like(depth), depth]))[None]  # only the newest frame counts
    got = metric_rays(stack, spec)[0].double().numpy() / RAY_SCALE
    z = spec.near_m + np.clip(depth, 0, None) * (spec.far_m - spec.near_m)
    x = z * (taken_col - TRAINED_STREAM.cx) / TRAINED_STREAM.fx
    y = z * (taken_row - TRAINED_STREAM.cy) / TRAINED_STREAM.fy
    valid = depth >= 0
    pixel = z / TRAINED_STREAM.fx  # a stream pixel, in metres, at the depth
    assert np.all(np.abs(got[0] - x)[valid] <= 0.5 * pixel[valid] + 1e-6)
    assert np.all(np.abs(got[1] - y)[valid] <= 0.5 * pixel[valid] + 1e-6)
    assert np.abs(got[0] - x)[valid].max() > 1e-4  # the bound above is not met trivially by a zero answer
    assert np.all(got[:, ~valid] == 0) and np.ptp(got[0][valid]) > 0.5


def test_rays_are_refused_for_another_crop_in_one_line():
    check_ray_spec(DepthSpec(out_height=144, out_width=192))  # another resolution is fine
    with pytest.raises(ValueError, match="crop_width differ"):
        check_ray_spec(DepthSpec(crop_width=380))


def test_rays_at_zero_weight_read_as_before_and_a_weight_makes_them_count(tmp_path):
    from trainer.student.cli import main as student_main

    assert student_main(["init", "--out", str(tmp_path / "eye.pt"), "--perception", "depth", *TINY]) == 0
    eye = checkpoint.load(tmp_path / "eye.pt")
    weights = dict(eye.ema)
    add_ray_inputs(weights, "perception.")
    rayed = dataclasses.replace(eye, config=dataclasses.replace(eye.config, rays=True), ema=weights)
    gen = torch.Generator().manual_seed(1)
    depth, state = torch.rand(2, 3, 96, 128, generator=gen), torch.randn(2, 8, generator=gen) * 0.3
    with torch.no_grad():
        before, after = eye.policy().perceive(depth, state), rayed.policy().perceive(depth, state)
        for a, b in zip(before, after, strict=True):
            torch.testing.assert_close(a, b, rtol=0, atol=0)
        weights["perception." + STEM_WEIGHT][:, -2:] = 0.1
        moved = rayed.policy().perceive(depth, state)[1]
    assert (moved - before[1]).abs().max() > 1e-4


def test_a_refit_with_rays_starts_from_the_init_and_exports_with_parity(tmp_path):
    from export.__main__ import main as export_main
    from export.check import run_check
    from trainer.student.cli import main as student_main

    eye = tmp_path / "eye.pt"
    assert student_main(["init", "--out", str(eye), "--perception", "depth", *TINY]) == 0
    init = checkpoint.load(eye)
    store = tmp_path / "frames.zarr"
    collect_round(store, EnvConfig(objects=("cube",), max_steps=6, depth=init.info.depth_spec),
                  RoundSpec(horizon=0), episodes=1, seed=3)
    assert student_main(["refit", "--init", str(eye), "--stores", str(store), "--steps", "2", "--batch", "2",
                         "--perception-only", "--rays", "--out", str(tmp_path / "fit")]) == 0
    done = checkpoint.load(tmp_path / "fit" / "ckpt.pt")
    assert done.config == dataclasses.replace(init.config, rays=True)
    stem = done.ema["perception." + STEM_WEIGHT]
    assert stem.shape[1] == init.config.obs_horizon + 2 and stem[:, -2:].abs().max() > 0  # taught to read them
    assert export_main([str(tmp_path / "fit" / "ckpt.pt"), "--ddim-steps", "4", "--out",
                        str(tmp_path / "r.onnx")]) == 0
    assert run_check(tmp_path / "r.onnx", repeats=1, trials=2, threads=1)["max_abs_err"] <= 1e-5
