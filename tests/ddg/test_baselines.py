import numpy as np
import pytest

from trainer.ddg.baselines import (
    SOURCES,
    UnknownSourceError,
    get_source,
    gt,
    inpaint,
    parse_sensor_arg,
    randnoise,
)
from trainer.ddg.sample import FrameError

from .conftest import scene


@pytest.fixture
def clean():
    return scene(np.random.default_rng(0))


def test_gt_is_the_clean_depth(clean):
    out = gt(clean, np.random.default_rng(0))
    assert np.array_equal(out, clean) and out is not clean


def test_randnoise_adds_holes_and_noise_reproducibly(clean):
    a, b = randnoise(clean, np.random.default_rng(3)), randnoise(clean, np.random.default_rng(3))
    assert np.array_equal(a, b) and a.dtype == np.uint16
    assert 0 < (a == 0).mean() < 0.5
    valid = a > 0
    assert np.abs(a[valid].astype(int) - clean[valid]).max() < 30


def test_inpaint_fills_every_hole(clean):
    holed = clean.copy()
    holed[20:30, 20:40] = 0
    out = inpaint(holed, np.random.default_rng(0))
    assert (out > 0).all()
    assert np.abs(out[20:30, 20:40].astype(int) - clean[20:30, 20:40]).mean() < 60


def test_registry_names_and_errors(tiny_model, clean):
    assert set(SOURCES) == {"gt", "randnoise", "inpaint", "ddg_nograft", "ddg", "residual", "residual_edges"}
    with pytest.raises(UnknownSourceError, match="unknown depth source 'kinect'"):
        get_source("kinect")
    out = get_source("ddg", model=tiny_model, steps=2)(clean, np.random.default_rng(0))
    assert out.shape == clean.shape and out.dtype == np.uint16
    keep = out > 0
    assert np.array_equal(out[keep], clean[keep])  # grafted: every kept pixel is the sim's


def test_ddg_source_takes_a_finer_students_frames(tiny_model):
    """A 192x144 frame of the same crop gets the holes of a generator told its spec, and keeps its own depth
    elsewhere (it is not the 128x96 frame's copy)."""
    from dataclasses import replace

    from trainer.ddg.sample import Generator

    fine = scene(np.random.default_rng(1), 144, 192)
    fine[::2, ::2] += 1  # detail a 128x96 copy cannot carry
    source = get_source("ddg", model=tiny_model, steps=2)
    out = source(fine, np.random.default_rng(5))
    index = np.array([np.random.default_rng(5).integers(0, 2**62)])
    spec = replace(source.generator.spec, out_height=144, out_width=192)
    told = Generator(tiny_model, steps=2, frames=spec)
    assert np.array_equal(out, told(fine[None], index)[0][0])
    keep = out > 0
    assert out.shape == (144, 192) and keep.any() and np.array_equal(out[keep], fine[keep])
    with pytest.raises(FrameError, match=r"\[N, 96, 128\] \(the model's resolution\)"):
        source(fine[None], np.random.default_rng(5))


def test_sources_plug_into_the_evaluation_sensors():
    import trainer.ddg.baselines  # noqa: F401  (registers the sources)
    from trainer.sim.sensors import make_sensor

    sensor = make_sensor("randnoise")
    d = np.full((96, 128), 900, np.uint16)
    assert sensor(d).shape == d.shape


def test_ddg_sensor_takes_model_and_steps(tiny_model, clean):
    from trainer.sim.sensors import make_sensor

    assert parse_sensor_arg("ddg", f"model={tiny_model},steps=2") == {"model": str(tiny_model), "steps": 2}
    assert parse_sensor_arg("ddg", str(tiny_model)) == {"model": str(tiny_model)}
    assert parse_sensor_arg("ddg", "") == {}
    for bad in ("steps=0", "steps=five", "speed=3"):
        with pytest.raises(UnknownSourceError, match="expected model=DIR or steps=K"):
            parse_sensor_arg("ddg", bad)
    out = make_sensor(f"ddg:model={tiny_model},steps=2")(clean)
    assert out.shape == clean.shape and out.dtype == np.uint16
