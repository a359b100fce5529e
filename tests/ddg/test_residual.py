"""The residual depth diffusion (Stable-Sim2Real): its target and decoding, point patches, stage II's loss
weights, sampling, the commands and their errors. Tiny models and a 4-episode randnoise store keep each fast;
every command runs with --threads 1 (torch's setting is process-wide: later tests inherit it)."""

import json
from dataclasses import replace

import numpy as np
import pytest
import torch

from runtime.preprocess import DepthSpec
from tests.conftest import write_synthetic_demos
from trainer.ddg.cli import main
from trainer.ddg.graft import graft_edges
from trainer.ddg.model import UNetConfig, build_unet, ddim_scheduler, ddpm_scheduler
from trainer.ddg.pairs import load_pairs
from trainer.ddg.point_patches import POINT_SCALE, PatchError, point_patches, tile
from trainer.ddg.residual import (
    ResidualCode,
    ResidualGenerator,
    decode,
    encode,
    stage_condition,
    stage_io,
)
from trainer.ddg.residual_fit import StageConfig, loss_weights
from trainer.ddg.sample import ddim_reverse, frame_noise
from trainer.ddg.train import train_step, weighted_mse
from trainer.diffusion import training_target

from .conftest import scene

LINEAR = ResidualCode(0.5)
TINY = ["--channels", "8", "8", "16", "--batch", "2", "--patch", "32", "32", "--threads", "1"]


@pytest.fixture(scope="module")
def paired(tmp_path_factory):
    """4 episodes of 4 steps, clean depth beside randnoise's frames (the stereo sensor's stand-in: same
    layout, 10x faster); with --holdout-every 2, episodes 1 and 3 are held out."""
    from trainer.sim.env import EnvConfig
    from trainer.student.dagger import RoundSpec, collect_round

    path = tmp_path_factory.mktemp("paired") / "pairs.zarr"
    collect_round(path, EnvConfig(objects=("cube",), max_steps=4), RoundSpec(horizon=0, sensor="randnoise"),
                  episodes=4, seed=3)
    return path


@pytest.fixture(scope="module")
def model(paired, tmp_path_factory):
    """A residual model with an (almost untrained) stage I."""
    root = tmp_path_factory.mktemp("residual")
    assert main(["residual-fit", "--store", str(paired), "--holdout-every", "2", "--out", str(root / "model"),
                 "--run", str(root / "run"), "--steps", "1", *TINY]) == 0
    return root / "model"


def test_a_zero_residual_returns_the_simulated_frame_and_the_hole_channel_its_holes(model):
    sim = np.stack([scene(np.random.default_rng(i)) for i in range(2)])
    sim[:, :3] = 0  # the simulator sees nothing there: nothing to add a residual to
    x0 = np.zeros((2, 2, 96, 128), np.float32)
    x0[:, 1] = -1.0
    assert np.array_equal(decode(sim, x0, LINEAR), sim)
    x0[:, 1, 40:50, 60:70] = 0.2
    out = decode(sim, x0, LINEAR)
    assert (out[:, 40:50, 60:70] == 0).all() and (out[:, 41:50, 70:] == sim[:, 41:50, 70:]).all()
    # the same through the generator, its net replaced by one that knows x0 (DDIM then lands on it)
    gen = ResidualGenerator(model, steps=4)
    abar = gen.stages[0].scheduler.alphas_cumprod.numpy()

    def perfect(x, t):
        a = abar[t]
        eps = (x[:, :2] - np.sqrt(a) * x0) / np.sqrt(1 - a)
        return (np.sqrt(a) * eps - np.sqrt(1 - a) * x0).astype(np.float32)  # v-prediction

    gen.stages[0].eps = perfect
    np.testing.assert_array_equal(gen(sim, np.arange(2)), out)


