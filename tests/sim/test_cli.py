"""``python -m trainer collect`` on tiny budgets: outputs, resume, kill -9, SIGTERM, bad input; the command
menu."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from trainer.collect import main as collect_main
from trainer.dataset import DemoStore

REPO = Path(__file__).resolve().parents[2]


def test_collect_writes_depth_demos_and_resumes(tmp_path) -> None:
    out = tmp_path / "demos.zarr"
    args = ["--objects", "cube,lemon", "--out", str(out), "--workers", "1", "--seed", "3"]
    assert collect_main(["--episodes", "1", *args]) == 0
    first = DemoStore.open(out).episode(0)
    assert first["kind"] == "cube" and 40 < len(first["action"]) <= 150
    assert first["depth"].dtype == np.uint16 and (first["depth"] > 0).mean() > 0.5
    assert np.abs(first["action"][:, :7]).max() <= 1.0
    assert set(np.unique(first["action"][:, 7])) == {-1.0, 1.0}
    assert collect_main(["--episodes", "2", *args]) == 0
    store = DemoStore.open(out)
    assert store.n_episodes == 2 and store.attrs["attempted"] == 2
    assert store.episode(1)["kind"] == "lemon" and int(store.episode(1)["seed"]) == 4
    np.testing.assert_array_equal(store.episode(0)["depth"], first["depth"])


def left_half_lost(_arg: str):
    """A sensor for the test below (``tests.sim.test_cli:left_half_lost``): no data in the left half."""
    def sensor(depth: np.ndarray) -> np.ndarray:
        out = depth.copy()
        out[..., : depth.shape[-1] // 2] = 0
        return out
    return sensor


def stuck(_arg: str):
    """A sensor that never returns a frame in a test's time (``tests.sim.test_cli:stuck``)."""
    def sensor(depth: np.ndarray) -> np.ndarray:
        time.sleep(600)
        return depth
    return sensor


def test_collect_with_a_sensor_keeps_its_frames_beside_the_clean_depth(tmp_path, capsys) -> None:
    from trainer.student.data import DemoDataError, DemoDataset

    out = tmp_path / "demos.zarr"
    args = ["--objects", "cube", "--out", str(out), "--workers", "1", "--seed", "3"]
    assert collect_main(["--episodes", "1", *args, "--sensor", "tests.sim.test_cli:left_half_lost"]) == 0
    store = DemoStore.open(out)
    episode = store.episode(0)
    assert store.attrs["sensor"] == "tests.sim.test_cli:left_half_lost"
    assert (episode["depth"] > 0).mean() > 0.5  # the clean depth, untouched
    np.testing.assert_array_equal(episode["depth_sensor"], left_half_lost("")(episode["depth"]))
    frames = DemoDataset(out, "sensor", obs_horizon=1, action_horizon=2).depth
    np.testing.assert_array_equal(frames, episode["depth_sensor"])
    # resumed with another sensor, or trained on sensor frames a store never kept: refused by name
    assert collect_main(["--episodes", "2", *args]) == 2
    err = capsys.readouterr().err
    assert "keeps the frames of sensor 'tests.sim.test_cli:left_half_lost', not None" in err
    assert collect_main(["--episodes", "1", *args, "--out", str(tmp_path / "plain.zarr")]) == 0
    assert "depth_sensor" not in DemoStore.open(tmp_path / "plain.zarr").root["data"]
    with pytest.raises(DemoDataError, match="no data/depth_sensor .* `python -m trainer collect --sensor`"):
        DemoDataset(tmp_path / "plain.zarr", "sensor", obs_horizon=1, action_horizon=2)
    assert collect_main(["--episodes", "1", *args, "--out", str(tmp_path / "x.zarr"), "--sensor", "fog"]) == 2
    assert "unknown sensor 'fog'" in capsys.readouterr().err and not (tmp_path / "x.zarr").exists()


def test_dart_demos_record_their_noise_and_a_negative_one_is_refused(tmp_path, capsys) -> None:
    args = ["--episodes", "1", "--objects", "cube", "--workers", "1", "--no-depth"]
    assert collect_main([*args, "--out", str(tmp_path / "dart.zarr"), "--action-noise", "0.3"]) == 0
    assert DemoStore.open(tmp_path / "dart.zarr").attrs["action_noise"] == 0.3
    assert collect_main([*args, "--out", str(tmp_path / "bad.zarr"), "--action-noise", "-1"]) == 2
    assert "--action-noise must be >= 0" in capsys.readouterr().err


