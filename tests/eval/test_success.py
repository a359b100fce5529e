"""``python -m trainer evaluate`` on tiny budgets: the JSON contract, the printed table, bad input."""

from __future__ import annotations

import json

import numpy as np
import pytest

from trainer.eval.success import first_close, table
from trainer.eval.success import main as evaluate_main


def test_evaluate_writes_the_json_contract(tmp_path, capsys) -> None:
    path = tmp_path / "eval.json"
    assert evaluate_main(["--episodes", "2", "--objects", "cube,peach", "--workers", "1", "--json",
                          str(path)]) == 0
    result = json.loads(path.read_text())
    assert result["episodes"] == 2 and set(result["per_object"]) == {"cube", "peach"}
    assert 0.0 <= result["success_rate"] <= 1.0
    assert result["success_rate"] == pytest.approx(np.mean(list(result["per_object"].values())))
    assert set(result["failed_seeds"]) <= {10_000, 10_001}
    assert len(result["failed_seeds"]) == round(2 * (1 - result["success_rate"]))
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


@pytest.mark.parametrize("argv,needle", [(["--objects", "dragonfruit"], "unknown object kind 'dragonfruit'"),
                                         (["--policy", "magic"], "unknown policy 'magic'"),
                                         (["--sensor", "fog"], "unknown sensor 'fog'")])
def test_evaluate_bad_input_is_one_error_line(argv, needle, capsys) -> None:
    assert evaluate_main(["--episodes", "1", "--workers", "1", *argv]) == 2
    err = capsys.readouterr().err.strip()
    assert needle in err and "\n" not in err