def test_a_stage_configs_hole_threshold_decides_its_holes_and_names_the_model(model, tmp_path):
    """A lower threshold turns the hole channel's blurred pixels into holes, and a store can tell the
    calibrated model from the plain one."""
    import shutil

    from trainer.ddg.residual import residual_model_id

    calibrated = tmp_path / "calibrated"
    shutil.copytree(model, calibrated)
    cfg_file = calibrated / "stage1" / "config.json"
    cfg_file.write_text(json.dumps({**json.loads(cfg_file.read_text()), "hole_threshold": -0.5}))
    sim = scene(np.random.default_rng(0))[None]
    x0 = np.zeros((1, 2, 96, 128), np.float32)
    x0[:, 1] = -1.0
    x0[:, 1, 40:50, 60:70] = -0.3  # more "hole" than "valid", not past half way
    assert (decode(sim, x0, LINEAR) == sim).all()
    assert (decode(sim, x0, LINEAR, holes=-0.5)[:, 40:50, 60:70] == 0).all()
    assert ResidualGenerator(calibrated).stages[0].holes == -0.5
    assert ResidualGenerator(model).stages[0].holes == 0.0
    assert residual_model_id(calibrated).endswith("~holes-0.5")
    assert "~holes" not in residual_model_id(model)


def test_an_edge_threshold_makes_holes_in_the_edge_band_only(model, tmp_path):
    """With ``hole_threshold_edges`` a blurred hole channel becomes holes within the simulated frame's edge
    band and stays depth on flat regions, and the model's id names both thresholds."""
    import shutil

    from trainer.ddg.graft import edge_bands
    from trainer.ddg.residual import residual_model_id

    calibrated = tmp_path / "edges"
    shutil.copytree(model, calibrated)
    cfg_file = calibrated / "stage1" / "config.json"
    cfg_file.write_text(json.dumps({**json.loads(cfg_file.read_text()), "hole_threshold_edges": -0.5}))
    stage = ResidualGenerator(calibrated).stages[0]
    sim = scene(np.random.default_rng(0))[None]
    band = edge_bands(sim)[0]
    assert band.any() and (~band).any()
    x0 = np.zeros((1, 2, 96, 128), np.float32)
    x0[:, 1] = -0.3  # blurred everywhere: a hole under -0.5, depth under 0
    out = decode(sim, x0, LINEAR, stage.thresholds(band[None]))[0]
    assert (out[band] == 0).all() and (out[~band] == sim[0][~band]).all()
    assert residual_model_id(calibrated).endswith("~edges-0.5")
    # through the sampler, same noise: off the band the same frame, in it the plain model's holes and more
    plain, edged = (ResidualGenerator(m, steps=2)(sim, np.array([0]))[0] for m in (model, calibrated))
    assert (edged[~band] == plain[~band]).all()
    assert (edged[band][plain[band] == 0] == 0).all()


def test_encode_then_decode_gives_back_the_sensor_frame():
    rng = np.random.default_rng(0)
    sim = scene(rng)[None]
    sensor = (sim.astype(int) + rng.integers(-300, 300, sim.shape)).astype(np.uint16)
    sensor[:, 10:20, 30:60] = 0
    for code in (LINEAR, ResidualCode(0.5, 255.0)):
        x0 = encode(sim, sensor, code)
        assert x0.shape == (1, 2, 96, 128) and x0.min() >= -1 and x0.max() <= 1
        assert np.array_equal(decode(sim, x0, code), sensor)
        far = sim + 700  # beyond the residual's range: clipped to it
        assert np.array_equal(decode(sim, encode(sim, far, code), code), sim + 500)
    # companding spreads the small errors: 4 mm is a fifth of the unit range, not 0.008 of it
    small = encode(sim, sim + 4, ResidualCode(0.5, 255.0))[0, 0]
    assert np.allclose(small[sim[0] > 0], 0.2005, atol=1e-3)


