"""``python -m trainer collect`` and ``evaluate`` on tiny budgets: outputs, resume, kill -9, bad input."""

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
from trainer.evaluate import first_close, median_interval, table, wilson_interval
from trainer.evaluate import main as evaluate_main

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
    import json

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


def test_evaluate_writes_the_json_contract(tmp_path, capsys) -> None:
    path = tmp_path / "eval.json"
    assert evaluate_main(["--episodes", "2", "--objects", "cube,peach", "--workers", "1", "--json",
                          str(path)]) == 0
    result = json.loads(path.read_text())
    assert result["episodes"] == 2 and set(result["per_object"]) == {"cube", "peach"}
    assert 0.0 <= result["success_rate"] <= 1.0
    assert result["success_rate"] == pytest.approx(np.mean(list(result["per_object"].values())))
    lo, hi = result["ci95"]
    assert 0.0 <= lo <= result["success_rate"] <= hi <= 1.0 and hi - lo > 0.3  # 2 episodes say little
    # The scripted expert closes centred over the object, the grasp site 1-5 cm above its centre.
    closes = result["first_close"]
    assert closes["episodes"] == 2 and 20 < closes["median_step"] < 100
    assert closes["horizontal_cm_median"] < 1.0 and -5.0 < closes["offset_cm_mean"][2] < -1.0
    lo, hi = closes["horizontal_cm_median_ci95"]
    assert lo <= closes["horizontal_cm_median"] <= hi
    out = capsys.readouterr().out
    assert "first close in 2 episodes" in out and out.rstrip().splitlines()[-1].startswith("ALL")


@pytest.mark.parametrize("successes,n", [(0, 10), (5, 10), (10, 10), (1, 30), (81, 263)])
def test_wilson_interval_matches_scipy(successes, n) -> None:
    from scipy.stats import binomtest

    expected = binomtest(successes, n).proportion_ci(method="wilson")
    np.testing.assert_allclose(wilson_interval(successes, n), (expected.low, expected.high), atol=1e-4)


def test_median_interval_holds_the_median_narrows_with_more_episodes_and_is_seeded() -> None:
    distances = np.random.default_rng(3).exponential(10.0, 400)
    small, large = median_interval(distances[:40]), median_interval(distances)
    assert small[0] <= np.median(distances[:40]) <= small[1] and large[0] <= np.median(distances) <= large[1]
    assert large[1] - large[0] < small[1] - small[0]
    assert median_interval(distances) == large and median_interval(distances[:1]) is None


def test_the_table_gives_the_closing_interval_only_when_there_is_one() -> None:
    def printed(offsets: list) -> str:
        result = {"per_object": {"cube": 0.0}, "ci95": [0.0, 0.5], "success_rate": 0.0, "episodes": 4,
                  "policy": "p", "sensor": "clean", "restore": "none",
                  "first_close": first_close([(30, np.array(o)) for o in offsets])}
        return table(result)

    one, three = printed([[0.03, 0.04, 0.0]]), printed([[0.03, 0.04, 0], [0.0, 0.1, 0], [0.06, 0.08, 0]])
    assert "5.0 cm apart horizontally (median)" in one and "None" not in one
    assert "10.0 cm apart horizontally (median; 95 % CI [" in three


def test_first_close_offsets_print_as_rounded_centimetres() -> None:
    closes = first_close([(30, np.array([0.0328, -0.0328, 0.0], dtype=np.float32))])
    assert closes["offset_cm_mean"] == [3.28, -3.28, 0.0]
    result = {"per_object": {}, "ci95": [0.0, 1.0], "success_rate": 0.0, "episodes": 1, "policy": "p",
              "sensor": "clean", "restore": "none", "first_close": closes}
    assert "[3.28, -3.28, 0.0] cm" in table(result)


def test_trainer_help_goes_to_stdout_and_an_unknown_command_is_named() -> None:
    def trainer(*argv: str) -> subprocess.CompletedProcess:
        return subprocess.run([sys.executable, "-m", "trainer", *argv], cwd=REPO, capture_output=True,
                              text=True, timeout=60)

    helped, bogus = trainer("--help"), trainer("bogus")
    assert helped.returncode == 0 and "evaluate" in helped.stdout and helped.stderr == ""
    assert bogus.returncode == 2 and bogus.stderr.strip().endswith("error: unknown command 'bogus'")


@pytest.mark.parametrize("argv,needle", [(["--objects", "dragonfruit"], "unknown object kind 'dragonfruit'"),
                                         (["--policy", "magic"], "unknown policy 'magic'"),
                                         (["--sensor", "fog"], "unknown sensor 'fog'")])
def test_evaluate_bad_input_is_one_error_line(argv, needle, capsys) -> None:
    assert evaluate_main(["--episodes", "1", "--workers", "1", *argv]) == 2
    err = capsys.readouterr().err.strip()
    assert needle in err and "\n" not in err


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
