"""CI's HIL gate: ``python -m hil_sim --seconds 60 --rate 10`` must hold the rate.

The runtime asks for SCHED_FIFO (runtime.realtime). Where the OS grants it, no job beside the test takes a
core from the loop, but a virtual machine's hypervisor still can: CI (2026-12-05, real-time granted) had 1
of 601 ticks late with the numpy preprocessing's p99 at 108 ms, 3 ms on an idle machine here, the loop
waiting for its core. So 0.5 % late ticks (3 of 600) are tolerated there. Where real-time is refused, the OS
also delays the loop behind other processes: measured at normal priority on a machine busy with training, 7
of 600 ticks were late (issue 47), so up to 2 % are tolerated. A loop too slow for 10 Hz misses most
inference ticks, one in four, far beyond either.
"""

import json
import subprocess
import sys

import pytest

from hil_sim import report
from tests.hil.rig import REPO, subprocess_env
from tests.runtime.fakes import free_addresses

pytestmark = [pytest.mark.hil, pytest.mark.slow]


REALTIME_LATE_SHARE = 0.005
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
    late_share = REALTIME_LATE_SHARE if realtime_granted() else NORMAL_PRIORITY_LATE_SHARE
    cmd = [sys.executable, "-m", "hil_sim", "--seconds", "60", "--rate", "10", "--report", str(out),
           "--camera", camera, "--robot", robot, "--late-share", str(late_share)]
    done = subprocess.run(cmd, cwd=REPO, env=subprocess_env(), capture_output=True, text=True, timeout=240)
    assert (out / "report.json").is_file(), (done.stdout + done.stderr)[-2000:]
    doc = json.loads((out / "report.json").read_text())
    assert doc["late_ticks_allowed"] == int(late_share * doc["ticks"]), report.table(doc)
    assert report.rate_held(doc), report.table(doc)
    assert abs(doc["rate_hz_achieved"] - 10.0) <= 0.1, report.table(doc)
    assert doc["ticks"] >= 590 and doc["commands_received"] >= 590, report.table(doc)
    assert doc["runtime_exit"] == 0 and done.returncode == 0, (done.stdout + done.stderr)[-2000:]
    assert (out / "latency.png").stat().st_size > 0