def test_point_patches_invert_to_the_depth_patch(paired):
    """Back through K: each valid point lands on its own pixel of its own patch at its own depth."""
    pairs = load_pairs((str(paired),), holdout_every=0)
    depth, K, p = pairs.real[:3], pairs.K[:3], 16
    assert depth.min() == 0 and K[0, 0, 2] != K[0, 1, 2]  # holes, and a principal point off the diagonal
    assert np.array_equal(tile(depth, p)[:, 9], depth[:, 16:32, 16:32].reshape(3, -1))  # row 1, column 1
    pts, centre = point_patches(depth, K, p)
    xyz = pts[..., :3] / POINT_SCALE + centre[:, :, None]
    valid = pts[..., 3] == 1
    assert np.array_equal(valid, tile(depth > 0, p)) and np.all(pts[~valid][:, :3] == 0)
    rows, cols = np.mgrid[0:96, 0:128].astype(np.float64)
    z = np.where(valid, xyz[..., 2], 1.0)
    fx, fy, cx, cy = (K[:, i, j][:, None, None] for i, j in ((0, 0), (1, 1), (0, 2), (1, 2)))
    u, v = fx * xyz[..., 0] / z + cx, fy * xyz[..., 1] / z + cy
    pixel = tile(np.broadcast_to(np.stack([cols, rows], -1), (3, 96, 128, 2)).copy(), p)
    assert np.abs(u - pixel[..., 0])[valid].max() < 1e-3 and np.abs(v - pixel[..., 1])[valid].max() < 1e-3
    assert np.abs(xyz[..., 2] * 1000 - tile(depth, p))[valid].max() < 1e-3
    with pytest.raises(PatchError, match="patch size 24 does not tile the 128x96 frames"):
        point_patches(depth, K, 24)


def test_stage_two_loss_weights_follow_the_discriminator_mask():
    """Eq. 6: lambda on the pixels of the patches the discriminator caught, omega on the rest."""
    hit = np.zeros((2, 48), bool)  # 6 x 8 patches of 16 px
    hit[0, 9] = True  # row 1, column 1
    w = loss_weights(hit, (96, 128), 16, omega=0.5, lam=1.5)
    assert w.shape == (2, 1, 96, 128) and w.dtype == np.float32
    assert (w[0, 0, 16:32, 16:32] == 1.5).all() and (w == 1.5).sum() == 256 and (w[1] == 0.5).all()
    pred, target = torch.randn(2, 2, 96, 128), torch.randn(2, 2, 96, 128)
    e2 = (pred - target) ** 2
    caught_px = torch.from_numpy(w == 1.5).expand_as(e2)
    eq6 = (0.5 * e2[~caught_px].sum() + 1.5 * e2[caught_px].sum()) / e2.numel()
    torch.testing.assert_close(weighted_mse(pred, target, torch.from_numpy(w)), eq6)
    assert weighted_mse(pred, target) == torch.nn.functional.mse_loss(pred, target)
    # train_step takes them: zero weights leave nothing to learn
    ucfg = UNetConfig(channels=(8, 8, 16))
    unet = build_unet(ucfg, DepthSpec(), stage_io(2))
    x0, c = torch.zeros(2, 2, 96, 128), torch.zeros(2, 5 - 2, 96, 128)
    opt = torch.optim.AdamW(unet.parameters())
    cfg = StageConfig(batch=2, patch=(32, 32))
    assert train_step(unet, opt, ddpm_scheduler(ucfg), x0, c, cfg, 0, torch.zeros(2, 1, 96, 128)) == 0.0


def test_the_sampler_is_deterministic_under_a_seed(model):
    sim = np.stack([scene(np.random.default_rng(i)) for i in range(3)])
    a, b = (ResidualGenerator(model, steps=2, seed=7)(sim, np.arange(3)) for _ in range(2))
    c = ResidualGenerator(model, steps=2, seed=8)(sim, np.arange(3))
    alone = ResidualGenerator(model, steps=2, seed=7)(sim[1:2], np.array([1]))
    assert np.array_equal(a, b) and not np.array_equal(a, c) and np.array_equal(a[1], alone[0])


