import subprocess
import sys

MODULES = ["runtime", "runtime.loop", "runtime.policy", "runtime.cameras", "runtime.franka_driver",
           "runtime.transport", "runtime.__main__", "runtime.cameras.hil", "runtime.cameras.replay"]


def test_runtime_never_imports_the_heavy_side():
    code = (f"import sys, importlib; [importlib.import_module(m) for m in {MODULES!r}]; "
            "print(sorted(m for m in sys.modules if m.split('.')[0] in ('torch', 'trainer', 'export', "
            "'diffusers')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=True)
    assert out.stdout.strip() == "[]", out.stdout
