"""The control loop's scheduling request: real-time where granted, a raised nice value, else said once."""

import os
import subprocess
import sys

import pytest

from runtime import realtime


def _refuse(*_args) -> None:
    raise PermissionError("not permitted")


def test_no_permission_falls_back_to_nice_then_to_normal_priority(monkeypatch):
    monkeypatch.setattr(os, "sched_setscheduler", _refuse)
    granted: list[int] = []
    monkeypatch.setattr(os, "setpriority", lambda _which, _who, nice: granted.append(nice))
    assert realtime.raise_priority() == (True, f"raised priority nice {realtime.RAISED_NICE} "
                                                "(no permission for SCHED_FIFO)")
    assert granted == [realtime.RAISED_NICE]
    monkeypatch.setattr(os, "setpriority", _refuse)
    raised, words = realtime.raise_priority()
    assert not raised and words.startswith("normal scheduling priority")


def test_a_process_that_may_gets_sched_fifo_for_its_later_threads():
    code = ("import os, threading; from runtime.realtime import raise_priority; print(raise_priority()[1]); "
            "t = threading.Thread(target=lambda: print(os.sched_getscheduler(0) == os.SCHED_FIFO)); "
            "t.start(); t.join()")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=30, check=True)
    granted, thread_fifo = out.stdout.splitlines()
    if not granted.startswith("real-time"):
        pytest.skip(f"this machine grants no SCHED_FIFO: {granted}")
    assert thread_fifo == "True"