def test_bad_inputs_are_one_line_errors(tmp_path, paired, model, capsys, tiny_model):
    no_sensor = write_synthetic_demos(tmp_path / "clean.zarr", episodes=1, steps=2)
    fit = ["residual-fit", "--store", str(paired), "--out", str(tmp_path / "m"), "--run", str(tmp_path / "r")]
    disc = ["residual-disc", "--store", str(paired), "--model", str(model), "--run", str(tmp_path / "d"),
            "--holdout-every", "2"]
    cases = [(["residual-fit", "--store", str(tmp_path / "none.zarr")], "no demo store at"),
             (["residual-fit", "--store", str(no_sensor)], "no data/depth_sensor, so no paired frames"),
             (["residual-fit"], "no store given"),
             ([*fit, "--stage", "3"], "--stage must be 1 or 2"),
             ([*fit, "--stage", "2"], "no stage1/ (not a residual model directory"),
             ([*fit, "--omega", "-1"], "--omega and --lam must be >= 0"),
             ([*fit, "--holdout-every", "1"], "no train episodes"),
             ([*disc, "--patch", "24"], "patch size 24 does not tile the 128x96 frames"),
             (["residual-disc", "--store", str(paired), "--model", str(tiny_model), "--holdout-every", "2",
               "--run", str(tmp_path / "d")], "no stage1/"),
             (["residual-fit", "--store", str(paired), "--stage", "2", "--out", str(model), "--run",
               str(tmp_path / "r2")], "no discriminator/")]
    for argv, message in cases:
        assert main([*argv, "--threads", "1"]) == 2, argv
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("error: ") and message in err[0], (argv, err)
    from trainer.ddg.model import ModelDirError

    (tmp_path / "x" / "stage1").mkdir(parents=True)
    for f in tiny_model.iterdir():
        (tmp_path / "x" / "stage1" / f.name).write_bytes(f.read_bytes())
    with pytest.raises(ModelDirError, match="a DDG model, not a residual depth diffusion one"):
        ResidualGenerator(tmp_path / "x", steps=1)
    with pytest.raises(ValueError, match=r"\[N, 96, 128\] \(the model's resolution\)"):
        ResidualGenerator(model, steps=1)(np.zeros((1, 48, 64), np.uint16), np.arange(1))
    finer = replace(ResidualGenerator(model, steps=1).spec, out_height=144, out_width=192)
    with pytest.raises(ValueError, match="96x128 depth; frames at 144x192 need a residual model of their"):
        ResidualGenerator(model, steps=1, frames=finer)


def test_a_tiny_stage_one_overfits_a_constant_residual():
    """Each sensor frame is its simulated one 40 mm farther, with no depth on the frame's box, which stands at
    another place in each (so only the condition can say where the holes go): after 150 steps the loss has
    dropped, the sampled residual is ~40 mm and the holes are on the boxes."""
    torch.manual_seed(0)
    rng = np.random.default_rng(0)
    sim = np.full((8, 32, 32), 1000, np.uint16)
    for frame, (r, c) in zip(sim, rng.integers(0, 22, (8, 2)), strict=True):
        frame[r:r + 10, c:c + 10] = 900
    sensor = sim + 40
    sensor[sim < 950] = 0
    x0, c = encode(sim, sensor, ResidualCode(0.1)), stage_condition(sim, DepthSpec(), ResidualCode(0.1))
    ucfg = UNetConfig(channels=(8, 8, 16))
    unet, sched = build_unet(ucfg, DepthSpec(), stage_io(1)), ddpm_scheduler(ucfg)
    opt = torch.optim.AdamW(unet.parameters(), lr=3e-3)

    def loss() -> float:
        g = torch.Generator().manual_seed(123)
        eps, k = torch.randn(x0.shape, generator=g), torch.linspace(50, 900, len(x0)).long()
        xk = sched.add_noise(torch.from_numpy(x0), eps, k)
        with torch.no_grad():
            pred = unet(torch.cat([xk, torch.from_numpy(c)], 1), k).sample
        return float(torch.nn.functional.mse_loss(pred, training_target(sched, torch.from_numpy(x0), eps, k)))

    before = loss()
    cfg = StageConfig(batch=4, patch=(0, 0))
    for step in range(150):
        train_step(unet, opt, sched, torch.from_numpy(x0), torch.from_numpy(c), cfg, step)
    assert loss() < 0.3 * before

    def eps_fn(x, t):
        with torch.no_grad():
            return unet(torch.from_numpy(x), torch.full((len(x),), t)).sample.numpy()

    x = ddim_reverse(eps_fn, c, frame_noise(0, np.arange(8), (32, 32), channels=2), ddim_scheduler(ucfg, 5))
    out = decode(sim, x, ResidualCode(0.1))
    both = (out > 0) & (sensor > 0)
    assert abs(np.median(out[both].astype(int) - sim[both]) - 40) <= 8
    assert ((out == 0) == (sensor == 0)).mean() > 0.93  # ~0.97; ~0.81 with the condition zeroed


