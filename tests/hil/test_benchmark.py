"""CI's HIL gate: ``python -m hil_sim --seconds 60 --rate 10`` must hold the rate with every deadline met."""

import json
import subprocess
import sys

import pytest

from hil_sim import report
from tests.hil.rig import REPO, subprocess_env
from tests.runtime.fakes import free_port_pair

pytestmark = [pytest.mark.hil, pytest.mark.slow]


def test_sixty_seconds_at_10_hz_holds_the_rate(tmp_path):
    out = tmp_path / "report"
    cmd = [sys.executable, "-m", "hil_sim", "--seconds", "60", "--rate", "10", "--report", str(out),
           "--camera", f"tcp://127.0.0.1:{free_port_pair()}", "--robot", f"tcp://127.0.0.1:{free_port_pair()}"]
    done = subprocess.run(cmd, cwd=REPO, env=subprocess_env(), capture_output=True, text=True, timeout=240)
    assert (out / "report.json").is_file(), (done.stdout + done.stderr)[-2000:]
    doc = json.loads((out / "report.json").read_text())
    assert doc["late_ticks"] == 0, report.table(doc)
    assert abs(doc["rate_hz_achieved"] - 10.0) <= 0.1, report.table(doc)
    assert doc["ticks"] >= 590 and doc["commands_received"] >= 590, report.table(doc)
    assert doc["runtime_exit"] == 0 and done.returncode == 0, (done.stdout + done.stderr)[-2000:]
    assert (out / "latency.png").stat().st_size > 0
