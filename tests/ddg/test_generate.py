import shutil
from dataclasses import replace

import numpy as np
import pytest
import zarr

from runtime.preprocess import DepthSpec
from tests.conftest import write_synthetic_demos
from trainer.ddg.generate import DemoStoreError, GenerateConfig, generate
from trainer.ddg.sample import FrameError
from trainer.student.data import DemoDataError, DemoDataset


def _run(store, model, **kw):
    settings = {"demos": str(store), "model": str(model), "steps": 2, "batch": 4, "chunk": 8}
    return generate(GenerateConfig(**{**settings, **kw}))


def test_generate_adds_both_arrays_with_grafted_geometry(tiny_demos, tiny_model):
    stats = _run(tiny_demos, tiny_model)
    root = zarr.open_group(str(tiny_demos), mode="r")
    sim, ddg, nog = (np.asarray(root[f"data/{k}"]) for k in ("depth", "depth_ddg", "depth_ddg_nograft"))
    assert stats["frames"] == 20 and ddg.shape == sim.shape == nog.shape and ddg.dtype == np.uint16
    keep = ddg > 0
    assert np.array_equal(ddg[keep], sim[keep])
    assert np.array_equal(ddg == 0, (nog == 0) | (sim < 300))
    assert np.all(np.asarray(root["meta/ddg_done"]))


def test_shards_cover_the_store_and_match_a_single_run(tiny_demos, tiny_model, tmp_path):
    copy = tmp_path / "copy.zarr"
    shutil.copytree(tiny_demos, copy)
    _run(tiny_demos, tiny_model)
    assert _run(copy, tiny_model, shard="1/2")["frames"] == 8  # chunk 1 of [0..8), [8..16), [16..20)
    assert _run(copy, tiny_model, shard="0/2")["frames"] == 12
    a, b = zarr.open_group(str(tiny_demos), mode="r"), zarr.open_group(str(copy), mode="r")
    assert np.array_equal(np.asarray(a["data/depth_ddg"]), np.asarray(b["data/depth_ddg"]))


def test_students_refuse_ddg_depth_no_shard_has_reached(tiny_model, tmp_path):
    """Chunks not generated yet hold zeros: a student trains only on episodes whose chunks are all done."""
    demos = write_synthetic_demos(tmp_path / "demos.zarr")  # 2 x 12 steps: chunks [0, 8), [8, 16), [16, 24)
    _run(demos, tiny_model, shard="0/3")
    with pytest.raises(DemoDataError, match=r"1 of the 2 chunks \(8 frames each\) .* not generated yet "
                                            r"\(first: chunk 1\)"):
        DemoDataset(demos, "ddg", 3, 16, episodes=1)
    _run(demos, tiny_model, shard="1/3")
    assert len(DemoDataset(demos, "ddg_nograft", 3, 16, episodes=1)) == 12
    with pytest.raises(DemoDataError, match="chunk 2"):
        DemoDataset(demos, "ddg", 3, 16)
    assert len(DemoDataset(demos, "gt", 3, 16)) == 24  # the simulated depth is always whole
    _run(demos, tiny_model)
    root = zarr.open_group(str(demos), mode="r+")
    root["data/depth_ddg"].resize((20, 96, 128))  # as if collect had appended 4 frames since
    with pytest.raises(DemoDataError, match="holds 20 frames, the episodes 24: the store grew"):
        DemoDataset(demos, "ddg", 3, 16)


def test_outputs_are_created_under_the_stores_lock(tiny_demos, tiny_model, monkeypatch):
    """Shards started at the same moment must not each create the output arrays: another process cannot take
    the lock while one creates them (it blocks until then), and the store still opens as zarr."""
    import fcntl

    import trainer.ddg.generate as gen

    create, held = gen._outputs, []

    def outputs_while_another_tries(*args):
        with open(tiny_demos / gen.LOCK_NAME) as other:  # another open file: as another process
            try:
                fcntl.flock(other, fcntl.LOCK_EX | fcntl.LOCK_NB)
                held.append(False)
            except BlockingIOError:
                held.append(True)
        return create(*args)

    monkeypatch.setattr(gen, "_outputs", outputs_while_another_tries)
    assert _run(tiny_demos, tiny_model)["frames"] == 20
    assert held == [True]
    assert np.all(np.asarray(zarr.open_group(str(tiny_demos), mode="r")["meta/ddg_done"]))


def test_resume_skips_finished_chunks(tiny_demos, tiny_model):
    _run(tiny_demos, tiny_model, shard="0/2")
    assert _run(tiny_demos, tiny_model)["frames"] == 8
    assert _run(tiny_demos, tiny_model)["frames"] == 0


def test_resume_with_other_settings_is_refused(tiny_demos, tiny_model):
    _run(tiny_demos, tiny_model)
    assert "eta" not in zarr.open_group(str(tiny_demos), mode="r").attrs["ddg"]  # older stores still resume
    for other in ({"steps": 5}, {"steps": 2, "eta": 1.0}):
        with pytest.raises(DemoStoreError, match="already holds ddg depth"):
            generate(GenerateConfig(demos=str(tiny_demos), model=str(tiny_model), chunk=8, **other))