def test_both_stages_fit_resume_and_serve_as_a_sensor(paired, tmp_path, capsys, monkeypatch):
    """Stage I, the discriminator, stage II, the discriminator's report again (now with stage II's share) and
    the `residual` depth source, on a tiny budget; a fit resumes where its checkpoint stopped."""
    import trainer.ddg.train as loop
    from trainer.sim.sensors import make_sensor

    out, run = tmp_path / "model", tmp_path / "run"
    fit = ["residual-fit", "--store", str(paired), "--holdout-every", "2", "--out", str(out), "--run",
           str(run), *TINY]
    assert main([*fit, "--steps", "2", "--ckpt-every", "1"]) == 0
    first = torch.load(run / "stage1" / "ckpt.pt", weights_only=True)
    steps, step = [], loop.train_step
    monkeypatch.setattr(loop, "train_step", lambda *a: steps.append(a[6]) or step(*a))
    assert main([*fit, "--steps", "3"]) == 0
    again = torch.load(run / "stage1" / "ckpt.pt", weights_only=True)
    assert first["step"] == 2 and again["step"] == 3 and again["losses"][:2] == first["losses"]
    assert steps == [2]  # resumed: only the step after the checkpoint
    disc = ["residual-disc", "--store", str(paired), "--holdout-every", "2", "--model", str(out), "--run",
            str(tmp_path / "disc"), "--steps", "2", "--batch", "2", "--ddim-steps", "2", "--width", "16",
            "--threads", "1", "--json", str(tmp_path / "disc.json")]
    assert main(disc) == 0
    assert main([*fit, "--stage", "2", "--steps", "2", "--ddim-steps", "2", "--lam", "3"]) == 0
    stage2 = json.loads((out / "stage2" / "config.json").read_text())
    assert stage2["io"] == [5, 2] and stage2["train"]["lam"] == 3 and 0 <= stage2["caught_share"] <= 1
    capsys.readouterr()
    assert main(disc) == 0
    printed = capsys.readouterr().out
    row = json.loads((tmp_path / "disc.json").read_text())["rows"][0]
    assert {"accuracy", "caught_stage1", "caught_stage2"} <= set(row) and "caught stage2 %" in printed
    sensor = make_sensor(f"residual:model={out},steps=2")
    sensor.reseed(4)
    clean = np.asarray(load_pairs((str(paired),), holdout_every=0).sim[0])
    frame = sensor(clean)
    sensor.reseed(4)
    assert frame.dtype == np.uint16 and frame.shape == clean.shape and np.array_equal(sensor(clean), frame)


def test_pairs_hold_out_every_kth_episode_and_stride(paired):
    train, held = (load_pairs((str(paired),), part, holdout_every=2) for part in ("train", "heldout"))
    every = load_pairs((str(paired),), holdout_every=0)
    assert len(train) == len(held) == 8 and len(every) == 16
    assert np.array_equal(train.sim, np.concatenate([every.sim[0:4], every.sim[8:12]]))
    assert np.array_equal(load_pairs((str(paired),), holdout_every=0, stride=2).real, every.real[::2])
    assert train.spec == DepthSpec()


@pytest.mark.parametrize("source", ["residual", "residual_edges"])
def test_residual_depth_generated_into_a_store_is_the_generators_in_any_shards_and_fits_read_it(
        paired, model, tmp_path, source):
    """`ddg generate --generator residual|residual_edges`: shard by shard into data/depth_<source>, each
    frame the generator's own under its index (edge-grafted for residual_edges); unfinished chunks are
    refused, and a fit (or a readout) then reads exactly those."""
    import shutil

    from trainer.dataset import DatasetError, DemoStore
    from trainer.student.steps import LabelledSteps

    store = tmp_path / "pairs.zarr"
    shutil.copytree(paired, store)
    run = ["generate", "--generator", source, "--demos", str(store), "--model", str(model),
           "--steps", "2", "--chunk", "4", "--batch", "3", "--threads", "1"]
    assert main([*run, "--shard", "1/2"]) == 0
    demos = DemoStore.open(store)
    with pytest.raises(DatasetError, match=rf"{source} depth of 2 of the 4 chunks .* \(first: chunk 0\)"):
        LabelledSteps([store], 1, 1, depth=True, chunks=False, depth_source=source)
    assert main([*run, "--shard", "0/2"]) == 0
    sim = demos.depth("gt", demos.n_steps)
    made = ResidualGenerator(model, steps=2, threads=1)(sim, np.arange(len(sim)))
    want = graft_edges(sim, made) if source == "residual_edges" else made
    np.testing.assert_array_equal(demos.depth(source, demos.n_steps), want)
    steps = LabelledSteps([store], 1, 1, depth=True, chunks=False, depth_source=source)
    np.testing.assert_array_equal(steps.frames.numpy().view(np.uint16), want)
    assert demos.generated_with("ddg") is None and demos.generated_with(source)["steps"] == 2


