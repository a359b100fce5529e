"""The training data path gives the policy exactly what the runtime gives it, bit for bit."""

from __future__ import annotations

import shutil

import numpy as np
import pytest
import zarr

from runtime.preprocess import FrameStack, normalise
from trainer.dataset import DemoStore
from trainer.student.data import DemoDataError, DemoDataset


def runtime_stacks(store_path, episode: int, first_frame: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Replay one episode the way the runtime sees it: frame by frame through normalise + FrameStack."""
    store = DemoStore.open(store_path)
    ep, attrs = store.episode(episode), store.attrs
    stack = FrameStack(3, first_frame)
    frames = [stack.push(normalise(d, attrs["depth_scale"], store.depth_spec)) for d in ep["depth"]]
    return np.stack(frames), ep["state"]


@pytest.mark.parametrize("first_frame", [False, True])
@pytest.mark.parametrize("episode", [0, 1])
def test_training_samples_equal_runtime_inputs(tiny_demos, episode, first_frame):
    data = DemoDataset(tiny_demos, "gt", obs_horizon=3, action_horizon=16, first_frame=first_frame)
    expected, states = runtime_stacks(tiny_demos, episode, first_frame)
    first = 0 if episode == 0 else int(data.ends[episode - 1])
    batch = data.batch(np.arange(first, first + len(expected)))
    got = batch.depth.numpy()
    assert got.dtype == expected.dtype == np.float32
    assert got.shape[1] == 3 + first_frame
    assert np.array_equal(got, expected)  # bit-exact, holes (-1) included
    assert (got == -1).any()
    assert np.array_equal(batch.state.numpy(), states)


def test_action_chunks_pad_with_the_last_action(tiny_demos):
    data = DemoDataset(tiny_demos, "gt", obs_horizon=3, action_horizon=16)
    end = int(data.ends[0])
    chunk = data.batch(np.array([end - 2])).action.numpy()[0]
    assert np.array_equal(chunk[0], data.action[end - 2])
    assert np.array_equal(chunk[1:], np.repeat(data.action[end - 1:end], 15, axis=0))


def test_frames_never_cross_episodes(tiny_demos):
    data = DemoDataset(tiny_demos, "gt", obs_horizon=3, action_horizon=16)
    start = int(data.ends[0])
    assert data.frame_indices(start).tolist() == [start] * 3
    assert data.frame_indices(start + 1).tolist() == [start, start, start + 1]


def test_randnoise_changes_frames_but_keeps_the_layout(tiny_demos):
    clean = DemoDataset(tiny_demos, "gt", 3, 16).batch(np.arange(4)).depth
    noisy = DemoDataset(tiny_demos, "randnoise", 3, 16).batch(np.arange(4), np.random.default_rng(0)).depth
    assert noisy.shape == clean.shape and not np.array_equal(noisy.numpy(), clean.numpy())
    assert float(noisy.min()) >= -1.0 and float(noisy.max()) <= 1.0


def test_gt_share_draws_each_stack_from_the_clean_or_the_sources_frames(tiny_demos, tmp_path):
    demos = tmp_path / "demos.zarr"
    shutil.copytree(tiny_demos, demos)
    root = zarr.open_group(str(demos), mode="a")
    clean = np.asarray(root["data/depth"])
    root.create_array("data/depth_sensor", data=clean // 2 + 100)  # a source unlike the clean frames
    steps, rng = np.arange(len(clean)), np.random.default_rng(0)
    gt, sensor = (DemoDataset(demos, s, 3, 16).batch(steps).depth.numpy() for s in ("gt", "sensor"))
    mixed = DemoDataset(demos, "sensor", 3, 16, gt_share=0.5).batch(steps, rng).depth.numpy()
    from_gt = [np.array_equal(m, g) for m, g in zip(mixed, gt, strict=True)]
    from_sensor = [np.array_equal(m, s) for m, s in zip(mixed, sensor, strict=True)]
    # whole stacks, each from one or the other
    assert all(a != b for a, b in zip(from_gt, from_sensor, strict=True))
    assert 0 < sum(from_gt) < len(steps)
    every = DemoDataset(demos, "sensor", 3, 16, gt_share=1.0).batch(steps, rng).depth.numpy()
    np.testing.assert_array_equal(every, gt)
    with pytest.raises(DemoDataError, match="gt_share must be in"):
        DemoDataset(demos, "sensor", 3, 16, gt_share=1.5)


@pytest.mark.parametrize("source, match", [("ddg", "depth_ddg"), ("sharpie", "unknown depth source")])
def test_missing_or_unknown_depth_source_is_named(tiny_demos, source, match):
    with pytest.raises(DemoDataError, match=match):
        DemoDataset(tiny_demos, source, 3, 16)
