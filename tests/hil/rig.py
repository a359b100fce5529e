"""HIL test rig: a recorder of the driver's state/status stream and a launcher of the real runtime."""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import zmq

from runtime.protocol import decode

REPO = Path(__file__).resolve().parents[2]
TIMEOUT = 20.0


@dataclass
class Sample:
    t: float
    q: np.ndarray
    holding: bool
    fault: str
    controller: str = ""


@dataclass
class StateLog:
    """Everything the driver publishes, time-stamped on arrival, recorded by a background thread."""

    address: str
    states: list[Sample] = field(default_factory=list)
    statuses: list[tuple[float, str, str]] = field(default_factory=list)

    def __post_init__(self) -> None:
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        ctx = zmq.Context()
        sub = ctx.socket(zmq.SUB)
        sub.setsockopt(zmq.SUBSCRIBE, b"")
        sub.connect(self.address)
        while not self._stop.is_set():
            if sub.poll(50):
                msg, t = decode(sub.recv_multipart()), time.monotonic()
                if msg.kind == "state":
                    self.states.append(Sample(t, np.array(msg["q"]), msg["holding"], msg["fault"],
                                              msg["controller"]))
                else:
                    self.statuses.append((t, msg["code"], msg["detail"]))
        sub.close(0)
        ctx.term()

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2.0)

    def wait(self, predicate, *, timeout: float = TIMEOUT, what: str = "condition") -> Sample:
        """The first new state satisfying ``predicate``."""
        start, end = len(self.states), time.monotonic() + timeout
        while time.monotonic() < end:
            for s in self.states[start:]:
                if predicate(s):
                    return s
            time.sleep(0.01)
        raise TimeoutError(f"no driver state with {what} within {timeout} s")

    def moving_for(self, seconds: float, *, timeout: float = TIMEOUT) -> None:
        """Wait until the arm has been commanded (not holding) for ``seconds`` in a row."""
        end = time.monotonic() + timeout
        while (now := time.monotonic()) < end:
            recent = [s for s in self.states if s.t > now - seconds]
            # The window must be covered from its start: a few non-holding states alone may be the tail of
            # the previous runtime's last command, before this test's runtime has even started.
            covered = len(recent) > 10 and recent[0].t < now - seconds + 0.05
            if covered and not any(s.holding for s in recent):
                return
            time.sleep(0.05)
        raise TimeoutError(f"the arm was never commanded for {seconds} s in a row within {timeout} s")

    def max_joint_step(self, since: float = 0.0) -> float:
        """Largest change of any joint between consecutive states (rad)."""
        qs = np.array([s.q for s in self.states if s.t >= since])
        return float(np.abs(np.diff(qs, axis=0)).max()) if len(qs) > 1 else 0.0

    def codes(self, since: float = 0.0) -> set[str]:
        return {code for t, code, _ in self.statuses if t >= since}


def subprocess_env() -> dict[str, str]:
    """The environment of a started process: the repository on its import path."""
    paths = [str(REPO), os.environ.get("PYTHONPATH", "")]
    return dict(os.environ, PYTHONPATH=os.pathsep.join(paths))


def start_runtime(model: Path, camera: str, robot: str, *, rate: float = 10.0, seconds: float = 30.0,
                  log: Path, metrics: Path | None = None) -> subprocess.Popen:
    cmd = [sys.executable, "-m", "runtime", "--model", str(model), "--camera", f"hil:{camera}",
           "--robot", robot, "--rate", str(rate), "--seconds", str(seconds)]
    if metrics is not None:
        cmd += ["--metrics", str(metrics)]
    return subprocess.Popen(cmd, cwd=REPO, env=subprocess_env(), stdout=open(log, "w"),
                            stderr=subprocess.STDOUT)
