"""Demo store: round trip, layout names, resume after an interrupted write, clear errors."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
import zarr

from runtime.preprocess import DepthSpec
from trainer.dataset import DatasetError, DemoStore, EpisodeRecord


def _episode(steps: int, seed: int, rgb: bool = False) -> EpisodeRecord:
    rng = np.random.default_rng(seed)
    return EpisodeRecord(
        depth=rng.integers(0, 3000, (steps, 96, 128), dtype=np.uint16),
        state=rng.normal(size=(steps, 8)).astype(np.float32),
        action=rng.uniform(-1, 1, (steps, 8)).astype(np.float32),
        kind=["apple", "banana"][seed % 2], seed=seed, crop_window=(80 + seed, 200 - seed),
        camera_K=np.diag([424.5, 424.2, 1.0]), camera_extrinsics=np.eye(4) * (seed + 1),
        randomisation={"seed": seed, "joint_friction": [0.1] * 7},
        rgb=rng.integers(0, 255, (steps, 96, 128, 3), dtype=np.uint8) if rgb else None)


def _create(path, rgb: bool = False) -> DemoStore:
    return DemoStore.create(path, spec=DepthSpec(), action_scale=0.05, control_rate_hz=10.0, rgb=rgb)


@pytest.mark.parametrize("rgb", [False, True])
def test_round_trip(tmp_path, rgb: bool) -> None:
    store = _create(tmp_path / "d.zarr", rgb=rgb)
    eps = [_episode(n, i, rgb) for i, n in enumerate((5, 9, 3))]
    for ep in eps:
        store.append(ep)
        store.count(success=True)
    store.count(success=False)
    back = DemoStore.open(tmp_path / "d.zarr")
    np.testing.assert_array_equal(back.episode_ends, [5, 14, 17])
    assert back.n_steps == 17 and back.n_episodes == 3
    attrs = back.attrs
    assert (attrs["attempted"], attrs["succeeded"], attrs["failed"]) == (4, 3, 1)
    assert attrs["depth_scale"] == 0.001 and attrs["action_scale"] == 0.05 and attrs["control_rate_hz"] == 10
    assert back.depth_spec == DepthSpec()
    for i, ep in enumerate(eps):
        got = back.episode(i)
        for name in ("depth", "state", "action", *(["rgb"] if rgb else [])):
            np.testing.assert_array_equal(got[name], getattr(ep, name))
            assert got[name].dtype == getattr(ep, name).dtype
        assert got["kind"] == ep.kind and int(got["seed"]) == ep.seed
        assert tuple(got["crop_window"]) == ep.crop_window
        np.testing.assert_array_equal(got["camera_extrinsics"], ep.camera_extrinsics)
        assert got["randomisation"] == ep.randomisation
    assert back.root["data/depth"].dtype == np.uint16 and back.root["data/depth"].shape == (17, 96, 128)
    assert json.loads(str(back.root["meta/randomisation"][1]))["seed"] == 1


def test_interrupted_append_is_cut_back_on_resume(tmp_path, monkeypatch) -> None:
    store = _create(tmp_path / "d.zarr")
    store.append(_episode(4, 0))
    array_type = type(store.root["meta/episode_ends"])
    original = array_type.append

    class Crash(RuntimeError):
        pass

    def crash(self, *args, **kwargs):  # dies after data/ and meta/ were appended, before episode_ends
        if self.path.endswith("episode_ends"):
            raise Crash
        return original(self, *args, **kwargs)

    monkeypatch.setattr(array_type, "append", crash, raising=True)
    with pytest.raises(Crash):
        store.append(_episode(6, 1))
    monkeypatch.undo()
    assert store.root["data/depth"].shape[0] == 10  # the partial episode is on disk ...
    resumed = DemoStore.create(tmp_path / "d.zarr", spec=DepthSpec(), action_scale=0.05, control_rate_hz=10.0)
    assert resumed.n_episodes == 1 and resumed.root["data/depth"].shape[0] == 4  # ... and cut on reopen
    assert resumed.root["meta/kind"].shape[0] == 1
    resumed.append(_episode(2, 2))
    np.testing.assert_array_equal(DemoStore.open(tmp_path / "d.zarr").episode_ends, [4, 6])


def test_unwritable_and_missing_paths_are_clear_errors(tmp_path) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("x")
    with pytest.raises(DatasetError, match="cannot write a demo store"):
        _create(blocker / "d.zarr")
    with pytest.raises(DatasetError, match="no demo store"):
        DemoStore.open(tmp_path / "absent.zarr")


def test_mismatched_episode_is_rejected(tmp_path) -> None:
    store = _create(tmp_path / "d.zarr")
    ep = _episode(4, 0)
    bad = dataclasses.replace(ep, state=ep.state[:3])
    with pytest.raises(DatasetError, match="state has 3 steps"):
        store.append(bad)
    with pytest.raises(IndexError):
        store.episode_slice(0)


def test_store_appears_only_complete(tmp_path, monkeypatch) -> None:
    """A kill during creation leaves no half-made store under the final name; the next run starts clean."""
    path = tmp_path / "d.zarr"

    class Crash(RuntimeError):
        pass

    def crash(*args, **kwargs):
        raise Crash

    monkeypatch.setattr(zarr.Group, "create_array", crash)
    with pytest.raises(Crash):
        _create(path)
    monkeypatch.undo()
    assert not path.exists() and (tmp_path / "d.zarr.creating").exists()
    with pytest.raises(DatasetError, match="no demo store"):
        DemoStore.open(path)
    store = _create(path)
    store.append(_episode(3, 0))
    assert DemoStore.open(path).n_episodes == 1 and not (tmp_path / "d.zarr.creating").exists()
    assert zarr.open_group(str(path), mode="r")["meta/episode_ends"].shape == (1,)


def _old_store(path) -> None:
    """A store as main wrote it before DemoStore owned the DDG record (collect --sensor, then 2 of 3 chunks of
    ``ddg generate --chunk 4``), spelled out array by array: the on-disk names are the contract."""
    root = zarr.open_group(str(path), mode="w")
    depth = np.arange(10 * 96 * 128, dtype=np.uint16).reshape(10, 96, 128)
    for name, value in (("depth", depth), ("depth_sensor", depth // 2), ("depth_ddg", depth + 1),
                        ("depth_ddg_nograft", depth + 2), ("state", np.zeros((10, 8), np.float32)),
                        ("action", np.zeros((10, 8), np.float32))):
        root.create_array(f"data/{name}", shape=value.shape, dtype=value.dtype)[:] = value
    root["data/depth_ddg"][8:] = 0  # the chunk no shard has reached
    root.create_array("meta/ddg_done", shape=(3,), dtype="bool", chunks=(1,))[:] = [True, True, False]
    root.create_array("meta/episode_ends", shape=(2,), dtype=np.int64)[:] = [6, 10]
    root.attrs.update({"depth_spec": DepthSpec().to_dict(), "action_scale": 0.05, "control_rate_hz": 10.0,
                       "depth_scale": 0.001, "attempted": 2, "succeeded": 2, "failed": 0, "sensor": "stereo",
                       "ddg": {"model": "m", "steps": 2, "seed": 0, "chunk": 4}})


def test_an_old_store_opens_and_reports_its_depth_sources_and_what_was_generated(tmp_path) -> None:
    _old_store(tmp_path / "old.zarr")
    store = DemoStore.open(tmp_path / "old.zarr")
    assert store.n_episodes == 2 and store.n_steps == 10 and store.attrs["sensor"] == "stereo"
    assert store.depth_sources == ["gt", "randnoise", "ddg", "ddg_nograft", "sensor"]
    assert store.generated_with("ddg") == {"model": "m", "steps": 2, "seed": 0, "chunk": 4}
    clean = store.root["data/depth"][:]
    np.testing.assert_array_equal(store.depth("sensor", 10), clean // 2)
    np.testing.assert_array_equal(store.depth("ddg", 6), clean[:6] + 1)  # episode 0: chunks 0 and 1, made
    with pytest.raises(DatasetError, match=r"1 of the 3 chunks \(4 frames each\) .* \(first: chunk 2\)"):
        store.depth("ddg", 10)
    with pytest.raises(DatasetError, match="unknown depth source 'sharpie'"):
        store.depth("sharpie", 10)


def test_a_store_names_the_command_that_makes_a_depth_source_it_lacks(tmp_path) -> None:
    store = _create(tmp_path / "d.zarr")
    store.append(_episode(4, 0))
    assert store.depth_sources == ["gt", "randnoise"] and store.generated_with("ddg") is None
    with pytest.raises(DatasetError, match=r"has no data/depth_ddg for depth source 'ddg' \(make it with "
                                           r"`python -m trainer ddg generate`\); it holds gt, randnoise"):
        store.depth("ddg", 4)


def test_a_store_that_drove_on_a_generated_source_holds_that_sources_frames_as_its_sensors(tmp_path) -> None:
    """A DAgger round under ``--sensor residual_edges:steps=5`` keeps what the learner saw as
    data/depth_sensor; a fit on ``residual_edges`` frames reads those, as it reads a generator's array in an
    expert's store."""
    from trainer.student.steps import _frames, depth_arrays

    drove = DemoStore.create(tmp_path / "drove.zarr", spec=DepthSpec(), action_scale=0.05,
                             control_rate_hz=10.0, sensor="residual_edges:steps=5")
    episode = _episode(3, 0)
    drove.append(dataclasses.replace(episode, depth_sensor=episode.depth // 3))
    assert drove.depth_sources == ["gt", "randnoise", "sensor", "residual_edges"]
    np.testing.assert_array_equal(drove.depth("residual_edges", 3), episode.depth // 3)
    with pytest.raises(DatasetError, match="no data/depth_residual for depth source 'residual'"):
        drove.depth("residual", 3)  # the residual diffusion without the edge graft is another source
    expert = _create(tmp_path / "expert.zarr")
    expert.append(_episode(5, 1))
    settings = {"model": "m", "steps": 5, "seed": 0, "chunk": 8}
    outs, done = expert.generation_outputs("residual_edges", settings, chunk=8)
    outs["residual_edges"][:] = expert.root["data/depth"][:] + 1
    done[:] = True
    stores = [expert, drove]
    both = _frames(stores, depth_arrays(stores, "residual_edges"), None)
    np.testing.assert_array_equal(both, np.concatenate([_episode(5, 1).depth + 1, episode.depth // 3]))
    np.testing.assert_array_equal(_frames(stores, depth_arrays(stores, "gt"), None),
                                  np.concatenate([_episode(5, 1).depth, episode.depth]))


def test_generated_depth_grows_with_the_store_and_makes_its_partial_chunk_again(tmp_path) -> None:
    store = _create(tmp_path / "d.zarr")
    store.append(_episode(6, 0))
    settings = {"model": "m", "steps": 2, "seed": 0, "chunk": 4}
    outs, done = store.generation_outputs("ddg", settings, chunk=4)
    assert set(outs) == {"ddg", "ddg_nograft"} and outs["ddg"].shape == (6, 96, 128) and done.shape == (2,)
    assert outs["ddg"].chunks == (4, 96, 128) and store.generated_with("ddg") == settings
    done[:] = True
    store.append(_episode(5, 1))  # collect resumed: frames 6..10 are new, chunk 1 ([4, 8)) is partly new
    outs, done = store.generation_outputs("ddg", settings, chunk=4)
    assert outs["ddg_nograft"].shape == (11, 96, 128) and done[:].tolist() == [True, False, False]
    store.drop_generated("ddg")
    assert store.depth_sources == ["gt", "randnoise"] and store.generated_with("ddg") is None
    assert "ddg_done" not in store.root["meta"]
