"""Hostile-input probe of the driver process (issue 44's table, driver rows), run by hand:

    python -m tests.hil.probe_link [--flood-s 5] [--kills 10]

Starts ``python -m hil_sim.driver`` on a free loopback port and, as separate
senders, throws at it: a header nested 1,000 deep, a garbage flood, a second controller, an out-of-order
command, and a controller that falls silent (the watchdog: time from its last command to the first holding
state, repeated). Prints one JSON document: each row's outcome, the driver's state rate before and during the
flood, the statuses it published meanwhile, the watchdog reaction times and the driver's RSS before/after.
Exit 0 only when every row held.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import msgpack
import numpy as np
import zmq

from runtime.protocol import Encoder, robot_endpoints
from tests.hil.rig import REPO, StateLog, subprocess_env
from tests.runtime.fakes import free_port_pair


def rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


class Sender:
    """One command sender: its own socket, session and sequence numbers."""

    def __init__(self, ctx: zmq.Context, address: str, session: str) -> None:
        self.push = ctx.socket(zmq.PUSH)
        self.push.linger = 0
        self.push.connect(robot_endpoints(address)[1])
        self.enc, self.session = Encoder(), session

    def command(self, q, *, valid_for: float = 0.15, seq: int | None = None) -> None:
        if seq is not None:
            self.enc.seq = seq
        now, target = time.monotonic(), [float(v) for v in q]
        self.push.send_multipart(self.enc.encode("command", t_capture=now, q_target=target, gripper=-1.0,
                                                 deadline=now + valid_for, session=self.session))


def state_rate(log: StateLog, seconds: float) -> tuple[float, int]:
    """States per second over the next ``seconds``, and the statuses published meanwhile."""
    n0, s0, t0 = len(log.states), len(log.statuses), time.monotonic()
    time.sleep(seconds)
    return (len(log.states) - n0) / (time.monotonic() - t0), len(log.statuses) - s0


def nested_row(log: StateLog, bad: Sender) -> dict:
    value: list = []
    for _ in range(1000):
        value = [value]
    raw = msgpack.packb({"v": 2, "kind": "command", "seq": value})
    t0 = time.monotonic()
    bad.push.send_multipart([raw, b""])
    log.wait(lambda s: s.t > t0 + 0.2, timeout=5, what="states after the nested message")
    return {"bytes": len(raw), "held": "bad_message" in log.codes(t0)}


def flood_row(log: StateLog, address: str, seconds: float) -> dict:
    normal, _ = state_rate(log, 2.0)
    code = ("import sys, time, zmq\n"
            "push = zmq.Context().socket(zmq.PUSH); push.connect(sys.argv[1]); n = 0\n"
            "end = time.monotonic() + float(sys.argv[2])\n"
            "while time.monotonic() < end: push.send_multipart([b'\\xc1garbage', b'']); n += 1\n"
            "print(n)\n")
    flood = subprocess.Popen([sys.executable, "-c", code, robot_endpoints(address)[1], str(seconds)],
                             stdout=subprocess.PIPE, text=True)
    time.sleep(0.5)
    flooded, statuses = state_rate(log, seconds - 1.0)
    sent = int(flood.communicate()[0] or 0)
    return {"messages_sent": sent, "state_hz_normal": round(normal, 1), "state_hz_flooded": round(flooded, 1),
            "statuses_published": statuses, "status_per_s": round(statuses / (seconds - 1.0), 1),
            "held": flooded >= 0.9 * normal}


def second_controller_row(log: StateLog, owner: Sender, intruder: Sender) -> dict:
    q0 = log.states[-1].q.copy()
    t0 = time.monotonic()
    while time.monotonic() < t0 + 1.0:  # the owner says 'stay', the intruder 'joint 0 -0.5 rad'
        owner.command(q0)
        intruder.command(q0 - np.eye(7)[0] * 0.5)
        time.sleep(0.01)
    moved = float(np.abs(np.array([s.q for s in log.states if s.t > t0]) - q0).max())
    refused = "not_controller" in log.codes(t0)
    return {"max_joint_motion_rad": round(moved, 5), "held": moved < 1e-3 and refused}


def out_of_order_row(log: StateLog, owner: Sender) -> dict:
    q0 = log.states[-1].q.copy()
    t0 = time.monotonic()
    owner.command(q0, valid_for=1.0, seq=owner.enc.seq + 10)  # the newer one first ...
    owner.command(q0 - np.eye(7)[0] * 0.3, valid_for=1.0, seq=owner.enc.seq - 5)  # ... then an older target
    time.sleep(0.5)
    owner.enc.seq += 20  # past the newer one again, for the rows that follow
    moved = float(np.abs(np.array([s.q for s in log.states if s.t > t0]) - q0).max())
    return {"max_joint_motion_rad": round(moved, 5), "held": moved < 1e-3 and "out_of_order" in log.codes(t0)}


def watchdog_row(log: StateLog, owner: Sender, kills: int) -> dict:
    reactions = []
    for _ in range(kills):
        q0 = log.states[-1].q.copy()
        for _ in range(10):  # 10 Hz commands for 1 s, then silence
            owner.command(q0, valid_for=10.0)  # a far deadline: the driver's age cap must still stop it
            time.sleep(0.1)
        t_last = time.monotonic()
        owner.command(q0, valid_for=10.0)
        held = log.wait(lambda s, t=t_last: s.holding and s.t > t, timeout=5, what="holding")
        reactions.append(1e3 * (held.t - t_last))
        time.sleep(0.3)
    return {"reaction_ms": [round(r, 1) for r in reactions], "max_ms": round(max(reactions), 1),
            "held": max(reactions) < 250}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--flood-s", type=float, default=5.0)
    p.add_argument("--kills", type=int, default=10)
    args = p.parse_args(argv)
    address = f"tcp://127.0.0.1:{free_port_pair()}"
    driver = subprocess.Popen([sys.executable, "-m", "hil_sim.driver", "--bind",
                               address], cwd=REPO, env=subprocess_env(), stderr=subprocess.DEVNULL)
    log, ctx = StateLog(address), zmq.Context()
    try:
        log.wait(lambda s: True, timeout=60, what="a first state")
        time.sleep(1.0)
        rss_before = rss_mb(driver.pid)
        owner, intruder = Sender(ctx, address, "owner" * 4), Sender(ctx, address, "intruder" * 4)
        rows = {"nested_1000": nested_row(log, intruder),
                "garbage_flood": flood_row(log, address, args.flood_s),
                "second_controller": second_controller_row(log, owner, intruder),
                "out_of_order": out_of_order_row(log, owner),
                "watchdog": watchdog_row(log, owner, args.kills)}
        alive = driver.poll() is None
        doc = {"rows": rows, "driver_alive": alive, "rss_mb_before": round(rss_before, 1),
               "rss_mb_after": round(rss_mb(driver.pid), 1) if alive else None}
    finally:
        driver.terminate()
        driver.wait(10)
        log.close()
        ctx.destroy(linger=0)
    print(json.dumps(doc, indent=2))
    return 0 if alive and all(r["held"] for r in rows.values()) else 1


if __name__ == "__main__":
    raise SystemExit(main())
