import json
import time
from pathlib import Path

import numpy as np
import pytest
import zmq

from runtime.cameras import CameraEnded, CameraError, StreamMismatch, open_camera
from runtime.preprocess import DepthSpec
from runtime.protocol import Encoder
from tests.runtime.fakes import free_port_pair

BAG = Path(__file__).resolve().parents[2].parent / "shared/data/realsense_bags/single_depth_color_640x480.bag"
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


def test_d455_bag_of_another_size_is_refused_naming_both_sizes():
    pytest.importorskip("pyrealsense2")
    with pytest.raises(StreamMismatch, match="streams 640x480 depth but the policy expects 848x480"):
        open_camera(f"d455:{BAG}", SPEC)


def test_d455_bag_plays_every_frame_with_device_scale_and_timestamps(capsys):
    pytest.importorskip("pyrealsense2")
    camera = open_camera(f"d455:{BAG}", DepthSpec(stream_width=640, stream_height=480))
    assert "D435 recording" in capsys.readouterr().err  # D400 family accepted in playback, with a warning
    got = _drain(camera)
    camera.close()
    assert [f.number for f in got] == [169, 170]  # the recording's own frame counter
    for frame in got:
        assert frame.depth.dtype == np.uint16 and frame.depth.shape == (480, 640)
        assert frame.depth_scale == pytest.approx(0.001)
        assert (frame.depth == 0).mean() == pytest.approx(0.067, abs=0.001)
        assert frame.t_capture <= frame.t_receive
    assert got[1].t_device - got[0].t_device == pytest.approx(0.1667, abs=0.002)  # device clock, 6 fps


def test_d455_missing_recording_is_named():
    pytest.importorskip("pyrealsense2")
    with pytest.raises(CameraError, match="no such recording"):
        open_camera("d455:/nowhere/rec.bag", SPEC)
