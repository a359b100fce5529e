"""The student recipe: labels match the simulator at their frame, a DAgger round records the learner's own
states with the expert's labels, training stacks equal the runtime's, the perception student exports with
parity, and the recipe resumes without redoing finished stages."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

from hil_sim.objects import GROUPS
from runtime.preprocess import FrameStack, normalise
from trainer.dataset import DatasetError, DemoStore
from trainer.sim.env import OBJECT_FROM_HAND, EnvConfig, GraspEnv
from trainer.sim.labels import GRASP_YAW, HAND_PX, OBJECT_PX, OFFSET, SIZE, frame_labels
from trainer.student import checkpoint
from trainer.student.dagger import GLIMPSE_TOP_M, RoundSpec, chunks_ahead, collect_round
from trainer.teacher.scripted import ReactiveExpert

TINY = ["--width", "8", "--head-dims", "16", "32", "--state-features", "16", "--step-features", "16"]


@pytest.fixture(scope="module")
def env():
    e = GraspEnv(EnvConfig(objects=("banana", "apple"), max_steps=40))
    yield e
    e.close()


def _pixel(frame: np.ndarray, xy: np.ndarray) -> tuple[int, int]:
    h, w = frame.shape
    return int(round((xy[1] + 1) * (h - 1) / 2)), int(round((xy[0] + 1) * (w - 1) / 2))


@pytest.mark.parametrize("kind", ["banana", "apple"])
def test_labels_match_the_simulator_at_their_frame(env, kind):
    obs, info = env.reset(seed=7, options={"kind": kind})
    expert = ReactiveExpert()
    expert.reset(info)
    for _ in range(12):  # the hand on its way down, in view
        obs, _, _, _, info = env.step(expert.act(obs))
    row = frame_labels(env)
    np.testing.assert_allclose(row[OFFSET], obs[OBJECT_FROM_HAND], atol=1e-6)
    extent = env.world.object_extent()
    np.testing.assert_allclose(row[SIZE], [min(extent[:2]), max(extent[:2]), extent[2]], atol=1e-6)
    yaw_norm = np.linalg.norm(row[GRASP_YAW])
    assert yaw_norm == pytest.approx(1.0 if kind == "banana" else 0.0, abs=1e-5)
    # the labelled pixels show the object and the hand: nearer the camera than the table around them
    depth = env.frame()
    table = np.median(depth[depth > 0])
    for pixel in (row[OBJECT_PX], row[HAND_PX]):
        assert np.all(np.abs(pixel) <= 1)
        assert 0 < depth[_pixel(depth, pixel)] < table - 20


def test_lookahead_is_the_experts_own_continuation_and_leaves_the_env_as_it_was(env):
    obs, info = env.reset(seed=3, options={"kind": "banana"})
    expert = ReactiveExpert()
    expert.reset(info)
    labels, taken = [], []
    for _ in range(20):
        before = env.observation()
        labels.append(env.lookahead(expert.act, 8))
        np.testing.assert_allclose(env.observation(), before, atol=1e-4)
        taken.append(expert.act(env.observation()))
        env.step(taken[-1])
    taken = np.array(taken)
    for t in range(12):
        np.testing.assert_allclose(labels[t], taken[t:t + 8], atol=2e-3)
    np.testing.assert_array_equal(chunks_ahead(taken, 8)[-1], np.repeat(taken[-1:], 8, axis=0))


def test_a_dagger_round_records_the_learners_states_with_the_experts_labels(tmp_path):
    from trainer.student.cli import main as student_main

    ckpt = tmp_path / "oracle.pt"
    assert student_main(["init", "--out", str(ckpt), "--perception", "privileged", *TINY]) == 0
    config = EnvConfig(objects=("cube",), max_steps=25, render_depth=False)
    spec = RoundSpec(learner=f"oracle:{ckpt}", beta=0.0, horizon=6, stall_steps=100)
    tally = collect_round(tmp_path / "round1.zarr", config, spec, episodes=1, seed=5)
    store = DemoStore.open(tmp_path / "round1.zarr")
    assert tally["attempted"] == 1 and store.n_steps == 25
    ep = store.episode(0)
    # replay the learner's executed actions: the recorded states are the ones it reached, and each chunk is
    # what the expert does from there (not what the learner did)
    env, expert = GraspEnv(config), ReactiveExpert()
    try:
        _, info = env.reset(seed=5, options={"kind": "cube"})
        expert.reset(info)
        for t in range(store.n_steps):
            np.testing.assert_allclose(ep["state"][t], info["state"], atol=1e-5)
            np.testing.assert_allclose(ep["chunk"][t][0], expert.act(env.observation()), atol=1e-4)
            np.testing.assert_allclose(ep["labels"][t], frame_labels(env), atol=1e-5)
            _, _, _, _, info = env.step(ep["action"][t])
    finally:
        env.close()
    assert not np.allclose(ep["action"][:, :7], ep["chunk"][:, 0, :7], atol=0.05)  # the learner drove


def test_a_round_of_approaches_ends_each_episode_before_the_hand_is_low(tmp_path):
    """``RoundSpec.end_height_m``: the episode stops at the first frame whose grasp site is that low over the
    object, which is not stored; the frames before it are the full episode's."""
    config = EnvConfig(objects=("cube",), max_steps=60, render_depth=False)
    for name, end in (("full", 0.0), ("approach", 0.12)):
        collect_round(tmp_path / f"{name}.zarr", config, RoundSpec(horizon=0, end_height_m=end), episodes=1,
                      seed=7)
    full, approach = (DemoStore.open(tmp_path / f"{n}.zarr").episode(0)["labels"]
                      for n in ("full", "approach"))
    height = -full[:, OFFSET][:, 2]
    first_low = int(np.argmax(height < 0.12))
    assert 0 < first_low < len(full) - 1  # the expert's hand went below 12 cm within the episode
    assert len(approach) == first_low
    np.testing.assert_array_equal(approach, full[:first_low])


def test_a_glimpse_keeps_the_last_frames_before_a_drawn_height_as_the_full_run_renders_them(tmp_path):
    """``RoundSpec.glimpse``: the episode ends once the grasp site is below a height drawn between
    ``end_height_m`` and ``GLIMPSE_TOP_M``; only its last N frames are kept, rendered afterwards from physics
    snapshots, and they equal the full run's frames and labels of those steps."""
    config = EnvConfig(objects=("cube",), max_steps=60)
    collect_round(tmp_path / "full.zarr", config, RoundSpec(horizon=0), episodes=1, seed=7)
    collect_round(tmp_path / "glimpse.zarr", config, RoundSpec(horizon=0, end_height_m=0.12, glimpse=3),
                  episodes=1, seed=7)
    full, glimpse = (DemoStore.open(tmp_path / f"{n}.zarr").episode(0) for n in ("full", "glimpse"))
    assert len(glimpse["labels"]) == 3
    last = int(np.flatnonzero((full["labels"] == glimpse["labels"][-1]).all(axis=1))[0])
    for key in ("labels", "depth", "state"):
        np.testing.assert_array_equal(glimpse[key], full[key][last - 2:last + 1])
    height = -full["labels"][:, OFFSET][:, 2]
    assert height[last] >= 0.12 and height[last + 1] < GLIMPSE_TOP_M  # it stopped inside the band
    assert not (glimpse["depth"] == 0).all()  # rendered, though the run itself rendered none