def test_wide_wrist_demos_start_their_wrist_anywhere_in_the_range(tmp_path, capsys) -> None:

    from hil_sim.world import HOME_Q

    args = ["--objects", "cube", "--workers", "1", "--no-depth", "--wrist-noise"]
    assert collect_main(["--episodes", "4", "--out", str(tmp_path / "w.zarr"), *args, "1.5"]) == 0
    store = DemoStore.open(tmp_path / "w.zarr")
    wrists = [json.loads(str(r))["q0"][6] - HOME_Q[6] for r in store.root["meta/randomisation"][:]]
    assert store.attrs["wrist_noise"] == 1.5 and max(np.abs(wrists)) <= 1.5 and max(np.abs(wrists)) > 0.05
    assert collect_main(["--episodes", "1", "--out", str(tmp_path / "bad.zarr"), *args, "-1"]) == 2
    assert "--wrist-noise must be >= 0" in capsys.readouterr().err


def test_unwritable_output_is_one_error_line(tmp_path, capsys) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("x")
    assert collect_main(["--episodes", "1", "--out", str(blocker / "d.zarr"), "--workers", "1"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: cannot write a demo store") and "\n" not in err


def test_trainer_help_goes_to_stdout_and_an_unknown_command_is_named() -> None:
    def trainer(*argv: str) -> subprocess.CompletedProcess:
        return subprocess.run([sys.executable, "-m", "trainer", *argv], cwd=REPO, capture_output=True,
                              text=True, timeout=60)

    helped, bogus = trainer("--help"), trainer("bogus")
    assert helped.returncode == 0 and "evaluate" in helped.stdout and helped.stderr == ""
    assert bogus.returncode == 2 and bogus.stderr.strip().endswith("error: unknown command 'bogus'")


def test_a_policy_the_workers_cannot_load_is_one_error_not_a_hang(tmp_path) -> None:
    missing = tmp_path / "missing.pt"  # each spawned worker loads it; a pool whose setup raised respawned
    run = subprocess.run([sys.executable, "-m", "trainer", "evaluate", "--policy", f"oracle:{missing}",
                          "--objects", "cube", "--episodes", "2", "--workers", "2"], cwd=REPO,
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 2 and "Traceback" not in run.stderr
    assert run.stderr.strip().splitlines()[-1].startswith(f"error: cannot read student checkpoint {missing}")


@pytest.mark.slow
def test_killed_collection_keeps_whole_episodes(tmp_path) -> None:
    out = tmp_path / "demos.zarr"
    cmd = [sys.executable, "-m", "trainer", "collect", "--episodes", "40", "--out", str(out), "--no-depth",
           "--workers", "1", "--objects", "cube"]
    proc = subprocess.Popen(cmd, cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            env={**os.environ, "PYTHONPATH": str(REPO)})
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:
            time.sleep(0.5)
            if (out / "zarr.json").exists() and DemoStore.open(out).n_episodes >= 2:
                break
        proc.send_signal(signal.SIGKILL)
    finally:
        proc.wait(timeout=30)
    store = DemoStore.create(out, spec=DemoStore.open(out).depth_spec, action_scale=0.05, control_rate_hz=10)
    n = store.n_episodes
    assert n >= 2
    ends = store.episode_ends
    assert store.root["data/action"].shape[0] == ends[-1] == store.root["data/state"].shape[0]
    for i in range(n):
        assert store.episode(i)["kind"] == "cube"


def _alive(pid: int) -> bool:
    """``pid`` runs (a zombie has ended: only its exit status is left to collect)."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except (FileNotFoundError, ProcessLookupError):
        return False


@pytest.mark.slow
def test_a_stopped_command_stops_its_workers(tmp_path) -> None:
    """``kill PID`` of a collection with --workers 2 ends its worker processes too: a bare SIGTERM left them
    collecting for a parent that was gone, at the cost of every later job on the machine."""
    cmd = [sys.executable, "-m", "trainer", "collect", "--episodes", "4", "--out", str(tmp_path / "d.zarr"),
           "--workers", "2", "--objects", "cube", "--sensor", "tests.sim.test_cli:stuck"]
    proc = subprocess.Popen(cmd, cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            env={**os.environ, "PYTHONPATH": str(REPO)})
    try:
        deadline, children = time.monotonic() + 120, []
        while time.monotonic() < deadline and len(children) < 3:  # two workers, multiprocessing's tracker
            time.sleep(0.5)
            children = Path(f"/proc/{proc.pid}/task/{proc.pid}/children").read_text().split()
        children = [int(c) for c in children]
        time.sleep(10)  # the workers inside their first episode
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=60) != 0
    finally:
        proc.kill()
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline and any(map(_alive, children)):
        time.sleep(0.5)
    assert not any(map(_alive, children))
