import subprocess
import sys

import numpy as np

from trainer.ddg.cli import main

from .conftest import scene


def test_ddg_help_lists_the_commands(capsys):
    assert main(["--help"]) == 0
    out = capsys.readouterr().out
    assert all(c in out for c in ("fit", "generate", "metrics"))
    assert main([]) == 2


def test_bad_real_dir_is_a_one_line_error(tmp_path, capsys):
    assert main(["fit", "--real", str(tmp_path), "--run", str(tmp_path / "r")]) == 2
    assert capsys.readouterr().err.strip() == f"error: no .npz depth frames in {tmp_path}"


def test_bad_inputs_are_one_line_errors_for_every_command(tmp_path, capsys, tiny_model):
    """No frames, NaNs, a store at another resolution: exit 2 and one `error:` line naming the problem."""
    empty = tmp_path / "empty"
    empty.mkdir()
    nan = tmp_path / "nan"
    nan.mkdir()
    depth = np.full((240, 320), 0.8, np.float32)
    depth[5, 5] = np.nan
    np.savez(nan / "f.npz", depth_m=depth)
    import zarr

    zarr.open_group(str(tmp_path / "s.zarr"), mode="w").create_array("data/depth", shape=(2, 48, 64),
                                                                       dtype="uint16")[:] = 900
    cases = [(["metrics", "--real", str(empty), "--model", ""], "no .npz depth frames"),
             (["metrics", "--real", str(nan), "--subset", "all", "--model", ""], "depth holds 1 NaN/inf"),
             (["generate", "--demos", str(tmp_path / "s.zarr"), "--model", str(tiny_model)],
              "the model's resolution"),
             (["generate", "--demos", str(tmp_path / "none.zarr")], "no demo store"),
             (["metrics", "--judge", "colour", "--model", ""], "--judge must be one of both, depth, holes"),
             (["metrics", "--views", "matched", "--demos", str(tmp_path / "s.zarr"), "--model", ""],
              "a demo store holds the policy's view only")]
    for argv, message in cases:
        assert main(argv) == 2, argv
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("error: ") and message in err[0], (argv, err)


def _real_dir(path):
    """Three D435-like frames and one from another sensor, with a manifest, like shared/data/real_depth."""
    import json

    rng = np.random.default_rng(0)
    entries = []
    for i in range(4):
        depth = scene(rng, 240, 320).astype(np.float32) / 1000
        depth[rng.random(depth.shape) < 0.05] = 0
        np.savez(path / f"f{i}.npz", depth_m=depth)
        entries.append({"file": f"f{i}.npz", "sensor": "Intel RealSense D435" if i < 3 else "Kinect v1"})
    (path / "MANIFEST.json").write_text(json.dumps({"frames": entries}))
    return path


def test_metrics_cli_end_to_end(tmp_path, tiny_demos, tiny_model):
    """Tiny budget: 4 crops per real frame, 12 sim frames from a demo store, 2 DDIM steps."""
    import json

    real = _real_dir(tmp_path)
    out = tmp_path / "m" / "metrics.json"
    args = ["metrics", "--real", str(real), "--subset", "all", "--json", str(out), "--model", str(tiny_model),
            "--demos", str(tiny_demos), "--crops", "4", "--sim-frames", "12", "--steps", "2",
            "--bootstrap", "3", "--threads", "1"]  # 1: the setting is process-wide and later tests inherit it
    assert main(args) == 0
    res = json.loads(out.read_text())
    assert set(res["sources"]) == {"real_other_sensors", "gt", "randnoise", "inpaint", "ddg_nograft", "ddg"}
    for s in res["sources"].values():
        assert np.isfinite(s["fid"]) and np.isfinite(s["kid"]) and 0 <= s["hole_fraction"] <= 1
    assert res["sources"]["randnoise"]["hole_fraction"] > res["sources"]["gt"]["hole_fraction"]
    lo, hi = res["sources"]["gt"]["fid_ci95"]
    assert lo <= hi and res["sources"]["gt"]["kid_ci95"][0] <= res["sources"]["gt"]["kid_ci95"][1]
    assert all((out.parent / f).stat().st_size > 0 for f in ("grid.png", "tsne.png", "holes.png"))
    off = {k: v.get("off_sim_mm_p50_p90") for k, v in res["sources"].items()}
    assert off["gt"] == off["ddg"] == [0.0, 0.0] and off["real_other_sensors"] is None
    assert off["ddg_nograft"][1] > 0  # an untrained net moves the geometry
    assert main([*args, "--judge", "holes", "--bootstrap", "0"]) == 0
    assert "inpaint" not in json.loads(out.read_text())["sources"]  # no holes on either side to judge



def test_metrics_judge_one_source_against_the_others_and_count_what_the_model_saw(tmp_path, tiny_demos,
                                                                                  tiny_model, capsys):
    """--source: the reference is that source's D4xx frames, real_train the other sources'; the JSON counts
    the reference frames the model trained on (its config's frames); an unknown source is named."""
    import json
    import shutil

    (tmp_path / "real").mkdir()
    real = _real_dir(tmp_path / "real")
    model = tmp_path / "model"
    shutil.copytree(tiny_model, model)
    config = json.loads((model / "config.json").read_text())
    (model / "config.json").write_text(json.dumps({**config, "frames": ["f0", "f1"]}))
    out = tmp_path / "m" / "metrics.json"
    args = ["metrics", "--real", str(real), "--json", str(out), "--model", str(model), "--demos",
            str(tiny_demos), "--crops", "4", "--sim-frames", "12", "--steps", "2", "--bootstrap", "0",
            "--threads", "1"]
    assert main([*args, "--source", "f2"]) == 0
    res = json.loads(out.read_text())
    assert res["reference"]["real_frames"] == 1 and res["reference"]["frames_the_model_trained_on"] == 0
    assert res["sources"]["real_train"]["frames"] == 12  # crops of f0 and f1, the other D4xx source
    assert main([*args, "--source", "f0"]) == 0
    assert json.loads(out.read_text())["reference"]["frames_the_model_trained_on"] == 1
    assert main([*args, "--source", "f3"]) == 2  # f3 is the Kinect's
    assert "no frames of source 'f3'; the sources are f0, f1, f2" in capsys.readouterr().err


def test_fit_help_shows_field_docs():
    cmd = [sys.executable, "-m", "trainer", "ddg", "fit", "--help"]
    r = subprocess.run(cmd, capture_output=True, text=True, check=True)
    assert "Random crops per real frame" in r.stdout
