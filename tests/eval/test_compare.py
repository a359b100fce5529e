"""``trainer compare``: two evaluate results on the same episodes, counted episode by episode."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from trainer.eval.compare import compare, main, mcnemar_p


def result(path: Path, failed: list[int], *, seed: int = 100, episodes: int = 6,
           objects: tuple[str, ...] = ("apple", "cube")) -> Path:
    path.write_text(json.dumps({"policy": f"student:{path.stem}.onnx", "objects": list(objects), "seed": seed,
                                "episodes": episodes, "failed_seeds": failed,
                                "success_rate": 1 - len(failed) / episodes}))
    return path


def test_won_and_lost_are_counted_per_kind_on_the_same_seeds(tmp_path: Path) -> None:
    # seeds 100..105 alternate apple, cube: A fails 100 (apple), 101, 103 (cubes); B fails 103 and 104 (apple)
    a, b = result(tmp_path / "a.json", [100, 101, 103]), result(tmp_path / "b.json", [103, 104])
    out = compare(a, b)
    assert out["kinds"]["apple"] == {"episodes": 3, "a_success": 2, "b_success": 2, "b_won": 1, "b_lost": 1,
                                     "p": 1.0}
    assert out["kinds"]["cube"]["b_won"] == 1 and out["kinds"]["cube"]["b_lost"] == 0
    assert (out["all"]["b_won"], out["all"]["b_lost"]) == (2, 1)


def test_the_exact_mcnemar_p_is_the_two_sided_binomial_of_the_discordant_episodes() -> None:
    assert mcnemar_p(17, 6) == pytest.approx(0.0347, abs=1e-4)  # round 4 against round 3 (docs/history.md)
    assert mcnemar_p(6, 0) == pytest.approx(2 * 0.5 ** 6)
    assert mcnemar_p(0, 0) == 1.0


@pytest.mark.parametrize("other", [{"seed": 101}, {"episodes": 8}, {"objects": ("cube", "apple")}])
def test_results_of_different_episodes_are_refused_in_one_line(tmp_path: Path, capsys, other: dict) -> None:
    a, b = result(tmp_path / "a.json", [100]), result(tmp_path / "b.json", [], **other)
    assert main([str(a), str(b)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and "did not run the same episodes" in err and err.count("\n") == 1


def test_a_file_that_is_not_a_result_is_named(tmp_path: Path, capsys) -> None:
    a, bad = result(tmp_path / "a.json", []), tmp_path / "bad.json"
    bad.write_text("{}")
    assert main([str(a), str(bad)]) == 2
    assert capsys.readouterr().err.startswith(f"error: {bad}: not a trainer evaluate result")