def test_a_glimpse_refuses_a_driver_that_reads_depth_and_a_spec_without_its_end_height():
    with pytest.raises(ValueError, match="end height"):
        RoundSpec(horizon=0, glimpse=3)
    with pytest.raises(ValueError, match="must read no depth"):
        RoundSpec(learner="student:models/student.onnx", horizon=0, end_height_m=0.12, glimpse=3)
    RoundSpec(learner="oracle:head.pt@1.0", horizon=0, end_height_m=0.12, glimpse=3)  # a privileged driver
    RoundSpec(learner="student:models/student.onnx", horizon=0, end_height_m=0.12)  # a whole approach


def test_a_round_without_chunks_drives_the_same_states_and_labels_its_frames_alone(tmp_path):
    """``RoundSpec.horizon`` 0 skips the expert's lookahead (3/4 of an episode's time): the learner reaches
    the same states with the same labels, the store holds no chunks, and ``beta`` still hands steps to the
    expert, whose action from that state is executed."""
    from trainer.student.cli import main as student_main

    ckpt = tmp_path / "oracle.pt"
    assert student_main(["init", "--out", str(ckpt), "--perception", "privileged", *TINY]) == 0
    config = EnvConfig(objects=("cube",), max_steps=20, render_depth=False)
    learner = f"oracle:{ckpt}"
    for name, horizon in (("chunks", 6), ("frames", 0)):
        spec = RoundSpec(learner=learner, horizon=horizon, stall_steps=100)
        collect_round(tmp_path / f"{name}.zarr", config, spec, episodes=1, seed=5)
    with_chunks, alone = (DemoStore.open(tmp_path / f"{n}.zarr") for n in ("chunks", "frames"))
    assert "data/chunk" in with_chunks.root and "data/chunk" not in alone.root
    assert "chunk_horizon" not in alone.attrs
    for key in ("state", "action", "labels"):
        np.testing.assert_array_equal(alone.episode(0)[key], with_chunks.episode(0)[key])

    spec = RoundSpec(learner=learner, beta=1.0, horizon=0, stall_steps=100)
    collect_round(tmp_path / "expert.zarr", config, spec, episodes=1, seed=6)
    ep = DemoStore.open(tmp_path / "expert.zarr").episode(0)
    env, expert = GraspEnv(config), ReactiveExpert()
    try:
        _, info = env.reset(seed=6, options={"kind": "cube"})
        expert.reset(info)
        for action in ep["action"]:
            np.testing.assert_allclose(action, expert.act(env.observation()), atol=1e-6)
            env.step(action)
    finally:
        env.close()


def test_training_stacks_are_the_runtimes(tmp_path):
    from trainer.student.steps import LabelledSteps

    config = EnvConfig(objects=("cube",), max_steps=9)
    collect_round(tmp_path / "round0.zarr", config, RoundSpec(horizon=4), episodes=2, seed=11)
    store = DemoStore.open(tmp_path / "round0.zarr")
    steps = LabelledSteps([tmp_path / "round0.zarr"], obs_horizon=3, action_horizon=4, depth=True)
    assert len(steps) == store.n_steps
    for e in range(store.n_episodes):
        ep, frames = store.episode(e), FrameStack(3)
        first = store.episode_slice(e).start
        for t, depth in enumerate(ep["depth"]):
            expected = frames.push(normalise(depth, 0.001, store.depth_spec))
            batch = steps.batch(torch.tensor([first + t]))
            np.testing.assert_array_equal(batch.depth[0].numpy(), expected)
            np.testing.assert_array_equal(batch.chunk[0].numpy(), ep["chunk"][t])


def test_steps_of_several_stores_keep_their_frames_off_the_heap_and_in_order(tmp_path, monkeypatch):
    """A recipe fit reads every round's store; its frames go to a mapped file the kernel can page out, not the
    process's heap (a 192 x 144 round-5 fit holding them twice there was killed on 24 GiB; once is 17 GB by
    round 6), and each store's frames land where its steps do. Small zarr chunks keep the one chunk read at a
    time small beside the frames, as it is in a real fit."""
    import tracemalloc

    import trainer.dataset
    from trainer.student.steps import LabelledSteps, _frames, depth_arrays

    monkeypatch.setattr(trainer.dataset, "_CHUNK_STEPS", 8)
    config = EnvConfig(objects=("cube",), max_steps=20)
    paths = [tmp_path / f"round{r}.zarr" for r in range(4)]
    for r, path in enumerate(paths):
        collect_round(path, config, RoundSpec(horizon=4), episodes=3, seed=20 + r)
    stores = [DemoStore.open(p) for p in paths]
    tracemalloc.start()
    try:
        steps = LabelledSteps(paths, obs_horizon=3, action_horizon=4, depth=True)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    joined = np.concatenate([s.root["data/depth"][:s.n_steps] for s in stores])
    np.testing.assert_array_equal(steps.frames.numpy().view(np.uint16), joined)
    assert peak < 0.5 * joined.nbytes, f"peak {peak} bytes on the heap for {joined.nbytes} bytes of frames"
    assert not list(tmp_path.glob("frames-*")), "the frames' file is left behind"
    in_memory = _frames(stores, depth_arrays(stores, "gt"), None)  # as for a GPU fit
    np.testing.assert_array_equal(in_memory, joined)


class _Reader:
    """A learner that records the frames it reads and holds still."""

    def __init__(self) -> None:
        self.read: list[np.ndarray] = []

    def reset(self, info: dict) -> None:
        pass

    def act(self, obs) -> np.ndarray:
        self.read.append(obs.depth.copy())
        return np.zeros(8, np.float32)


def test_a_round_under_a_sensor_shows_the_learner_its_frames_and_keeps_them_beside_the_clean_ones(tmp_path):
    """``RoundSpec.sensor``: the learner acts on the sensor's frames, the record keeps exactly those as
    ``depth_sensor``, the clean ones as ``depth``, and the sensor restarts from the episode's seed."""
    from trainer.sim.rollout import Job
    from trainer.sim.sensors import make_sensor
    from trainer.student.dagger import labelled_episode

    env = GraspEnv(EnvConfig(objects=("cube",), max_steps=5))
    spec, sensor = RoundSpec(learner="reader", horizon=0, stall_steps=100), make_sensor("randnoise")
    try:
        runs = []
        for _ in range(2):
            learner = _Reader()
            record, _ = labelled_episode(env, ReactiveExpert(), learner, Job(7, "cube"), spec, sensor)
            runs.append(record)
            np.testing.assert_array_equal(np.stack(learner.read), record.depth_sensor)
        clean, _ = labelled_episode(env, ReactiveExpert(), _Reader(), Job(7, "cube"), spec)
    finally:
        env.close()
    assert clean.depth_sensor is None
    np.testing.assert_array_equal(runs[0].depth, clean.depth)
    assert (runs[0].depth_sensor != runs[0].depth).mean() > 0.05  # randnoise moved the frames
    np.testing.assert_array_equal(runs[0].depth_sensor, runs[1].depth_sensor)


