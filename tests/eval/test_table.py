"""``trainer table``: evaluate results -> one table, one cell per policy x sensor x object group."""

from __future__ import annotations

import json

import pytest

from hil_sim.objects import GROUPS
from trainer.eval.table import TableError, build, main, markdown


def _result(tmp_path, name, *, sensor="clean", objects="seen", rate=0.5, restore="none"):
    path = tmp_path / f"{name}.json"
    path.write_text(json.dumps({"success_rate": rate, "episodes": 10, "policy": "student:runs/a.onnx",
                                "sensor": sensor, "objects": list(GROUPS[objects]), "restore": restore}))
    return path


def test_cells_land_in_their_row_and_column_with_a_wilson_interval(tmp_path):
    doc = build([_result(tmp_path, "a", rate=0.5),
                 _result(tmp_path, "b", sensor="stereo", objects="unseen", rate=0.0),
                 _result(tmp_path, "c", restore="inpaint", rate=1.0)])
    assert doc["columns"] == ["clean seen", "stereo unseen"]
    assert set(doc["rows"]) == {"a", "a + inpaint"}
    assert doc["rows"]["a"]["stereo unseen"]["successes"] == 0
    assert doc["rows"]["a"]["clean seen"]["ci95"] == pytest.approx([0.2366, 0.7634], abs=1e-4)
    assert "| a + inpaint | 100.0% [72%, 100%] n=10 | - |" in markdown(doc)


def test_rows_of_files_with_one_name_keep_as_many_folders_as_tell_them_apart(tmp_path):
    policies = {"student:$R/row_a/c1/student.onnx": "row_a/c1/student",
                "student:$R/row_b/c1/student.onnx": "row_b/c1/student",
                "student:models/student.onnx": "models/student", "student:runs/a.onnx": "a"}
    paths = []
    for i, policy in enumerate(policies):
        path = _result(tmp_path, f"r{i}")
        path.write_text(json.dumps(dict(json.loads(path.read_text()), policy=policy)))
        paths.append(path)
    assert set(build(paths)["rows"]) == set(policies.values())


def test_a_cell_carries_the_closing_distance_when_the_result_has_one(tmp_path):
    path = _result(tmp_path, "d", sensor="stereo")
    result = json.loads(path.read_text())
    result["first_close"] = {"episodes": 7, "horizontal_cm_median": 18.87,
                             "horizontal_cm_median_ci95": [16.23, 20.32]}
    path.write_text(json.dumps(result))
    doc = build([path, _result(tmp_path, "e")])
    assert doc["rows"]["a"]["stereo seen"]["closes_cm_ci95"] == [16.23, 20.32]
    # e.json has no first_close: its cell is the success alone.
    row = "| a | 50.0% [24%, 76%] n=10 | 50.0% [24%, 76%] n=10, closes 18.9 cm [16.2, 20.3] |"
    assert row in markdown(doc)


def test_two_results_for_one_cell_and_foreign_json_are_named(tmp_path, capsys):
    with pytest.raises(TableError, match="two results for a / clean seen"):
        build([_result(tmp_path, "x"), _result(tmp_path, "y")])
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"hello": 1}))
    assert main([str(bad)]) == 2
    assert "bad.json: not a trainer evaluate result" in capsys.readouterr().err


def test_a_base_table_keeps_its_cells_and_a_new_result_replaces_the_same_cell(tmp_path):
    old = build([_result(tmp_path, "a", rate=0.5), _result(tmp_path, "b", sensor="stereo", rate=0.1)])
    old["rows"]["older"] = {"clean unseen": dict(old["rows"]["a"]["clean seen"], source="gone.json")}
    base = tmp_path / "table.json"
    base.write_text(json.dumps(old))
    out = tmp_path / "merged.json"
    assert main([str(_result(tmp_path, "c", rate=1.0)), "--base", str(base), "--out", str(out)]) == 0
    doc = json.loads(out.read_text())
    assert list(doc["rows"]) == ["a", "older"]
    assert doc["rows"]["a"]["clean seen"]["successes"] == 10  # replaced by c.json
    assert doc["rows"]["a"]["stereo seen"]["successes"] == 1  # kept
    assert doc["rows"]["older"]["clean unseen"]["source"] == "gone.json"
    assert doc["columns"] == ["clean seen", "clean unseen", "stereo seen"]
    base.write_text(json.dumps({"hello": 1}))
    assert main([str(_result(tmp_path, "c")), "--base", str(base)]) == 2
