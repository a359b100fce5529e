"""What the runtime and the driver ask of the OS: real-time scheduling where granted, and a clean stop.

Their control threads run under SCHED_FIFO so that a CPU-bound job beside them (a training run, a compiler)
cannot delay a tick past its deadline: at normal priority a busy 2-core machine missed 7 of 600 deadlines
(issue 47), always waiting for a core, never for its own work. Without the permission (CAP_SYS_NICE or an
rtprio limit) the next best is a raised nice value; without that, normal priority, said once.
"""

from __future__ import annotations

import os
import signal
import sys
import threading

FIFO_PRIORITY = 10  # low among real-time priorities: above every normal process, below threaded IRQs (50)
RAISED_NICE = -10


def raise_priority() -> tuple[bool, str]:
    """Ask for SCHED_FIFO for this thread and the threads it starts later (they inherit it), else a raised
    nice value. Returns (whether anything was raised, what was granted in words); never raises."""
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(FIFO_PRIORITY))
        return True, f"real-time scheduling SCHED_FIFO priority {FIFO_PRIORITY}"
    except (OSError, AttributeError):  # no permission; AttributeError: a platform without sched_* calls
        pass
    try:
        os.setpriority(os.PRIO_PROCESS, 0, RAISED_NICE)
        return True, f"raised priority nice {RAISED_NICE} (no permission for SCHED_FIFO)"
    except OSError:
        return False, ("normal scheduling priority: no permission for SCHED_FIFO or a raised nice value "
                       "(grant CAP_SYS_NICE or an rtprio limit); deadlines may slip on a busy machine")


def announce_priority(prog: str) -> None:
    """``raise_priority`` and say what was granted, as ``prog``."""
    raised, granted = raise_priority()
    print(f"{prog}: {'' if raised else 'WARNING '}{granted}", file=sys.stderr, flush=True)


def stop_on_signals() -> threading.Event:
    """An event that SIGINT and SIGTERM set: the process ends its loop cleanly instead of dying in it."""
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    return stop