def test_vs_sensor_sets_each_source_beside_the_sensors_frames(paired, model, tiny_model, tmp_path, capsys):
    """`ddg vs-sensor` on a paired store: every source (the residual model's stage I among them) judged
    against the sensor's frames; the sensor itself shares all its holes, the clean frames none and are never
    off; the grid is drawn."""
    out = tmp_path / "vs.json"
    assert main(["vs-sensor", "--store", str(paired), "--ddg", str(tiny_model), "--residual", str(model),
                 "--steps", "1", "--every", "1", "--bootstrap", "2", "--threads", "1",
                 "--json", str(out)]) == 0
    rows = json.loads(out.read_text())["sources"]
    assert list(rows) == ["sensor", "gt", "randnoise", f"{tiny_model.name} grafted",
                          f"{tiny_model.name} ungrafted", f"{model.name} stage I",
                          f"{model.name} edge-grafted"]
    made, edges = rows[f"{model.name} stage I"], rows[f"{model.name} edge-grafted"]
    assert made["flat_off_20mm_pct"] > 0 and edges["flat_off_20mm_pct"] == 0.0  # flat: the simulator's depth
    assert edges["edge_off_20mm_pct"] == made["edge_off_20mm_pct"]  # near edges: the generator's
    assert rows["sensor"]["sensor_holes_shared_pct"] == 100.0
    assert rows["gt"]["sensor_holes_shared_pct"] == 0.0 and rows["gt"]["flat_off_20mm_pct"] == 0.0
    assert rows["sensor"]["flat_holes_pct"] > 0 and len(rows["gt"]["fid_ci95"]) == 2
    assert out.with_suffix(".png").is_file() and "| gt |" in capsys.readouterr().out
    assert main(["vs-sensor", "--store", str(tmp_path / "nope.zarr")]) == 2


def test_bench_times_the_residual_generator_in_each_setting(paired, model, tmp_path):
    out = tmp_path / "bench.json"
    assert main(["bench", "--generator", "residual", "--model", str(model), "--demos", str(paired),
                 "--steps", "1", "2", "--batches", "2", "--modes", "split", "--frames", "4", "--rounds", "2",
                 "--threads", "1", "--json", str(out)]) == 0
    rows = json.loads(out.read_text())["rows"]
    # (steps, batch, calls): 2 calls of 2 frames per round, the warm-up round not counted
    assert [(r["steps"], r["batch"], r["calls"]) for r in rows] == [(1, 2, 2), (2, 2, 2)]
    assert all(r["fps"] > 0 for r in rows)
    assert main(["bench", "--generator", "gan"]) == 2


def test_the_shipped_model_has_both_stages_and_its_discriminator_and_generates_policy_frames():
    from trainer.ddg.baselines import DEFAULT_RESIDUAL
    from trainer.ddg.discriminator import load_discriminator

    gen = ResidualGenerator(DEFAULT_RESIDUAL, steps=2, threads=1)
    assert len(gen.stages) == 2 and (gen.spec.out_height, gen.spec.out_width) == (144, 192)
    assert load_discriminator(DEFAULT_RESIDUAL)[1] == 16  # the patch stage II's loss was weighted by
    sim = scene(np.random.default_rng(0), 144, 192)[None]
    out = gen(sim, np.arange(1))
    assert out.shape == sim.shape and out.dtype == np.uint16 and not out[sim == 0].any()
    np.testing.assert_array_equal(gen(sim, np.arange(1)), out)