def test_replace_drops_other_settings_depth_and_matches_a_fresh_run(tiny_demos, tiny_model, tmp_path):
    """A copy of a store that already holds one generator's depth gets another's with --replace: every chunk
    made again, nothing of the old depth left, the same result as a store that never held any."""
    fresh = tmp_path / "fresh.zarr"
    shutil.copytree(tiny_demos, fresh)
    _run(tiny_demos, tiny_model, steps=1)
    _run(tiny_demos, tiny_model, shard="0/2", replace=True)  # a shard may stop half way and resume
    assert zarr.open_group(str(tiny_demos), mode="r").attrs["ddg"]["steps"] == 2
    assert _run(tiny_demos, tiny_model, replace=True)["frames"] == 8  # same settings now: resumes
    _run(fresh, tiny_model)
    a, b = zarr.open_group(str(tiny_demos), mode="r"), zarr.open_group(str(fresh), mode="r")
    for name in ("data/depth_ddg", "data/depth_ddg_nograft", "meta/ddg_done"):
        np.testing.assert_array_equal(np.asarray(a[name]), np.asarray(b[name]))


def test_episodes_limits_the_work_to_the_chunks_they_span(tiny_demos, tiny_model):
    assert _run(tiny_demos, tiny_model, episodes=1)["frames"] == 16  # episode 0 is frames [0, 10): 2 chunks
    done = np.asarray(zarr.open_group(str(tiny_demos), mode="r")["meta/ddg_done"])
    assert done.tolist() == [True, True, False]
    assert _run(tiny_demos, tiny_model)["frames"] == 4  # the rest on the next run
    shutil.rmtree(tiny_demos / "data" / "depth_ddg")
    with pytest.raises(DemoStoreError, match="--episodes 3: the store holds 2 episodes"):
        _run(tiny_demos, tiny_model, episodes=3)
    assert "depth_ddg" not in zarr.open_group(str(tiny_demos), mode="r")["data"]  # refused before any work


def test_a_store_at_a_finer_resolution_of_the_crop_gets_ddg_depth_at_its_own(tiny_model, tmp_path):
    spec = replace(DepthSpec(), out_height=144, out_width=192)
    demos = write_synthetic_demos(tmp_path / "fine.zarr", spec=spec)
    _run(demos, tiny_model)
    root = zarr.open_group(str(demos), mode="r")
    sim, ddg = np.asarray(root["data/depth"]), np.asarray(root["data/depth_ddg"])
    assert ddg.shape == sim.shape == (24, 144, 192)
    assert np.array_equal(ddg[ddg > 0], sim[ddg > 0])


def test_bad_stores_and_shards(tmp_path, tiny_model):
    with pytest.raises(DemoStoreError, match="no demo store"):
        _run(tmp_path / "nope.zarr", tiny_model)
    zarr.open_group(str(tmp_path / "empty.zarr"), mode="w")
    with pytest.raises(DemoStoreError, match="no data/depth"):
        _run(tmp_path / "empty.zarr", tiny_model)
    with pytest.raises(DemoStoreError, match="i/n"):
        GenerateConfig(shard="2").shard_pair()
    with pytest.raises(DemoStoreError, match="0 <= i < n"):
        GenerateConfig(shard="3/2").shard_pair()


def test_store_at_another_resolution_is_refused_before_any_work(tmp_path, tiny_model):
    root = zarr.open_group(str(tmp_path / "big.zarr"), mode="w")
    root.create_array("data/depth", shape=(4, 120, 160), dtype="uint16")[:] = 900
    with pytest.raises(FrameError, match=r"\[N, 96, 128\] \(the model's resolution\), got uint16 \[4, 120"):
        _run(tmp_path / "big.zarr", tiny_model)
    assert "data/depth_ddg" not in zarr.open_group(str(tmp_path / "big.zarr"), mode="r")


def test_a_store_that_grew_gets_its_new_frames_and_keeps_the_old(tiny_demos, tiny_model, tmp_path):
    """collect resumed into a store after generation: the next run fills only the new frames (and the old
    partial last chunk again, identically), ending where a single run over the grown store ends."""
    root = zarr.open_group(str(tiny_demos), mode="r+")
    full = np.asarray(root["data/depth"])
    whole = tmp_path / "whole.zarr"
    shutil.copytree(tiny_demos, whole)
    _run(whole, tiny_model)
    root["data/depth"].resize((12, *full.shape[1:]))  # the store as it was before its last 8 frames
    assert _run(tiny_demos, tiny_model)["frames"] == 12
    root["data/depth"].resize(full.shape)
    root["data/depth"][12:] = full[12:]
    assert _run(tiny_demos, tiny_model)["frames"] == 12  # chunk [8, 16) again, then [16, 20)
    grown, single = zarr.open_group(str(tiny_demos), mode="r"), zarr.open_group(str(whole), mode="r")
    for name in ("data/depth_ddg", "data/depth_ddg_nograft", "meta/ddg_done"):
        np.testing.assert_array_equal(np.asarray(grown[name]), np.asarray(single[name]))