def test_a_fit_reads_the_sensors_frames_where_asked_and_refuses_a_store_without_them(tmp_path):
    from trainer.student.steps import LabelledSteps

    config = EnvConfig(objects=("cube",), max_steps=4)
    noisy_round = RoundSpec(horizon=0, sensor="randnoise")
    collect_round(tmp_path / "noisy.zarr", config, noisy_round, episodes=1, seed=3)
    collect_round(tmp_path / "clean.zarr", config, RoundSpec(horizon=0), episodes=1, seed=3)
    noisy = DemoStore.open(tmp_path / "noisy.zarr")
    assert noisy.attrs["sensor"] == "randnoise"
    for source, array in (("gt", "depth"), ("sensor", "depth_sensor")):
        steps = LabelledSteps([tmp_path / "noisy.zarr"], obs_horizon=1, action_horizon=1, depth=True,
                              chunks=False, depth_source=source)
        expected = normalise(noisy.episode(0)[array][2], 0.001, noisy.depth_spec)
        np.testing.assert_array_equal(steps.batch(torch.tensor([2])).depth[0, -1].numpy(), expected)
    with pytest.raises(DatasetError, match="no data/depth_sensor .* `python -m trainer student readout "):
        LabelledSteps([tmp_path / "clean.zarr"], 1, 1, depth=True, chunks=False, depth_source="sensor")
    both = LabelledSteps([tmp_path / "noisy.zarr"], obs_horizon=2, action_horizon=1, depth=True, chunks=False,
                         depth_source="sensor", teacher_source="gt")
    index = torch.tensor([0, 2, 3])
    alone = {source: LabelledSteps([tmp_path / "noisy.zarr"], obs_horizon=2, action_horizon=1, depth=True,
                                   chunks=False, depth_source=source).batch(index).depth
             for source in ("gt", "sensor")}
    batch = both.batch(index)
    torch.testing.assert_close(batch.depth, alone["sensor"], rtol=0, atol=0)
    torch.testing.assert_close(batch.teacher_depth, alone["gt"], rtol=0, atol=0)
    plain = LabelledSteps([tmp_path / "noisy.zarr"], 1, 1, depth=True, chunks=False)
    assert plain.teacher_frames is None and plain.batch(index).teacher_depth is None


def test_training_frames_are_held_in_a_dtype_a_gpu_can_index_and_read_back_exactly(tmp_path):
    """CUDA cannot index a uint16 tensor (torch 2.11: "index_cuda" not implemented for 'UInt16'), so the
    frames are held as int16 bits; a sensor value above 32767 must still read back as itself."""
    from trainer.student.steps import LabelledSteps

    config = EnvConfig(objects=("cube",), max_steps=3)
    collect_round(tmp_path / "round0.zarr", config, RoundSpec(horizon=4), episodes=1, seed=11)
    steps = LabelledSteps([tmp_path / "round0.zarr"], obs_horizon=3, action_horizon=4, depth=True)
    assert steps.frames.dtype == torch.int16
    far = np.full(steps.frames.shape[1:], 50_000, np.uint16)
    steps.frames[0] = torch.from_numpy(far.view(np.int16))
    expected = normalise(far, 0.001, DemoStore.open(tmp_path / "round0.zarr").depth_spec)
    np.testing.assert_array_equal(steps.batch(torch.tensor([0])).depth[0, -1].numpy(), expected)


def test_perception_student_exports_with_parity(tmp_path):
    from export.__main__ import main as export_main
    from export.check import run_check
    from trainer.student.cli import main as student_main

    ckpt, out = tmp_path / "p.pt", tmp_path / "p.onnx"
    assert student_main(["init", "--out", str(ckpt), "--perception", "depth", "--prediction", "v_prediction",
                         *TINY]) == 0
    assert export_main([str(ckpt), "--ddim-steps", "4", "--out", str(out)]) == 0
    assert run_check(out, repeats=1, trials=2, threads=1)["max_abs_err"] <= 1e-5


def test_the_rounds_draw_their_own_kinds_and_a_misspelt_one_is_refused(tmp_path, capsys, short_episodes):
    from trainer.student.recipe import main as recipe_main

    args = ["--out", str(tmp_path / "r"), "--perception", "privileged", "--objects", "cube", "--demos", "2",
            "--rounds", "1", "--round-episodes", "2", "--fit-steps", "2", "--round-steps", "1",
            "--workers", "1", "--curve-episodes", "1", "--eval-episodes", "1", "--state-features", "16",
            "--head-dims", "16", "32"]
    assert recipe_main([*args, "--round-objects", "bananna"]) == 2
    assert "bananna" in capsys.readouterr().err
    assert recipe_main([*args, "--round-objects", "banana"]) == 0
    data = tmp_path / "r" / "data"
    assert DemoStore.open(data / "round0.zarr").kinds == ["cube", "cube"]
    assert DemoStore.open(data / "round1.zarr").kinds == ["banana", "banana"]


def test_the_recipe_resumes_without_redoing_finished_stages(tmp_path, capsys, short_episodes):
    from trainer.student.recipe import main as recipe_main

    base = ["--out", str(tmp_path / "r"), "--perception", "privileged", "--demos", "2", "--rounds", "1",
            "--round-episodes", "1", "--fit-steps", "3", "--round-steps", "2", "--workers", "1",
            "--curve-episodes", "1", "--eval-episodes", "1", "--state-features", "16"]
    args = [*base, "--head-dims", "16", "32"]
    assert recipe_main(args) == 0
    log = (tmp_path / "r" / "log.jsonl").read_text().splitlines()
    stages = [json.loads(line)["stage"] for line in log]
    assert stages == ["round 0 data", "round 0 fit", "round 0 held-out", "round 1 data", "round 1 fit",
                      "round 1 held-out"]
    files = {p: p.stat().st_mtime_ns for p in (tmp_path / "r").rglob("*") if p.is_file()}
    assert recipe_main(args) == 0  # everything done: nothing is redone
    assert (tmp_path / "r" / "log.jsonl").read_text().splitlines() == log
    assert {p: p.stat().st_mtime_ns for p in files if p.name != "recipe.json"} == {
        p: t for p, t in files.items() if p.name != "recipe.json"}
    assert recipe_main([*base, "--head-dims", "16", "16"]) == 2
    assert "other settings" in capsys.readouterr().err
    summary = json.loads((tmp_path / "r" / "fit" / "round1" / "eval_seen.json").read_text())
    assert summary["episodes"] == 1 and summary["policy"].endswith("round1/ckpt.pt")
    more = [a if a != "1" or base[i - 1] != "--rounds" else "2" for i, a in enumerate(base)]
    # one more round, fitted in bf16, longer and on more episodes (which a resume may change): only its stages
    # run, and the measured rounds keep their data and weights
    longer = [a if base[i - 1] not in ("--round-steps", "--round-episodes") else "3"
              for i, a in enumerate(more)]
    assert recipe_main([*longer, "--head-dims", "16", "32", "--precision", "bf16"]) == 0
    entries = [json.loads(line) for line in (tmp_path / "r" / "log.jsonl").read_text().splitlines()]
    assert [e["stage"] for e in entries[len(log):]] == ["round 2 data", "round 2 fit", "round 2 held-out"]
    assert entries[len(log) + 1]["precision"] == "bf16" and entries[len(log) + 1]["steps"] == 3
    assert checkpoint.load(tmp_path / "r" / "fit" / "round1" / "ckpt.pt").step == 2
    assert [entries[i]["attempted"] for i in (3, len(log))] == [1, 3]  # round 1's store kept, round 2 longer
    assert json.loads((tmp_path / "r" / "fit" / "round2" / "eval_seen.json").read_text())["policy"].endswith(
        "round2/ckpt.pt")
    assert (tmp_path / "r" / "fit" / "round1" / "eval_seen.json").read_text() == json.dumps(summary, indent=2)


