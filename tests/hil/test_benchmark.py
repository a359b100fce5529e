"""CI's HIL gate: ``python -m hil_sim --seconds 60 --rate 10`` must hold the rate with every deadline met.

The runtime asks for SCHED_FIFO (runtime.realtime). Where the OS grants it, a CPU-bound job beside the test
cannot take a core from the loop, and every deadline must be met. Where it does not, the OS may delay the
loop behind other processes: measured at normal priority on a machine busy with training, 7 of 600 ticks
were late (issue 47), each waiting for a core, so up to 2 % late ticks are tolerated there, and only there.
"""

import json
import subprocess
import sys

import pytest

from hil_sim import report
from tests.hil.rig import REPO, subprocess_env
from tests.runtime.fakes import free_addresses

pytestmark = [pytest.mark.hil, pytest.mark.slow]


NORMAL_PRIORITY_LATE_SHARE = 0.02


def realtime_granted() -> bool:
    """Whether a process here may take SCHED_FIFO (asked in a child: pytest keeps its own priority)."""
    code = "from runtime.realtime import raise_priority; print(raise_priority()[1].startswith('real-time'))"
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO, env=subprocess_env(), capture_output=True,
                         text=True, timeout=30, check=True)
    return out.stdout.strip() == "True"


def test_sixty_seconds_at_10_hz_holds_the_rate(tmp_path):
    out = tmp_path / "report"
    camera, robot = free_addresses()
    cmd = [sys.executable, "-m", "hil_sim", "--seconds", "60", "--rate", "10", "--report", str(out),
           "--camera", camera, "--robot", robot]
    done = subprocess.run(cmd, cwd=REPO, env=subprocess_env(), capture_output=True, text=True, timeout=240)
    assert (out / "report.json").is_file(), (done.stdout + done.stderr)[-2000:]
    doc = json.loads((out / "report.json").read_text())
    allowed_late = 0 if realtime_granted() else int(NORMAL_PRIORITY_LATE_SHARE * doc["ticks"])
    assert doc["late_ticks"] <= allowed_late, report.table(doc)
    assert abs(doc["rate_hz_achieved"] - 10.0) <= 0.1, report.table(doc)
    assert doc["ticks"] >= 590 and doc["commands_received"] >= 590, report.table(doc)
    assert doc["runtime_exit"] == 0 and done.returncode == 0, (done.stdout + done.stderr)[-2000:]
    assert (out / "latency.png").stat().st_size > 0
