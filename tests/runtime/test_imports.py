"""The deploy side stays lean and readable: no heavy or simulator imports, and few enough lines to read."""

import ast
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
MODULES = ["runtime", "runtime.loop", "runtime.policy", "runtime.cameras", "runtime.franka_driver",
           "runtime.transport", "runtime.__main__", "runtime.cameras.hil", "runtime.cameras.replay",
           "runtime.franka_driver.__main__", "runtime.franka_driver.server", "runtime.franka_driver.safety",
           "runtime.franka_driver.franka_backend"]
BANNED = ("torch", "trainer", "export", "diffusers", "mujoco", "hil_sim")
ENTRY_POINTS = ("runtime/__main__.py", "runtime/franka_driver/__main__.py")
DEPLOY_LINES = 2100
"""Ceiling on what ``runtime`` and ``python -m runtime.franka_driver`` import from the project, in non-blank
lines (2,353 before issue 43, 2,082 after). A ratchet: lower it as the deploy side shrinks. The issue's goal
of 1,500 is below its code alone (~1,560 lines without a docstring, comment or import)."""


def test_runtime_never_imports_the_heavy_side_or_the_simulator():
    code = (f"import sys, importlib; [importlib.import_module(m) for m in {MODULES!r}]; "
            f"print(sorted(m for m in sys.modules if m.split('.')[0] in {BANNED!r}))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=True)
    assert out.stdout.strip() == "[]", out.stdout


@pytest.mark.skipif(shutil.which("ruff") is None and not Path(sys.prefix, "bin", "ruff").exists(),
                    reason="ruff not installed")
@pytest.mark.parametrize("module", BANNED)
def test_the_lint_rule_refuses_each_banned_import_in_runtime(module):
    cmd = [sys.executable, "-m", "ruff", "check", "--select=TID251", "--stdin-filename=runtime/x.py", "-"]
    done = subprocess.run(cmd, input=f"import {module}\n", cwd=REPO, capture_output=True, text=True,
                          timeout=60)
    assert done.returncode == 1 and f"`{module}` is banned" in done.stdout, done.stdout + done.stderr


def deploy_files() -> dict[str, int]:
    """Every project file the two deploy commands import (statically, lazily imported ones included), with
    its non-blank line count."""
    counts: dict[str, int] = {}
    todo = [REPO / p for p in ENTRY_POINTS]
    while todo:
        path = todo.pop()
        rel = path.relative_to(REPO).as_posix()
        if rel in counts:
            continue
        text = path.read_text()
        counts[rel] = sum(1 for line in text.splitlines() if line.strip())
        for node in ast.walk(ast.parse(text)):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else []
            if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names = [node.module, *(f"{node.module}.{a.name}" for a in node.names)]
            for name in names:
                parts = name.split(".")  # the module and each package on its way, as Python runs them
                for i in range(1, len(parts) + 1):
                    base = REPO.joinpath(*parts[:i])
                    todo += [f for f in (base / "__init__.py", base.with_suffix(".py")) if f.is_file()]
    return counts


def test_the_deploy_side_reads_in_one_sitting():
    counts = deploy_files()
    assert all(path.startswith("runtime/") for path in counts), sorted(counts)
    assert {"runtime/cameras/d455.py", "runtime/franka_driver/franka_backend.py"} <= set(counts)  # lazily
    total = sum(counts.values())
    table = "\n".join(f"{n:5d} {path}" for path, n in sorted(counts.items(), key=lambda kv: -kv[1]))
    assert total < DEPLOY_LINES, f"deploy side is {total} non-blank lines (limit {DEPLOY_LINES}):\n{table}"