def test_recipe_data_are_refused_by_another_chunk_length(tmp_path):
    from trainer.dataset import DatasetError

    config = EnvConfig(objects=("cube",), max_steps=3, render_depth=False)
    collect_round(tmp_path / "r.zarr", config, RoundSpec(horizon=4), episodes=1, seed=1)
    with pytest.raises(DatasetError, match="expert chunks of 4 steps, not 6"):
        collect_round(tmp_path / "r.zarr", config, RoundSpec(horizon=6), episodes=2, seed=1)


def test_an_oracle_bias_moves_the_facts_it_reads(tmp_path):
    from trainer.student.cli import main as student_main
    from trainer.student.oracle_policy import load

    ckpt = tmp_path / "oracle.pt"
    assert student_main(["init", "--out", str(ckpt), "--perception", "privileged", *TINY]) == 0
    policy = load(f"{ckpt}@0.5")
    policy.reset({"object_half_extent": [0.02, 0.04, 0.02], "episode": {"seed": 3}})
    assert np.linalg.norm(policy._bias) == pytest.approx(0.005) and policy._bias[2] == 0
    with pytest.raises(ValueError, match="centimetres"):
        load(f"{ckpt}@half")


@pytest.mark.parametrize("mode", ["depth", "privileged"])
def test_the_student_runs_on_any_device(mode):
    """Every constant the network makes lives on its inputs' device (the recipe trains on a GPU): here the
    'meta' device, where a tensor left on the CPU fails the forward."""
    from trainer.student.config import StudentConfig
    from trainer.student.model import PerceptionStudent

    net = PerceptionStudent(StudentConfig(perception=mode, width=8, head_dims=(16, 32), state_features=16,
                                          step_features=16)).to("meta")
    seen = torch.zeros(2, 3, 96, 128) if mode == "depth" else torch.zeros(2, 12)
    obs = net.encode(seen.to("meta"), torch.zeros(2, 8, device="meta"))
    out = net(torch.zeros(2, 16, 8, device="meta"), torch.zeros(2, dtype=torch.int64, device="meta"), obs)
    assert out.shape == (2, 16, 8) and out.device.type == "meta"


@pytest.mark.slow
@pytest.mark.parametrize(("with_head", "sensor"), [(False, "clean"), (True, "randnoise")])
def test_a_depth_recipe_runs_its_stages_and_measures_its_readout(tmp_path, with_head, sensor, short_episodes):
    """The product path end to end at toy size: a depth student is exported each round (with ``--head``,
    composed with a privileged head first), drives the next round through onnxruntime, and its readout is
    measured on frames it never trained on; with ``--sensor``, every store keeps that sensor's frames and the
    readout is measured on them."""
    from trainer.student.cli import main as student_main
    from trainer.student.recipe import main as recipe_main

    out, head = tmp_path / "d", tmp_path / "m0.pt"
    assert student_main(["init", "--out", str(head), "--perception", "privileged", *TINY]) == 0
    args = ["--out", str(out), "--perception", "depth", "--demos", "2", "--rounds", "1",
            "--round-episodes", "1", "--fit-steps", "2", "--round-steps", "1", "--workers", "1",
            "--curve-episodes", "1", "--eval-episodes", "1", "--width", "8", "--head-dims", "16", "32",
            "--state-features", "16", "--batch", "4", "--sensor", sensor,
            *(["--head", str(head)] if with_head else [])]
    assert recipe_main(args) == 0
    kept = None if sensor == "clean" else sensor
    assert {DemoStore.open(out / "data" / f"round{r}.zarr").attrs.get("sensor") for r in (0, 1)} == {kept}
    for r in (0, 1):
        assert (out / "fit" / f"round{r}" / "student.onnx").is_file()
        assert (out / "fit" / f"round{r}" / "composed.pt").is_file() == with_head
        readout = json.loads((out / "fit" / f"round{r}" / "readout.json").read_text())
        assert readout["frames"] > 0 and readout["all"]["offset_cm_median"] > 0
        assert set(readout["near_by_kind"]) <= set(GROUPS["seen"])
        assert readout["depth_source"] == ("gt" if sensor == "clean" else "sensor")
    assert DemoStore.open(out / "data" / "round1.zarr").attrs["learner"].startswith("student:")
    # a round fitted elsewhere comes back without its ONNX file or held-out episodes (research/device):
    # the resume exports it again and collects nothing its measured readout no longer needs
    (out / "fit" / "round1" / "student.onnx").unlink()
    shutil.rmtree(out / "data" / "held_out_round1.zarr")
    assert recipe_main(args) == 0
    assert (out / "fit" / "round1" / "student.onnx").is_file()
    assert not (out / "data" / "held_out_round1.zarr").exists()
    assert json.loads((out / "fit" / "round1" / "eval_unseen.json").read_text())["objects"] == list(
        GROUPS["unseen"])


def test_one_bad_batch_moves_the_weights_no_further_than_the_clip_allows():
    """A loss a million times too large gives gradients of norm far above the limit; the step uses them
    scaled down to it (without the clip the gradients keep their norm)."""
    from trainer.student.distill import optimise

    torch.manual_seed(0)
    net = torch.nn.Linear(4, 2)
    optim = torch.optim.SGD(net.parameters(), lr=1.0)
    before = [p.detach().clone() for p in net.parameters()]
    loss = 1e6 * net(torch.randn(8, 4)).pow(2).sum()
    norm = optimise(net, optim, loss, max_grad_norm=0.5)
    moved = torch.cat([(p.detach() - b).flatten() for p, b in zip(net.parameters(), before, strict=True)])
    assert norm > 1e3 and float(moved.norm()) == pytest.approx(0.5, rel=1e-4)


