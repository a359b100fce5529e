"""The training data path gives the policy exactly what the runtime gives it, bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

from runtime.preprocess import FrameStack, normalise
from trainer.dataset import DemoStore
from trainer.student.data import DemoDataError, DemoDataset


def runtime_stacks(store_path, episode: int) -> tuple[np.ndarray, np.ndarray]:
    """Replay one episode the way the runtime sees it: frame by frame through normalise + FrameStack."""
    store = DemoStore.open(store_path)
    ep, attrs = store.episode(episode), store.attrs
    stack = FrameStack(3)
    frames = [stack.push(normalise(d, attrs["depth_scale"], store.depth_spec)) for d in ep["depth"]]
    return np.stack(frames), ep["state"]


@pytest.mark.parametrize("episode", [0, 1])
def test_training_samples_equal_runtime_inputs(tiny_demos, episode):
    data = DemoDataset(tiny_demos, "gt", obs_horizon=3, action_horizon=16)
    expected, states = runtime_stacks(tiny_demos, episode)
    first = 0 if episode == 0 else int(data.ends[episode - 1])
    batch = data.batch(np.arange(first, first + len(expected)))
    got = batch.depth.numpy()
    assert got.dtype == expected.dtype == np.float32
    assert got.shape[1] == 3
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


@pytest.mark.parametrize("source, match", [("ddg", "depth_ddg"), ("sharpie", "unknown depth source")])
def test_missing_or_unknown_depth_source_is_named(tiny_demos, source, match):
    with pytest.raises(DemoDataError, match=match):
        DemoDataset(tiny_demos, source, 3, 16)
