"""scripts/size_report.py on a made-up tree: lines, models/ files, docs and the import cycles it finds."""

from __future__ import annotations

import importlib.util
from pathlib import Path

_spec = importlib.util.spec_from_file_location(
    "size_report", Path(__file__).parents[2] / "scripts" / "size_report.py"
)
size_report = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(size_report)

TREE = {
    "runtime/__init__.py": b"",
    "runtime/a.py": b"from hil_sim import b\n",  # a module of a package: the edge is to hil_sim.b
    "hil_sim/__init__.py": b"from hil_sim.b import X\n",
    "hil_sim/b.py": b"X = 1\n\ndef f():\n    from runtime.a import g  # lazy, still an edge\n",
    "hil_sim/c.py": b"from .b import X\nfrom . import b\n",
    "models/student/run.sh": b"echo hi",
    "models/student/README.md": b"# x\n",
    "docs/x.md": b"one\ntwo\n",
    "README.md": b"r\n",
}


def test_cycle_through_a_lazy_import_and_no_parent_package_edge():
    graph = size_report.import_graph(TREE)
    assert graph["runtime.a"] == {"hil_sim.b"}
    assert graph["hil_sim.c"] == {"hil_sim.b"}
    assert size_report.cycles(graph) == [["hil_sim.b", "runtime.a"]]


def test_lines_models_and_docs():
    rows = {label: value for section in size_report.report(TREE) for label, value in section.items()}
    assert rows["lines (.py+.sh) models/"] == 1
    assert rows["lines (.py+.sh) hil_sim/"] == 7
    assert rows["files in models/ (code)"] == "2 (1)"
    assert rows["lines docs/x.md"] == 2 and rows["lines README.md"] == 1
    assert rows["import cycles"] == 1