def test_a_bf16_fit_step_computes_the_fp32_loss_to_within_bf16s_precision():
    """Under ``precision="bf16"`` the network runs in bf16 (the loss differs from fp32's on the same batch and
    noise) while its terms come back fp32 and within a few per cent; the weights stay fp32."""
    from trainer.student.config import StudentConfig
    from trainer.student.ddim import training_scheduler
    from trainer.student.distill import DistillConfig, losses
    from trainer.student.model import PerceptionStudent
    from trainer.student.steps import StepBatch

    torch.manual_seed(0)
    net = PerceptionStudent(StudentConfig(perception="depth", width=8, head_dims=(16, 32), state_features=16,
                                          step_features=16, prediction="v_prediction"))
    scheduler = training_scheduler(100, "v_prediction")
    b = 16
    batch = StepBatch(torch.rand(b, 3, 96, 128), torch.rand(b, 8), torch.rand(b, 12) * 2 - 1,
                      torch.rand(b, 16, 8))
    totals = {}
    for precision in ("fp32", "bf16"):
        cfg = DistillConfig(shift_px=2, near_loss=1, precision=precision)
        loss, terms = losses(net, scheduler, batch, torch.Generator().manual_seed(1), cfg)
        assert loss.dtype == torch.float32 and set(terms) == {"facts", "near", "keypoints", "denoise"}
        totals[precision] = float(loss.detach())
    assert totals["bf16"] != totals["fp32"]
    assert totals["bf16"] == pytest.approx(totals["fp32"], rel=0.05)
    assert all(p.dtype == torch.float32 for p in net.parameters())


@pytest.mark.parametrize("flags, warned", [({"avx2", "fma"}, True), ({"avx2", "avx512_bf16"}, False),
                                           ({"avx2", "amx_bf16"}, False), (set(), False)])
def test_bf16_on_a_cpu_without_bf16_arithmetic_warns_in_one_line(monkeypatch, capsys, flags, warned):
    """Emulated bf16 is ~13x slower than fp32: the fit says so once, and only where the flags say it is."""
    from trainer.student import distill

    monkeypatch.setattr(distill, "cpu_flags", lambda: flags)
    distill.warn_slow_bf16(distill.DistillConfig(precision="bf16"), torch.device("cpu"))
    distill.warn_slow_bf16(distill.DistillConfig(precision="fp32"), torch.device("cpu"))
    err = capsys.readouterr().err
    assert ("bf16 on a CPU without bf16 arithmetic" in err) == warned
    assert err.count("\n") == int(warned)


def test_an_unknown_fit_precision_is_refused_in_one_line(capsys):
    from trainer.student.recipe import main

    assert main(["--out", "/nonexistent/recipe", "--precision", "fp8"]) == 2
    err = capsys.readouterr().err.strip()
    assert "precision must be one of fp32, bf16" in err and "\n" not in err


def test_a_shifted_stack_carries_its_pixel_labels_along():
    """Every sample's marked pixel lands where its shifted labels say, in every frame of its stack, and the
    offset label (the object from the hand) is left as it was."""
    from trainer.student.distill import shifted
    from trainer.student.steps import StepBatch

    h, w, n = 96, 128, 16
    ys, xs = torch.randint(10, h - 10, (n,)), torch.randint(10, w - 10, (n,))
    depth = torch.zeros(n, 3, h, w)
    depth[torch.arange(n), :, ys, xs] = 1.0
    labels = torch.rand(n, 12)
    labels[:, OBJECT_PX] = torch.stack([xs * 2 / (w - 1) - 1, ys * 2 / (h - 1) - 1], dim=1)
    out = shifted(StepBatch(depth, torch.zeros(n, 8), labels, torch.zeros(n, 4, 8), 2 * depth), 4,
                  torch.Generator().manual_seed(0))
    torch.testing.assert_close(out.teacher_depth, 2 * out.depth, rtol=0, atol=0)  # the same shift
    moved = 0
    for i in range(n):
        peak = (out.depth[i] == 1).nonzero()
        assert len(peak) == 3 and (peak[:, 1:] == peak[0, 1:]).all()  # one pixel, the same in each frame
        y, x = peak[0, 1:].tolist()
        torch.testing.assert_close(out.labels[i, OBJECT_PX], torch.tensor([x * 2 / (w - 1) - 1,
                                                                           y * 2 / (h - 1) - 1]))
        moved += (x, y) != (int(xs[i]), int(ys[i]))
    assert moved >= n // 2
    torch.testing.assert_close(out.labels[:, OFFSET], labels[:, OFFSET])


def _unlike_students(folder, kinds: dict[str, str]) -> dict:
    """Tiny students of the given perceptions whose hand and label normalisers differ, as real fits' do."""
    from trainer.student import checkpoint
    from trainer.student.cli import main as student_main

    gen = torch.Generator().manual_seed(0)
    ckpts = {}
    for name, kind in kinds.items():
        path = folder / f"{name}.pt"
        assert student_main(["init", "--out", str(path), "--prediction", "v_prediction", *TINY,
                             "--perception", kind]) == 0
        ckpts[name] = ckpt = checkpoint.load(path)
        for key in ("hand_norm.centre", "label_norm.centre"):
            ckpt.ema[key] = torch.randn(ckpt.ema[key].shape, generator=gen)
        for key in ("hand_norm.half_range", "label_norm.half_range"):
            ckpt.ema[key] = torch.rand(ckpt.ema[key].shape, generator=gen) + 0.5
    return ckpts


def _facts_in_head_units(eye, head, depth, state):
    _, facts, _ = eye.perceive(depth, state)
    return head.label_norm.normalise(eye.label_norm.unnormalise(facts))


def test_a_composed_student_acts_on_the_readout_as_the_privileged_head_would(tmp_path):
    """The depth student's readout, turned into the head's units, feeds the privileged head: the composed
    network computes exactly that, though the two were normalised differently; and it exports with parity."""
    from export.__main__ import main as export_main
    from export.check import run_check
    from trainer.student import checkpoint
    from trainer.student.compose import compose

    ckpts = _unlike_students(tmp_path, {"eye": "depth", "head": "privileged"})
    eye, head = (ckpts[name].policy() for name in ("eye", "head"))
    composed = compose(ckpts["eye"], ckpts["head"])
    gen = torch.Generator().manual_seed(1)
    depth, state = torch.rand(3, 3, 96, 128, generator=gen), torch.randn(3, 8, generator=gen) * 0.3
    with torch.no_grad():
        expected = head.fuse(state[:, :0], _facts_in_head_units(eye, head, depth, state), state)
        got = composed.policy().encode(depth, state)
    torch.testing.assert_close(got, expected, atol=1e-5, rtol=1e-5)
    assert not composed.config.head_features
    checkpoint.save(tmp_path / "c.pt", composed)
    assert export_main([str(tmp_path / "c.pt"), "--ddim-steps", "4", "--out", str(tmp_path / "c.onnx")]) == 0
    assert run_check(tmp_path / "c.onnx", repeats=1, trials=2, threads=1)["max_abs_err"] <= 1e-5


