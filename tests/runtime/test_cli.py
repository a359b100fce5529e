"""`runtime` as a real process on loopback, against a fake camera publisher and a fake driver."""

import json
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from tests.runtime import handmade
from tests.runtime.fakes import READY_Q, FakeWorld, free_port_pair

pytestmark = pytest.mark.hil
RATE = 20.0
FIELDS = {"tick", "deadline", "late", "cmd_seq", "t_capture", "t_receive", "t_preprocess", "t_inference",
          "t_send", "frame"}


_RUNNING: list[subprocess.Popen] = []


@pytest.fixture(autouse=True)
def _no_orphans():
    """Kill any runtime a failed test left running."""
    yield
    while _RUNNING:
        proc = _RUNNING.pop()
        if proc.poll() is None:
            proc.kill()
            proc.wait(5)


def _start(model, world: FakeWorld, *extra: str) -> subprocess.Popen:
    argv = ["--model", str(model), "--camera", f"hil:{world.camera}", "--robot", world.robot,
            "--rate", str(RATE), *extra]
    _RUNNING.append(subprocess.Popen([sys.executable, "-m", "runtime", *argv], stderr=subprocess.PIPE,
                                     text=True))
    return _RUNNING[-1]


def _assert_final_hold(commands: list[dict]) -> None:
    moving, final = commands[-2], commands[-1]
    np.testing.assert_allclose(moving["q_target"], READY_Q + handmade.DELTA, atol=1e-6)
    np.testing.assert_allclose(final["q_target"], READY_Q, atol=1e-9)
    assert final["gripper"] == moving["gripper"] == 1.0


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_signal_sends_hold_and_exits_zero(tmp_path, sig):
    model, metrics = handmade.build(tmp_path / "s.onnx"), tmp_path / "metrics.jsonl"
    with FakeWorld(RATE) as world:
        proc = _start(model, world, "--metrics", str(metrics))
        world.wait_commands(10)
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=10)
        time.sleep(0.2)
        assert proc.returncode == 0, err
        _assert_final_hold(world.commands)
    ticks = [json.loads(line) for line in metrics.read_text().splitlines()]
    assert len(ticks) >= 9 and FIELDS <= set(ticks[0])
    assert [t["cmd_seq"] for t in ticks] == list(range(len(ticks)))
    # a loaded machine may delay a frame or a state for a tick: that tick holds, says why, and has no capture
    assert all(t["status"] for t in ticks if t["hold"])
    acted = [t for t in ticks if not t["hold"]]
    assert len(acted) >= len(ticks) // 2
    assert all(t["t_capture"] <= t["t_receive"] <= t["t_preprocess"] <= t["t_send"] for t in acted)


def test_camera_that_vanishes_is_fatal_after_hold(tmp_path):
    with FakeWorld(RATE) as world:
        proc = _start(handmade.build(tmp_path / "s.onnx"), world)
        world.wait_commands(5)
        world.camera_stop.set()
        t_stop = time.monotonic()
        _, err = proc.communicate(timeout=10)
        time.sleep(0.2)
    assert proc.returncode == 3, err
    assert "camera_stalled" in err
    after = [c for c in world.commands if c["t_receive"] > t_stop]
    holding = [np.allclose(c["q_target"], READY_Q) for c in after]
    first = holding.index(True)
    assert all(holding[first:])  # once the camera is gone: hold to the end, the final command included
    assert after[-1]["gripper"] == 1.0
    # detected within: the frame that never came (<= 1 camera period) + one control period + scheduling
    assert after[first]["t_receive"] - t_stop < 2 / RATE + 0.05


def test_exported_untrained_student_runs(untrained_student_onnx):
    with FakeWorld(RATE) as world:
        proc = _start(untrained_student_onnx, world, "--seconds", "1.5")
        _, err = proc.communicate(timeout=30)
    assert proc.returncode == 0, err
    assert "UNTRAINED" in err and len(world.commands) >= 20


@pytest.mark.parametrize("args, code, match", [
    (["--model", "missing.onnx", "--camera", "hil"], 2, "missing.onnx: no such policy file"),
    (["--camera", "teleport:x"], 3, "unknown camera 'teleport:x'"),
    (["--camera", "replay:/nonexistent.npz"], 3, "replay:/nonexistent.npz"),
    (["--camera", "hil", "--robot", "tcp://10.1.2.3:7000"], 2, "without CurveZMQ keys"),
    (["--camera", "hil", "--rate", "-3"], 2, "--rate must be a positive number of Hz, got -3"),
    (["--camera", "hil", "--rate", "0"], 2, "--rate must be a positive number of Hz, got 0"),
])
def test_bad_arguments_give_one_clear_line(tmp_path, args, code, match):
    model = handmade.build(tmp_path / "s.onnx")
    argv = args if "--model" in args else ["--model", str(model), *args]
    proc = subprocess.run([sys.executable, "-m", "runtime", *argv], capture_output=True, text=True,
                          timeout=30)
    assert proc.returncode == code, proc.stderr
    errors = [line for line in proc.stderr.splitlines() if line.startswith("runtime: error")]
    assert len(errors) == 1 and match in errors[0], proc.stderr


def test_a_recording_that_ends_before_the_first_tick_says_nothing_was_commanded(tmp_path):
    clip = tmp_path / "two.npz"
    np.savez(clip, depth=np.full((2, 480, 848), 600, np.uint16), fps=30.0)
    with FakeWorld(RATE) as world:
        model = handmade.build(tmp_path / "s.onnx")
        proc = subprocess.run([sys.executable, "-m", "runtime", "--model", str(model), "--camera",
                               f"replay:{clip}", "--robot", world.robot, "--seconds", "5"],
                              capture_output=True, text=True, timeout=30)
    assert proc.returncode == 0, proc.stderr
    ended = [line for line in proc.stderr.splitlines() if "status camera_ended" in line]
    assert len(ended) == 1 and ended[0].endswith("it ended before the first tick: nothing was commanded")
    assert "'ticks': 0" in proc.stderr


def test_no_robot_names_the_address_and_the_driver_command_within_seconds(tmp_path):
    robot = f"tcp://127.0.0.1:{free_port_pair()}"  # nothing serves it
    with FakeWorld(RATE) as world:
        start = time.monotonic()
        model = handmade.build(tmp_path / "s.onnx")
        proc = subprocess.run([sys.executable, "-m", "runtime", "--model", str(model), "--camera",
                               f"hil:{world.camera}", "--robot", robot, "--seconds", "1"],
                              capture_output=True, text=True, timeout=30)
        took = time.monotonic() - start
    assert proc.returncode == 4, proc.stderr
    fatal = [line for line in proc.stderr.splitlines() if "status fatal" in line]
    assert len(fatal) == 1 and f"no robot state on {robot} within 1 s" in fatal[0]
    assert f"python -m runtime.franka_driver --bind {robot}" in fatal[0] and "hil_sim.driver" in fatal[0]
    assert took < 8.0  # --seconds bounds the wait (the default is 10 s); the rest is start-up
