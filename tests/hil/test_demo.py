"""``python -m hil_sim.demo`` (make demo): the grasp judge, the event count, one short episode end to end."""

import json
import subprocess
import sys
import threading
from collections import Counter
from types import SimpleNamespace

import numpy as np
import pytest

from hil_sim import demo
from hil_sim.server import SimConfig, SimServer
from hil_sim.world import TABLE_Z
from tests.hil.rig import REPO, subprocess_env
from tests.runtime.fakes import free_addresses

TARGET = np.array([0.5, 0.0, TABLE_Z + demo.LIFT_M])


class FakeWorld:
    """The few readings the judge takes: finger contacts and the object's pose and size."""

    def __init__(self) -> None:
        self.contacts, self.position = (False, False), np.array([0.5, 0.0, TABLE_Z + 0.03])
        self.data = SimpleNamespace(qpos=np.zeros(3))

    def finger_contacts(self):
        return self.contacts

    def object_pose(self):
        return self.position, np.array([1.0, 0, 0, 0])

    def object_extent(self):
        return np.array([0.025, 0.025, 0.025])


def test_the_judge_wants_the_object_held_at_the_target_for_half_a_second(monkeypatch):
    world, now = FakeWorld(), [0.0]
    monkeypatch.setattr(demo.time, "monotonic", lambda: now[0])
    judge = demo.Judge(world, threading.Lock(), TARGET)
    assert not judge() and not judge.grasped  # on the table
    world.contacts, world.position = (True, True), TARGET + [0, 0, 0.05]  # held, lifted, 5 cm off the target
    assert not judge() and judge.grasped
    world.position = TARGET + [0, 0, 0.01]
    for t in (1.0, 1.3):
        now[0] = t
        assert not judge()
    world.contacts = (True, False)  # slipped for a moment: the half second starts again
    assert not judge()
    world.contacts = (True, True)
    for t in (1.4, 1.8):
        now[0] = t
        assert not judge()
    now[0] = 1.9
    assert judge() and judge.success and len(judge.poses) == 8


def test_events_count_what_happened_not_the_all_clears():
    log = "\n".join(["runtime: real-time scheduling SCHED_FIFO priority 10",
                     "runtime: status camera_stalled: no frame from hil:x for 0.2 s",
                     "runtime: status camera_stalled_cleared: resuming",
                     "runtime: status driver: command_timeout: no valid command for 0.3 s",
                     "runtime: status driver: fault cleared",
                     "runtime: status camera_stalled: no frame from hil:x for 0.2 s"])
    assert demo.runtime_events(log) == Counter({"camera_stalled": 2, "driver command_timeout": 1})


def _cli(module: str, *argv: str, timeout: float) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", module, *argv], cwd=REPO, env=subprocess_env(),
                          capture_output=True, text=True, timeout=timeout)


@pytest.mark.parametrize("module", ["hil_sim", "hil_sim.demo"])
def test_a_zero_rate_is_refused_in_one_line(module):
    done = _cli(module, "--rate", "0", timeout=60)
    assert done.returncode == 2 and done.stderr.strip() == f"{module}: --rate must be positive, got 0"


def test_a_late_share_outside_0_1_is_refused_in_one_line():
    done = _cli("hil_sim", "--late-share", "1", timeout=60)
    assert done.returncode == 2 and done.stderr.strip() == "hil_sim: --late-share must be in [0, 1), got 1"


@pytest.mark.parametrize("module", ["hil_sim", "hil_sim.demo"])
def test_a_model_that_is_not_onnx_is_named_before_any_run(module, tmp_path):
    bad = tmp_path / "x.onnx"
    bad.write_text("garbage")  # the runtime process died on it and the demo blamed a missing ticks.jsonl
    done = _cli(module, "--model", str(bad), timeout=60)
    assert done.returncode == 2 and done.stderr.count("\n") == 1
    assert done.stderr.startswith(f"{module}: --model {bad}: not a loadable ONNX model")


@pytest.mark.hil
@pytest.mark.slow
def test_one_short_episode_writes_the_summary_the_video_and_the_plot(tmp_path):
    camera, robot = free_addresses()
    done = _cli("hil_sim.demo", "--episodes", "1", "--seconds", "3", "--out", str(tmp_path),
                "--camera", camera, "--robot", robot, timeout=240)
    assert done.returncode == 0, (done.stdout + done.stderr)[-2000:]
    lines = done.stdout.splitlines()
    assert lines[1].startswith("episode 1/1 (seed 10000): ") and "ticks" in lines[1]
    heads = [line.split()[0] for line in lines[2:]]
    assert heads == ["grasps", "latency", "events", "video", "plot", "summary"]
    doc = json.loads((tmp_path / "demo.json").read_text())
    assert doc["episodes"] == 1 and doc["ticks"] >= 25 and doc["runtime_exits"] == [0]
    assert (tmp_path / "episode.gif").read_bytes()[:6] == b"GIF89a"
    assert (tmp_path / "latency.png").read_bytes()[:4] == b"\x89PNG"


@pytest.mark.hil
def test_the_driver_restarts_on_its_own_address_again_and_again():
    """stop_driver then start_driver on the same port (each demo episode does): ZeroMQ releases the old port
    asynchronously, which made the fourth restart or so fail with "Address already in use"."""
    camera, robot = free_addresses()
    with SimServer(SimConfig(camera, robot)) as sim:
        for _ in range(40):
            sim.stop_driver()
            sim.start_driver()
        assert sim._driver_thread.is_alive()
