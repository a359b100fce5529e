"""The deploy side stays lean: no heavy or simulator imports."""

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