def test_a_composed_pair_acts_on_the_mean_of_its_readouts(tmp_path, capsys):
    """``compose --also``: each readout is turned into the head's units and the head reads their mean; a
    partner that sees depth through another network is refused in one line."""
    from trainer.student.cli import main as student_main
    from trainer.student.compose import compose

    ckpts = _unlike_students(tmp_path, {"eye": "depth", "other": "depth", "head": "privileged"})
    eye, other, head = (ckpts[name].policy() for name in ("eye", "other", "head"))
    pair = compose(ckpts["eye"], ckpts["head"], (ckpts["other"],))
    gen = torch.Generator().manual_seed(1)
    depth, state = torch.rand(3, 3, 96, 128, generator=gen), torch.randn(3, 8, generator=gen) * 0.3
    with torch.no_grad():
        mean = sum(_facts_in_head_units(e, head, depth, state) for e in (eye, other)) / 2
        expected = head.fuse(state[:, :0], mean, state)
        got = pair.policy().encode(depth, state)
    torch.testing.assert_close(got, expected, atol=1e-5, rtol=1e-5)
    assert pair.config.perceptions == 2
    wide = tmp_path / "wide.pt"
    assert student_main(["init", "--out", str(wide), "--perception", "depth", *TINY, "--width", "16"]) == 0
    assert student_main(["compose", "--perception", str(tmp_path / "eye.pt"), "--also", str(wide), "--head",
                         str(tmp_path / "head.pt"), "--out", str(tmp_path / "c.pt")]) == 2
    err = capsys.readouterr().err
    assert "--also students must see depth as --perception does: width differ" in err and err.count("\n") == 1


def test_compose_refuses_a_head_that_reads_depth(tmp_path, capsys):
    from trainer.student.cli import main as student_main

    eye = tmp_path / "eye.pt"
    assert student_main(["init", "--out", str(eye), "--perception", "depth", *TINY]) == 0
    assert student_main(["compose", "--perception", str(eye), "--head", str(eye), "--out",
                         str(tmp_path / "c.pt")]) == 2
    assert "--head must be a privileged student" in capsys.readouterr().err


def test_readout_errors_name_an_empty_group_instead_of_failing():
    """A learner that never came near the object leaves the 'near' group empty."""
    from trainer.student.readout import errors

    labels = np.zeros((4, 12), np.float32)
    labels[:, 0] = 0.2  # 20 cm from the hand throughout
    result = errors(labels + 0.01, labels, np.array([2, 4]))
    assert result["near"] == {"frames": 0} and result["all"]["offset_cm_median"] == pytest.approx(1.732, 1e-3)


def test_the_gate_judges_every_frame_as_well_as_the_frames_near_the_object():
    """A readout 0.5 cm off near the object passes the near target; 5 cm off on the far frames it fails the
    every-frame one, and so the gate (the residual readout's case); one never near the object fails."""
    from trainer.student.readout import errors, gate

    labels = np.zeros((40, 12), np.float32)
    labels[20:, 0] = 0.2  # half of each episode far from the object
    estimate = labels.copy()
    estimate[:, 1] += 0.005
    ends = np.array([10, 20, 30, 40])  # two episodes near the object, two far
    good = gate(errors(estimate, labels, ends))
    assert good["passed"] and good["near"]["bias_cm_p90"] == pytest.approx(0.5, abs=1e-3)
    estimate[20:, 1] += 0.05
    far = gate(errors(estimate, labels, ends))
    assert far["near"]["passed"] and not far["all"]["passed"] and not far["passed"]
    assert not gate(errors(labels[20:] + 0.001, labels[20:], np.array([10, 20])))["passed"]


def test_the_near_loss_weighs_an_error_by_how_near_the_object_is():
    """A 1 cm horizontal error costs 1 where the hand is on the object and 1/441 twenty centimetres away, so
    the fit cares most where the grasp is decided; the vertical error and the other facts do not enter."""
    from trainer.student.distill import near_error

    labels = torch.zeros(2, 12)
    labels[1, 0] = 0.20  # the second frame: the object 20 cm from the hand
    facts = labels[:, :8].clone()
    facts[:, 1] += 0.01
    facts[:, 2:] += 0.5  # height, direction and size: not this term's business
    per_frame = [float(near_error(facts[i:i + 1], labels[i:i + 1])) for i in range(2)]
    assert per_frame == pytest.approx([1.0, 1 / 441], rel=1e-4)


def test_the_readout_reports_how_much_of_a_near_miss_it_sees():
    """A readout that reports half of every offset reads a share of 0.5 of the near misses; one that reports
    them whole reads 1; frames outside the near-miss band are not counted."""
    from trainer.student.readout import off_target

    rng = np.random.default_rng(0)
    labels = np.zeros((200, 8), np.float32)
    labels[:, :2] = rng.uniform(-0.03, 0.03, (200, 2))
    length = np.linalg.norm(labels[:, :2], axis=1)
    in_band = int(((length >= 0.007) & (length < 0.02)).sum())
    assert off_target(labels * 0.5, labels) == {"frames": in_band, "read_share_median": 0.5}
    assert off_target(labels, labels)["read_share_median"] == 1.0


def test_the_readout_names_the_kind_it_misplaces():
    """Near the object, each kind's mean error vector: a kind read 2 cm off in x every frame shows as
    (2, 0, 0), one read exactly as (0, 0, 0); frames far from the object are not counted; a size misread
    shows the same way. A kind with a grasp direction read 30 degrees off shows it; a round kind shows the
    length of the direction it reads."""
    from trainer.student.readout import by_kind

    labels = np.zeros((6, 12), np.float32)
    labels[2, 0] = 0.2  # the first episode's last frame: 20 cm away, misread by 5 cm
    labels[3:, 3] = 1.0  # the second kind's grasp direction: (cos 2p, sin 2p) at p = 0
    estimate = labels.copy()
    estimate[:3, 0] += [0.02, 0.02, 0.05]
    estimate[:3, 3:5] = [[0.6, 0.8], [0.0, 0.0], [0.0, 0.0]]  # the round can read as elongated once, far
    estimate[3:, 3:5] = np.cos(np.pi / 3), np.sin(np.pi / 3)  # read at p = 30 degrees
    estimate[:2, 5:7] -= 0.008  # the can read 1.6 cm narrower near it
    result = by_kind(estimate, labels, np.array([3, 6]), ["can", "block"])
    assert result["can"] == {"near_frames": 2, "offset_cm_median": 2.0, "mean_error_cm": [2.0, 0.0, 0.0],
                             "size_error_cm": [-0.8, -0.8, 0.0], "grasp_yaw_length_median": 0.5}
    assert result["block"] == {"near_frames": 3, "offset_cm_median": 0.0, "mean_error_cm": [0.0, 0.0, 0.0],
                               "size_error_cm": [0.0, 0.0, 0.0], "grasp_yaw_deg_median": 30.0}


