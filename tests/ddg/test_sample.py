import json
import shutil
from dataclasses import replace

import numpy as np
import pytest

from runtime.preprocess import DepthSpec, resample
from trainer.ddg.model import ModelDirError, UNetConfig, ddim_scheduler, load_config
from trainer.ddg.sample import (
    SESSION_MODES,
    FrameError,
    Generator,
    OnnxEps,
    TorchEps,
    ddim_sample,
    frame_noise,
)

from .conftest import scene


@pytest.fixture(scope="module")
def sims():
    rng = np.random.default_rng(5)
    return np.stack([scene(rng) for _ in range(3)])


def test_sampler_is_deterministic_under_a_seed(tiny_model, sims):
    idx = np.arange(3)
    a = Generator(tiny_model, steps=3, seed=7)(sims, idx)
    b = Generator(tiny_model, steps=3, seed=7)(sims, idx)
    c = Generator(tiny_model, steps=3, seed=8)(sims, idx)
    assert all(np.array_equal(x, y) for x, y in zip(a, b, strict=True))
    assert not np.array_equal(a[1], c[1])


def test_output_of_a_frame_does_not_depend_on_its_batch(tiny_model, sims):
    gen = Generator(tiny_model, steps=2, seed=0)
    _, together = gen(sims, np.array([10, 11, 12]))
    _, alone = gen(sims[1:2], np.array([11]))
    assert np.array_equal(together[1], alone[0])


def test_onnx_unet_matches_torch(tiny_model, sims):
    x = np.random.default_rng(0).standard_normal((2, 2, 96, 128)).astype(np.float32)
    diff = np.abs(OnnxEps(tiny_model)(x, 500) - TorchEps(tiny_model)(x, 500)).max()
    assert diff < 1e-4


def test_onnx_and_torch_samplers_agree(tiny_model, sims):
    cfg = load_config(tiny_model)
    c = np.zeros((1, 96, 128), np.float32)
    noise = frame_noise(0, np.array([0]), (96, 128))
    a = ddim_sample(OnnxEps(tiny_model), c, noise, ddim_scheduler(cfg["unet"], 4))
    b = ddim_sample(TorchEps(tiny_model), c, noise, ddim_scheduler(cfg["unet"], 4))
    assert np.abs(a - b).max() < 1e-3


@pytest.mark.parametrize("prediction", ["epsilon", "v_prediction"])
def test_ddim_with_a_perfect_predictor_recovers_x0(prediction):
    """A net that knows x0 returns the exact noise (or v) of x_t; DDIM must then land on x0 in any step
    count."""
    sched = ddim_scheduler(UNetConfig(prediction=prediction), 5)
    x0 = np.random.default_rng(1).uniform(-1, 1, (1, 1, 8, 8)).astype(np.float32)
    abar = sched.alphas_cumprod.numpy()

    def eps_fn(x, t):
        a = abar[t]
        eps = (x[:, :1] - np.sqrt(a) * x0) / np.sqrt(1 - a)
        return (eps if prediction == "epsilon" else np.sqrt(a) * eps - np.sqrt(1 - a) * x0).astype(np.float32)

    noise = np.random.default_rng(2).standard_normal(x0.shape).astype(np.float32)
    out = ddim_sample(eps_fn, np.zeros((1, 8, 8), np.float32), noise, sched)
    assert np.abs(out - x0[:, 0]).max() < 1e-3


def test_a_model_from_the_old_metric_eps_trainer_is_refused(tmp_path, tiny_model):
    old = tmp_path / "old"
    shutil.copytree(tiny_model, old)
    cfg = json.loads((old / "config.json").read_text())
    del cfg["x0_scale"], cfg["unet"]["prediction"]
    (old / "config.json").write_text(json.dumps(cfg))
    with pytest.raises(ModelDirError, match="older trainer .*metric, prediction eps"):
        load_config(old)


def test_bad_step_count_and_missing_model(tmp_path):
    with pytest.raises(ValueError, match="DDIM steps"):
        ddim_scheduler(UNetConfig(), 0)
    with pytest.raises(ModelDirError, match="no config.json"):
        load_config(tmp_path)


def test_generator_refuses_frames_it_cannot_take(tiny_model, sims):
    gen = Generator(tiny_model, steps=1)
    for bad in (sims[:, :80], sims.astype(np.float32), sims[0]):
        with pytest.raises(FrameError, match="model's resolution"):
            gen(bad, np.arange(len(bad)))


def test_frames_at_a_finer_resolution_get_the_models_holes_carried_back(tiny_model, sims):
    """A 192x144 student's demos: the generator runs on their 128x96 nearest-neighbour copy, its holes come
    back nearest-neighbour, and every other pixel keeps the finer frame's own depth."""
    fine_spec = replace(DepthSpec(), out_height=144, out_width=192)
    fine = resample(sims, 144, 192)
    fine[:, 60:63, 90:93] += 7  # detail the 128x96 copy does not see: it must survive where no hole is
    idx = np.arange(3)
    grafted, pred = Generator(tiny_model, steps=2, frames=fine_spec)(fine, idx)
    _, coarse = Generator(tiny_model, steps=2)(resample(fine, 96, 128), idx)
    assert grafted.shape == pred.shape == fine.shape
    np.testing.assert_array_equal(pred, resample(coarse, 144, 192))
    holes = grafted == 0
    assert 0 < holes.mean() < 1 and np.array_equal(grafted[~holes], fine[~holes])
    with pytest.raises(FrameError, match=r"\[N, 144, 192\] \(the frames' spec resolution\)"):
        Generator(tiny_model, steps=1, frames=fine_spec)(sims, idx)


def test_frames_of_another_crop_are_refused(tiny_model):
    with pytest.raises(FrameError, match="another crop, range or stream"):
        Generator(tiny_model, steps=1, frames=replace(DepthSpec(), crop_width=380, out_width=192))


@pytest.mark.parametrize("mode", SESSION_MODES)
def test_session_modes_give_the_same_noise_prediction(tiny_model, mode):
    x = np.random.default_rng(0).standard_normal((5, 2, 96, 128)).astype(np.float32)
    ref = OnnxEps(tiny_model, threads=1, mode="intra")(x, 300)
    assert np.abs(OnnxEps(tiny_model, threads=2, mode=mode)(x, 300) - ref).max() < 1e-5
    with pytest.raises(ValueError, match="session mode"):
        OnnxEps(tiny_model, mode="turbo")


def test_stochastic_sampling_is_seeded_per_frame(tiny_model, sims):
    """eta > 0 draws fresh noise each step; it must still come from the frame's own (seed, index)."""
    _, together = Generator(tiny_model, steps=3, seed=0, eta=1.0)(sims, np.array([10, 11, 12]))
    _, alone = Generator(tiny_model, steps=3, seed=0, eta=1.0)(sims[1:2], np.array([11]))
    _, ddim = Generator(tiny_model, steps=3, seed=0)(sims, np.array([10, 11, 12]))
    assert np.array_equal(together[1], alone[0])
    assert not np.array_equal(together, ddim)
