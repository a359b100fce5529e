import json
import time
from pathlib import Path

import numpy as np
import pytest
import zmq

from runtime.cameras import open_camera
from runtime.cameras.base import CameraEnded, CameraError, StreamMismatch
from runtime.preprocess import DepthSpec
from runtime.protocol import Encoder
from tests.runtime.fakes import free_port_pair

REPO = Path(__file__).resolve().parents[2]
BAG = REPO.parent / "shared/data/realsense_bags/single_depth_color_640x480.bag"
SPEC = DepthSpec()


def _frames(n: int, h: int = 480, w: int = 848) -> np.ndarray:
    return (np.arange(n, dtype=np.uint16)[:, None, None] * 100 + 500 + np.zeros((n, h, w), np.uint16))


def _drain(camera) -> list:
    got = []
    with pytest.raises(CameraEnded):
        while True:
            if (frame := camera.poll(0.5)) is not None:
                got.append(frame)
    return got


def test_replay_npz_plays_every_frame_at_its_rate(tmp_path):
    path = tmp_path / "rec.npz"
    np.savez(path, depth=_frames(4), depth_scale=0.00025, fps=20.0)
    camera = open_camera(f"replay:{path}", SPEC)
    got = _drain(camera)
    assert [f.number for f in got] == [0, 1, 2, 3] and camera.period_s == 0.05
    assert [int(f.depth[0, 0]) for f in got] == [500, 600, 700, 800] and got[0].depth_scale == 0.00025
    np.testing.assert_allclose(np.diff([f.t_capture for f in got]), 0.05, atol=1e-9)
    assert all(f.t_capture <= f.t_receive for f in got)


def test_replay_folder_with_meta(tmp_path):
    for i, frame in enumerate(_frames(3)):
        np.save(tmp_path / f"{i:04d}.npy", frame)
    (tmp_path / "meta.json").write_text(json.dumps({"fps": 50, "depth_scale": 0.001}))
    got = _drain(open_camera(f"replay:{tmp_path}", SPEC))
    assert [int(f.depth[0, 0]) for f in got] == [500, 600, 700]


def test_replay_skips_frames_a_slow_reader_missed(tmp_path):
    path = tmp_path / "rec.npz"
    np.savez(path, depth=_frames(10), fps=100.0)
    camera = open_camera(f"replay:{path}", SPEC)
    assert camera.poll(0.1).number == 0
    time.sleep(0.055)
    assert camera.poll(0.1).number >= 5  # newest only, no backlog


@pytest.mark.parametrize("write, error, match", [
    (lambda p: np.savez(p, depth=_frames(2).astype(np.float32)), CameraError, "uint16"),
    (lambda p: np.savez(p, other=_frames(2)), CameraError, "'depth' array"),
    (lambda p: np.savez(p, depth=_frames(2, 480, 640)), StreamMismatch, "640x480 .* 848x480"),
    (lambda p: p.write_bytes(b"junk"), CameraError, "not a readable .npz"),
])
def test_bad_replay_files_are_named(tmp_path, write, error, match):
    path = tmp_path / "rec.npz"
    write(path)
    with pytest.raises(error, match=match):
        open_camera(f"replay:{path}", SPEC)


def test_unknown_camera_is_named():
    with pytest.raises(CameraError, match="unknown camera 'usb3'"):
        open_camera("usb3", SPEC)


def test_hil_camera_takes_newest_and_refuses_a_wrong_size():
    ctx = zmq.Context.instance()
    address = f"tcp://127.0.0.1:{free_port_pair()}"
    pub, enc = ctx.socket(zmq.PUB), Encoder()
    pub.linger = 0
    pub.bind(address)
    camera = open_camera(f"hil:{address}", SPEC, period_s=0.05)
    frame, i = None, 0
    while frame is None:  # slow joiner
        pub.send_multipart(enc.depth(_frames(1)[0], t_capture=time.monotonic(), frame_number=i,
                                     depth_scale=0.001))
        frame, i = camera.poll(0.05), i + 1
    assert frame.depth.shape == (480, 848) and frame.t_capture <= frame.t_receive
    pub.send_multipart(enc.depth(_frames(1, 480, 640)[0], t_capture=time.monotonic(), frame_number=i,
                                 depth_scale=0.001))
    with pytest.raises(StreamMismatch, match="640x480 depth but the policy expects 848x480"):
        camera.poll(1.0)
    camera.close()
    pub.close()


def test_the_640x480_recording_drives_the_shipped_policy():
    """The one real recording (a D435, 640x480) through the d455 reader, preprocessing, the shipped file."""
    pytest.importorskip("pyrealsense2")
    from runtime.policy import Policy
    from runtime.preprocess import FrameStack, preprocess

    camera = open_camera(f"d455:{BAG}", SPEC)
    frame = _drain(camera)[0]
    camera.close()
    policy = Policy(REPO / "models" / "student.onnx")
    spec = policy.metadata.preprocess
    depth = preprocess(frame.depth, frame.depth_scale, spec)
    assert depth.shape == (spec.out_height, spec.out_width) and (depth == spec.invalid_value).mean() < 0.1
    stack = FrameStack(policy.metadata.obs_horizon).push(depth)
    actions = policy(stack, np.zeros(policy.metadata.state_dim, np.float32))
    assert actions.shape == (policy.metadata.action_horizon, 8) and np.isfinite(actions).all()


def test_d455_bag_plays_every_frame_with_device_scale_and_timestamps(capsys):
    pytest.importorskip("pyrealsense2")
    camera = open_camera(f"d455:{BAG}", SPEC)
    err = capsys.readouterr().err
    assert "D435 recording" in err  # D400 family accepted in playback, with a warning
    assert "streams 640x480: mapped onto the policy's 848x480 view by its intrinsics" in err
    got = _drain(camera)
    camera.close()
    assert [f.number for f in got] == [169, 170]  # the recording's own frame counter
    top, left = SPEC.centred_window()
    for frame in got:
        assert frame.depth.dtype == np.uint16 and frame.depth.shape == (480, 848)
        assert frame.depth_scale == pytest.approx(0.001)
        crop = frame.depth[top:top + SPEC.crop_height, left:left + SPEC.crop_width]
        assert (crop == 0).mean() == pytest.approx(0.025, abs=0.01)  # the recording's holes, not its edges
        assert frame.t_capture <= frame.t_receive
    assert got[1].t_device - got[0].t_device == pytest.approx(0.1667, abs=0.002)  # device clock, 6 fps


def test_a_bag_given_to_replay_is_pointed_at_the_d455_reader():
    with pytest.raises(CameraError, match=r"replay:rec.bag: .bag recordings play as a camera: use --camera "
                                          r"d455:rec.bag"):
        open_camera("replay:rec.bag", SPEC)


def test_d455_missing_recording_is_named():
    pytest.importorskip("pyrealsense2")
    with pytest.raises(CameraError, match="no such recording"):
        open_camera("d455:/nowhere/rec.bag", SPEC)