def test_readout_refuses_an_unknown_kind_in_one_line(tmp_path, capsys):
    from trainer.student.cli import main as student_main
    from trainer.student.readout import main as readout_main

    eye = tmp_path / "eye.pt"
    assert student_main(["init", "--out", str(eye), "--perception", "depth", *TINY]) == 0
    assert readout_main([str(eye), "--store", str(tmp_path / "s.zarr"), "--episodes", "1",
                         "--objects", "dragonfruit"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: unknown object kind 'dragonfruit'") and "\n" not in err


def test_refit_fits_a_student_on_given_stores_from_its_own_weights(tmp_path, capsys):
    """``student refit``: the init's network and weights, fitted on the named stores, resumable; a student
    that is not a depth student of one perception is refused in one line."""
    from trainer.student.cli import main as student_main
    from trainer.student.recipe import Recipe, RecipeConfig

    head, eye = tmp_path / "m0.pt", tmp_path / "eye.pt"
    assert student_main(["init", "--out", str(head), "--perception", "privileged", *TINY]) == 0
    assert student_main(["init", "--out", str(eye), "--perception", "depth", *TINY]) == 0
    recipe = Recipe(tmp_path / "r", RecipeConfig(head=str(head), hover_episodes=1, workers=1))
    recipe.env = EnvConfig(objects=("cube",), max_steps=6, depth=recipe.env.depth)
    recipe.hover()
    args = ["refit", "--init", str(eye), "--stores", str(recipe.hover_store()), "--steps", "2", "--batch",
            "2", "--shares", "cube=0.5", "--out", str(tmp_path / "fit")]
    assert student_main(args) == 0
    done, init = checkpoint.load(tmp_path / "fit" / "ckpt.pt"), checkpoint.load(eye)
    assert done.step == 2 and done.config == init.config
    assert done.info.data["refit"]["stores"] == [str(recipe.hover_store())]
    key = "perception.readout.4.weight"
    assert not torch.equal(done.ema[key], init.ema[key])
    capsys.readouterr()
    assert student_main(args) == 0 and json.loads(capsys.readouterr().out)["steps_this_run"] == 0  # resumed
    assert student_main(["refit", "--init", str(head), "--stores", str(recipe.hover_store()), "--out",
                         str(tmp_path / "no")]) == 2
    err = capsys.readouterr().err
    assert "--init must be a depth student of one perception" in err and err.count("\n") == 1


def test_a_feature_teacher_pulls_the_fitted_features_toward_its_own_of_the_clean_frames(tmp_path, capsys):
    """``refit --teacher``: the teacher's term is nil where the student is the teacher and the fitted frames
    are the clean ones, not where they are a sensor's; the refit records its teacher; a teacher without a
    weight, or of another network, is refused in one line."""
    from trainer.student.cli import main as student_main
    from trainer.student.distill import FeatureTeacher
    from trainer.student.steps import LabelledSteps

    eye, other = tmp_path / "eye.pt", tmp_path / "other.pt"
    assert student_main(["init", "--out", str(eye), "--perception", "depth", *TINY]) == 0
    wider = [*TINY[:1], "16", *TINY[2:]]
    assert student_main(["init", "--out", str(other), "--perception", "depth", *wider]) == 0
    config = EnvConfig(objects=("cube",), max_steps=6, depth=checkpoint.load(eye).info.depth_spec)
    store = tmp_path / "noisy.zarr"
    collect_round(store, config, RoundSpec(horizon=0, sensor="randnoise"), episodes=2, seed=3)
    net, index = checkpoint.load(eye).policy(), torch.arange(8)
    for source, nil in (("gt", True), ("sensor", False)):
        steps = LabelledSteps([store], net.config.obs_horizon, 1, depth=True, chunks=False,
                              depth_source=source, teacher_source="gt")
        batch = steps.batch(index)
        with torch.no_grad():
            features = net.perceive(batch.depth, batch.state)[0]
        loss = float(FeatureTeacher(checkpoint.load(eye).policy(), steps).loss(features, batch))
        assert (loss < 1e-10) if nil else (loss > 1e-3), (source, loss)
    args = ["refit", "--init", str(eye), "--stores", str(store), "--steps", "2", "--batch", "2",
            "--perception-only", "--depth-source", "sensor", "--teacher", str(eye)]
    assert student_main([*args, "--teacher-loss", "0.5", "--out", str(tmp_path / "fit")]) == 0
    done = checkpoint.load(tmp_path / "fit" / "ckpt.pt")
    assert done.step == 2 and done.info.data["refit"]["teacher"] == str(eye)
    assert json.loads(capsys.readouterr().out.strip().splitlines()[-1])["last_terms"]["teacher"] > 0
    for extra, message in (([], "a feature teacher and --teacher-loss > 0 go together"),
                           (["--teacher-loss", "1", "--teacher", str(other)], "must be a depth student of")):
        assert student_main([*args, *extra, "--out", str(tmp_path / "no")]) == 2
        err = capsys.readouterr().err
        assert message in err and err.count("\n") == 1


def test_a_perception_only_refit_reads_frames_without_chunks_and_leaves_the_head_as_it_was(tmp_path, capsys):
    """``refit --perception-only``: the readout is fitted on a store whose frames are labelled alone
    (``readout --no-chunks``), the head's weights stay the init's (to the EMA's float rounding, 1e-7 where
    two optimiser steps move a weight 1e-6 or more); a full refit refuses that store in one line that says
    what it holds."""
    from trainer.student.cli import main as student_main

    eye = tmp_path / "eye.pt"
    assert student_main(["init", "--out", str(eye), "--perception", "depth", *TINY]) == 0
    config = EnvConfig(objects=("cube",), max_steps=6, depth=checkpoint.load(eye).info.depth_spec)
    store = tmp_path / "frames.zarr"
    collect_round(store, config, RoundSpec(horizon=0), episodes=2, seed=3)
    args = ["refit", "--init", str(eye), "--stores", str(store), "--steps", "2", "--batch", "2", "--out"]
    assert student_main([*args, str(tmp_path / "fit"), "--perception-only"]) == 0
    done, init = checkpoint.load(tmp_path / "fit" / "ckpt.pt"), checkpoint.load(eye)
    assert not torch.equal(done.ema["perception.readout.4.weight"], init.ema["perception.readout.4.weight"])
    head = [k for k in init.ema if not k.startswith("perception.")]
    assert head and all(torch.allclose(done.ema[k], init.ema[k], rtol=0, atol=1e-7) for k in head)
    capsys.readouterr()
    assert student_main([*args, str(tmp_path / "full")]) == 2
    err = capsys.readouterr().err
    assert "its frames are labelled alone, for a perception-only fit" in err and err.count("\n") == 1


def test_hover_episodes_are_driven_by_the_biased_head_and_join_every_fit(tmp_path, capsys):
    """``--hover-episodes``: the privileged head, its facts offset by ``--hover-cm``, drives a store labelled
    by the expert, which every fit reads beside the rounds' stores; without ``--head`` it is refused."""
    from trainer.student.cli import main as student_main
    from trainer.student.recipe import Recipe, RecipeConfig
    from trainer.student.recipe import main as recipe_main

    head = tmp_path / "m0.pt"
    assert student_main(["init", "--out", str(head), "--perception", "privileged", *TINY]) == 0
    recipe = Recipe(tmp_path / "r", RecipeConfig(head=str(head), hover_episodes=1, hover_cm=2.0, workers=1))
    recipe.env = EnvConfig(objects=("cube",), max_steps=4, depth=recipe.env.depth)
    recipe.hover()
    store = DemoStore.open(recipe.hover_store())
    assert store.attrs["learner"] == f"oracle:{head}@2" and store.attrs["attempted"] == 1
    assert store.n_steps > 0 and "chunk" in store.root["data"]
    assert recipe.stores(1) == [recipe.store(0), recipe.store(1), recipe.hover_store()]
    assert recipe_main(["--out", str(tmp_path / "x"), "--hover-episodes", "1"]) == 2
    assert "--hover-episodes needs --head" in capsys.readouterr().err


def test_training_kinds_are_chosen_by_objects_and_a_bad_one_is_refused_in_one_line(tmp_path, capsys):
    """``--objects train``: the demos and the rounds draw from the seen kinds and the procedural shapes; the
    curve and the evaluation keep the built-in groups. An unknown kind stops the recipe before any work."""
    from trainer.student.recipe import Recipe, RecipeConfig
    from trainer.student.recipe import main as recipe_main

    assert Recipe(tmp_path / "s", RecipeConfig()).env.objects == GROUPS["seen"]
    train = Recipe(tmp_path / "t", RecipeConfig(objects="train")).env.objects
    assert train == GROUPS["seen"] + GROUPS["shapes"]
    assert recipe_main(["--out", str(tmp_path / "x"), "--objects", "apple,dragonfruit"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: unknown object kind 'dragonfruit'") and "\n" not in err
    assert not (tmp_path / "x").exists()


def test_the_fit_runs_the_encoder_channels_last_on_the_cpu_with_the_same_loss():
    """``training_layout`` puts the convolutions channels-last (faster on the CPU) and changes no value: the
    loss on the same batch and noise equals the contiguous layout's to float rounding."""
    from trainer.student.config import StudentConfig
    from trainer.student.ddim import training_scheduler
    from trainer.student.distill import DistillConfig, losses, training_layout
    from trainer.student.model import PerceptionStudent
    from trainer.student.steps import StepBatch

    torch.manual_seed(0)
    cfg = StudentConfig(perception="depth", width=8, head_dims=(16, 32), state_features=16, step_features=16)
    plain = PerceptionStudent(cfg)
    fast = PerceptionStudent(cfg)
    fast.load_state_dict(plain.state_dict())
    fast = training_layout(fast)
    conv = fast.perception.resnet.stem[0].weight
    assert conv.is_contiguous(memory_format=torch.channels_last) and not conv.is_contiguous()
    batch = StepBatch(torch.rand(8, 3, 96, 128), torch.rand(8, 8), torch.rand(8, 12) * 2 - 1,
                      torch.rand(8, 16, 8))
    scheduler, fit = training_scheduler(100, "epsilon"), DistillConfig(shift_px=2)
    totals = [losses(net, scheduler, batch, torch.Generator().manual_seed(1), fit)[0].item()
              for net in (plain, fast)]
    assert totals[1] == pytest.approx(totals[0], rel=1e-5)


def test_a_missing_head_is_refused_in_one_line_before_any_stage(tmp_path, capsys):
    from trainer.student.recipe import main

    out = tmp_path / "recipe"
    assert main(["--out", str(out), "--head", str(tmp_path / "m0.pt"), "--hover-episodes", "2"]) == 2
    err = capsys.readouterr().err
    assert f"--head {tmp_path / 'm0.pt'}: no such checkpoint" in err and err.count("\n") == 1
    assert not out.exists()


@pytest.mark.slow
def test_round_0_starts_from_init_at_another_resolution_and_a_mismatched_one_is_refused(tmp_path, capsys,
                                                                                         short_episodes):
    """A checkpoint holds no image size, so a student of the same model settings warms a recipe at 192 x 144:
    with no learning rate round 0's weights stay the ones it started from, which are init's."""
    from trainer.student.cli import main as student_main
    from trainer.student.recipe import main as recipe_main

    init = tmp_path / "init.pt"
    assert student_main(["init", "--out", str(init), "--perception", "depth", "--width", "8", "--head-dims",
                         "16", "32", "--state-features", "16", "--exec-horizon", "4", "--prediction",
                         "v_prediction"]) == 0
    args = ["--perception", "depth", "--demos", "1", "--rounds", "0", "--fit-steps", "1", "--lr", "0",
            "--workers", "1", "--curve-episodes", "1", "--eval-episodes", "1", "--width", "8", "--head-dims",
            "16", "32", "--state-features", "16", "--batch", "2", "--resolution", "192x144",
            "--init", str(init)]
    other = [a if args[i - 1] != "--state-features" else "32" for i, a in enumerate(args)]
    assert recipe_main(["--out", str(tmp_path / "other"), *other]) == 2
    assert f"--init {init} is a student of other settings" in capsys.readouterr().err
    assert not (tmp_path / "other").exists()
    assert recipe_main(["--out", str(tmp_path / "r"), *args]) == 0
    fitted, source = checkpoint.load(tmp_path / "r" / "fit" / "round0" / "ckpt.pt"), checkpoint.load(init)
    assert fitted.step == 1 and fitted.model.keys() == source.ema.keys()
    assert all(torch.equal(fitted.model[k], source.ema[k]) for k in source.ema)


def test_shares_draw_each_named_group_that_share_of_each_batch(tmp_path):
    """Steps know their episode's kind; with shares the fit draws each named group's steps that often (the
    first named group that holds a kind takes it), the other steps what is left, however few each holds."""
    from trainer.student.distill import batch_weights
    from trainer.student.steps import LabelledSteps

    config = EnvConfig(objects=("cube", "shape03"), max_steps=3)
    collect_round(tmp_path / "round0.zarr", config, RoundSpec(horizon=4), episodes=3, seed=11)
    store = DemoStore.open(tmp_path / "round0.zarr")
    steps = LabelledSteps([tmp_path / "round0.zarr"], obs_horizon=3, action_horizon=4, depth=False)
    lengths = np.diff(store.episode_ends, prepend=0)
    assert list(steps.kinds) == list(np.repeat(store.kinds, lengths))
    kinds = np.array(["cube"] * 10 + ["apple_x89"] * 30 + ["square00"] * 20 + ["shape03"] * 40)
    assert batch_weights(kinds, ()) is None
    weights = batch_weights(kinds, ("seen=0.4", "scaled=0.25", "squares=0.15"))
    draws = torch.multinomial(weights, 40_000, replacement=True, generator=torch.Generator().manual_seed(0))
    drawn = np.bincount(np.digitize(draws.numpy(), [10, 40, 60]), minlength=4) / len(draws)
    assert np.allclose(drawn, [0.4, 0.25, 0.15, 0.2], atol=0.01)
    first = batch_weights(kinds, ("cube=0.3", "train=0.3"))  # cube is in train: the first group takes it
    assert float(first[:10].sum()) == pytest.approx(0.3) and float(first[60:].sum()) == pytest.approx(0.3)
    with pytest.raises(ValueError, match="no step's kind is in it"):
        batch_weights(np.array(["shape03"] * 5), ("seen=0.5",))
    with pytest.raises(ValueError, match="leave nothing for the 40 steps"):
        batch_weights(kinds, ("seen=0.5", "scaled=0.3", "squares=0.2"))


@pytest.mark.parametrize("shares, message", [
    (["seen=1.5"], "each share between 0 and 1"), (["seen"], "GROUP=SHARE"),
    (["seen=0.6", "shapes=0.6"], "add up to 1.2"), (["lemon=0.3"], "--shares names lemon, which neither"),
    (["sen=0.3"], "sen")])
def test_bad_shares_are_refused_in_one_line_before_any_work(capsys, shares, message):
    from trainer.student.recipe import main

    assert main(["--out", "/nonexistent/recipe", "--objects", "train", "--shares", *shares]) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and "\n" not in err
    assert not Path("/nonexistent/recipe").exists()
