import numpy as np
import pytest

from runtime.preprocess import (
    TRAINED_STREAM,
    DepthSpec,
    FrameStack,
    PreprocessError,
    StreamIntrinsics,
    crop_resize,
    match_stream,
    normalise,
    preprocess,
    restore_holes,
    trained_stream,
)

SPEC = DepthSpec()


def _frame(seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    frame = rng.integers(200, 2500, size=(SPEC.stream_height, SPEC.stream_width)).astype(np.uint16)
    frame[rng.random(frame.shape) < 0.1] = 0
    return frame


def test_two_step_path_equals_one_step_bit_exact():
    raw = _frame()
    two_step = normalise(crop_resize(raw, SPEC), 0.001, SPEC)
    np.testing.assert_array_equal(preprocess(raw, 0.001, SPEC), two_step)


def test_restored_path_equals_the_steps_and_the_trainers_inpaint_source():
    from trainer.ddg.baselines import inpaint  # what Table I and `--sensor inpaint` apply

    raw = _frame()
    small = crop_resize(raw, SPEC)
    trainer_side = normalise(inpaint(small, np.random.default_rng(0)), 0.001, SPEC)
    np.testing.assert_array_equal(preprocess(raw, 0.001, SPEC, restore="inpaint"), trainer_side)
    np.testing.assert_array_equal(preprocess(raw, 0.001, SPEC, restore="none"), preprocess(raw, 0.001, SPEC))


def test_inpaint_fills_holes_from_their_surroundings_and_keeps_measured_pixels():
    depth = np.full((96, 128), 800, np.uint16)
    depth[:, 64:] = 1200
    depth[40:50, 20:30] = 0  # inside the 800 mm half
    depth[40:50, 95:105] = 0  # inside the 1200 mm half
    out = restore_holes(depth, "inpaint")
    assert out.dtype == np.uint16 and not (out == 0).any()
    np.testing.assert_array_equal(out[depth > 0], depth[depth > 0])
    assert set(np.unique(out[40:50, 20:30])) == {800} and set(np.unique(out[40:50, 95:105])) == {1200}


def test_restore_leaves_hole_free_and_all_hole_frames_and_names_unknown_methods():
    full = np.full((4, 5), 900, np.uint16)
    empty = np.zeros((4, 5), np.uint16)
    np.testing.assert_array_equal(restore_holes(full, "inpaint"), full)
    np.testing.assert_array_equal(restore_holes(empty, "inpaint"), empty)
    with pytest.raises(PreprocessError, match="unknown hole restoration 'median'"):
        restore_holes(full, "median")


def test_shape_dtype_and_range():
    out = preprocess(_frame(), 0.001, SPEC)
    assert out.shape == (SPEC.out_height, SPEC.out_width) and out.dtype == np.float32
    valid = out[out != SPEC.invalid_value]
    assert valid.min() >= 0.0 and valid.max() <= 1.0


def test_holes_stay_holes_and_never_blend():
    raw = np.full((SPEC.stream_height, SPEC.stream_width), 900, np.uint16)
    raw[::2, ::2] = 0  # dense holes: any averaging resizer would produce values between 0 and 900
    small = crop_resize(raw, SPEC)
    assert set(np.unique(small)) <= {0, 900}


def test_metric_mapping_and_clipping():
    raw = np.zeros((SPEC.stream_height, SPEC.stream_width), np.uint16)
    raw[:, :300] = 100    # 0.1 m: nearer than near_m -> clipped to 0
    raw[:, 300:600] = 900  # 0.9 m -> (0.9-0.3)/1.2 = 0.5
    raw[:, 600:] = 5000   # 5 m: farther than far_m -> clipped to 1
    out = preprocess(raw, 0.001, SPEC, window=(0, 0))
    assert out[0, 0] == 0.0
    cols = np.round((np.arange(SPEC.out_width) + 0.5) * SPEC.crop_width / SPEC.out_width - 0.5)
    mid = int(np.argmax(cols >= 310))
    assert out[0, mid] == pytest.approx(0.5, abs=1e-6)


def test_crop_window_moves_the_view():
    raw = np.zeros((SPEC.stream_height, SPEC.stream_width), np.uint16)
    raw[:, 500:] = 1000
    left = crop_resize(raw, SPEC, window=(0, 0))
    right = crop_resize(raw, SPEC, window=(0, SPEC.stream_width - SPEC.crop_width))
    assert (left == 0).all() and (right != 0).any()


@pytest.mark.parametrize("bad", [np.zeros((480, 848), np.float32), np.zeros((480, 848, 1), np.uint16),
                                 np.zeros((100, 100), np.uint16)])
def test_bad_frames_named_in_error(bad):
    with pytest.raises(PreprocessError):
        preprocess(bad, 0.001, SPEC)


def test_bad_scale_and_spec():
    with pytest.raises(PreprocessError, match="depth_scale"):
        normalise(np.zeros((4, 4), np.uint16), 0.0, SPEC)
    with pytest.raises(PreprocessError, match="near_m"):
        DepthSpec(near_m=2.0, far_m=1.0)
    with pytest.raises(PreprocessError, match="unknown"):
        DepthSpec.from_dict({"bogus": 1})


def test_frame_stack_fills_then_rolls_oldest_first():
    stack = FrameStack(3)
    a, b, c, d = (np.full((2, 2), v, np.float32) for v in range(4))
    assert stack.push(a)[:, 0, 0].tolist() == [0, 0, 0]
    stack.push(b)
    stack.push(c)
    assert stack.push(d)[:, 0, 0].tolist() == [1, 2, 3]
    stack.reset()
    assert stack.push(d)[:, 0, 0].tolist() == [3, 3, 3]



def _scene(stream: StreamIntrinsics) -> np.ndarray:
    """One scene seen through ``stream``'s intrinsics, uint16 mm: a tilted table, a box on it (sharp edges)
    and a hole, each a function of the ray alone, so that every stream mode sees the same scene."""
    x = (np.arange(stream.width) - stream.cx) / stream.fx
    y = ((np.arange(stream.height) - stream.cy) / stream.fy)[:, None]
    depth = 900.0 + 300.0 * y + 200.0 * x
    depth = np.where((np.abs(x - 0.05) < 0.12) & (np.abs(y + 0.02) < 0.09), 760.0, depth)
    depth[(np.abs(x + 0.2) < 0.03) & (np.abs(y - 0.1) < 0.03)] = 0  # no data
    return depth.astype(np.uint16)


OTHER_MODES = {
    # a D455's 1280x720: 848x480's field of view at 1.5x the pixels (pixel centres scale about -0.5)
    "1280x720": StreamIntrinsics(1280, 720, 424.51 * 1.5, 424.24 * 1.5, 415.71 * 1.5 + 0.25,
                                 249.80 * 1.5 + 0.25),
    # the shipped D435 recording's 640x480: another focal length and principal point
    "640x480": StreamIntrinsics(640, 480, 390.43, 390.43, 331.39, 242.19)}


@pytest.mark.parametrize("mode", sorted(OTHER_MODES))
def test_other_stream_modes_give_the_native_frame_policy_input(mode):
    spec, other = DepthSpec(), OTHER_MODES[mode]
    native = trained_stream(spec)
    want = preprocess(_scene(native), 0.001, spec)
    got = preprocess(match_stream(_scene(other), other, native), 0.001, spec)
    # a centred crop by pixels of the other mode: a different field of view
    top, left = (other.height - native.height) // 2, (other.width - native.width) // 2
    padded = np.pad(_scene(other), ((max(0, -top),) * 2, (max(0, -left),) * 2))
    naive = preprocess(padded[max(0, top):max(0, top) + 480, max(0, left):max(0, left) + 848], 0.001, spec)
    off = (np.abs(got - want) > 0.01).mean()  # > 1.2 cm: only edge pixels may sample the other side
    assert off < 0.03
    assert (np.abs(naive - want) > 0.01).mean() > 5 * off  # the comparison can tell a wrong field of view


def test_the_native_stream_is_left_untouched():
    native = trained_stream(DepthSpec())
    frame = _scene(native)
    assert native == TRAINED_STREAM and match_stream(frame, native, native) is frame


def test_the_trained_stream_is_hil_sims_d455():
    from hil_sim.camera import Intrinsics

    d455 = Intrinsics()
    assert TRAINED_STREAM == StreamIntrinsics(d455.width, d455.height, d455.fx, d455.fy, d455.cx, d455.cy)
