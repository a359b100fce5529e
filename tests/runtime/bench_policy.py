"""Policy latency under deploy-like load, per onnxruntime setting (not a test; run by hand).

    nice -n 10 python -m tests.runtime.bench_policy --model student.onnx [other.onnx ...] \
        --out runs/runtime/bench.json

Load while timing: a camera process publishing 848x480 depth at 30 Hz and a driver process publishing robot
state at 200 Hz, both over ZeroMQ loopback, and in this process a thread doing the runtime's receive work
(newest-frame drain, decode, preprocess, state drain). Settings (and models, where several are given) are
interleaved call by call (in a fresh random order each round) so a change in the machine's other load hits all
of them alike; each model after the first is reported as its per-round time ratio to the first's.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import random
import threading
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from runtime.cameras.hil import HilCamera
from runtime.loop import RobotLink
from runtime.policy import Policy, SessionConfig
from runtime.preprocess import DepthSpec, preprocess
from runtime.protocol import Encoder

CONFIGS = [SessionConfig(t, s) for t in (1, 2) for s in (False, True)]


def _camera(address: str, stop) -> None:
    import zmq

    pub, enc = zmq.Context().socket(zmq.PUB), Encoder()
    pub.bind(address)
    depth = np.random.default_rng(0).integers(0, 3000, (480, 848), dtype=np.uint16)
    i, start = 0, time.monotonic()
    while not stop.is_set():
        time.sleep(max(0.0, start + i / 30 - time.monotonic()))
        pub.send_multipart(enc.depth(depth, t_capture=time.monotonic(), frame_number=i, depth_scale=0.001))
        i += 1


def _driver(address: str, stop) -> None:
    import zmq

    from runtime.protocol import robot_endpoints

    state_ep, command_ep = robot_endpoints(address)
    ctx = zmq.Context()
    pub, pull, enc = ctx.socket(zmq.PUB), ctx.socket(zmq.PULL), Encoder()
    pub.bind(state_ep)
    pull.bind(command_ep)
    i, start = 0, time.monotonic()
    while not stop.is_set():
        time.sleep(max(0.0, start + i / 200 - time.monotonic()))
        pub.send_multipart(enc.encode("state", t_capture=time.monotonic(), q=[0.0] * 7, dq=[0.0] * 7,
                                      gripper=0.04, holding=False, fault="", controller=""))
        i += 1


def _receiver(camera: HilCamera, robot: RobotLink, spec: DepthSpec, stop: threading.Event, counts: dict):
    while not stop.is_set():
        frame = camera.poll(0.01)
        if frame is not None:
            preprocess(frame.depth, frame.depth_scale, spec)
            counts["frames"] += 1
        if robot.poll(0.0) is not None:
            counts["states"] += 1


def _time(policy: Policy) -> tuple[float, float]:
    """(wall, process CPU) seconds of one call; CPU includes the receiver thread's share of that time."""
    shapes = policy.metadata.input_shapes()
    depth = np.random.default_rng(1).random(shapes["depth"][1:], dtype=np.float32)
    cpu, wall = time.process_time(), time.perf_counter()
    policy(depth, np.zeros(8, np.float32))
    return time.perf_counter() - wall, time.process_time() - cpu


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--model", required=True, nargs="+", help="policy files, timed side by side")
    p.add_argument("--rounds", type=int, default=100, help="timed calls per setting")
    p.add_argument("--out", type=Path)
    args = p.parse_args(argv)
    spawn = mp.get_context("spawn")
    stop_procs = spawn.Event()
    cam_addr, robot_addr = "tcp://127.0.0.1:25555", "tcp://127.0.0.1:25556"
    procs = [spawn.Process(target=f, args=(a, stop_procs), daemon=True)
             for f, a in ((_camera, cam_addr), (_driver, robot_addr))]
    for proc in procs:
        proc.start()
    # by position, not path: a model given twice is an A/A run
    keys = [(i, c) for i in range(len(args.model)) for c in CONFIGS]
    policies = {(i, c): Policy(args.model[i], c) for i, c in keys}
    spec = next(iter(policies.values())).metadata.preprocess
    stop, counts = threading.Event(), {"frames": 0, "states": 0}
    links = (HilCamera(spec, cam_addr), RobotLink(robot_addr))
    receiver = threading.Thread(target=_receiver, args=(*links, spec, stop, counts), daemon=True)
    receiver.start()
    results = {k: {"s": [], "cpu": []} for k in keys}
    started = time.monotonic()
    for policy in policies.values():
        policy.warmup(3)
    for _ in tqdm(range(args.rounds), desc="rounds"):
        for key in random.sample(keys, len(keys)):
            wall, cpu = _time(policies[key])
            results[key]["s"].append(wall)
            results[key]["cpu"].append(cpu)
    elapsed = time.monotonic() - started
    stop.set()
    stop_procs.set()
    report = {"models": args.model, "frames_per_s": counts["frames"] / elapsed,
              "states_per_s": counts["states"] / elapsed,
              "settings": [{"model": args.model[i], "ddim_steps": policies[i, c].metadata.ddim_steps,
                            **_row(c, results[i, c], results[0, c])} for i, c in keys]}
    print(f"receiver: {report['frames_per_s']:.1f} frames/s, {report['states_per_s']:.0f} states/s")
    print("| model | intra-op threads | spinning | median ms | p90 ms | p99 ms | CPU ms/call | x the first |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- |")
    for row in report["settings"]:
        print(f"| {Path(row['model']).name} | {row['threads']} | {'on' if row['spinning'] else 'off'} | "
              f"{row['median_ms']:.2f} | {row['p90_ms']:.2f} | {row['p99_ms']:.2f} | "
              f"{row['cpu_ms_per_call']:.2f} | {row['ratio_to_first_median']:.2f} |")
    if args.out:
        args.out.write_text(json.dumps(report, indent=2))
    return 0


def _row(config: SessionConfig, r: dict, first: dict) -> dict:
    """One (model, setting)'s times; its ratio to the first model's, round by round (under the same load)."""
    ms = np.array(r["s"]) * 1e3
    return {"threads": config.intra_op_threads, "spinning": config.allow_spinning, "calls": len(ms),
            "median_ms": float(np.median(ms)), "p90_ms": float(np.percentile(ms, 90)),
            "p99_ms": float(np.percentile(ms, 99)), "cpu_ms_per_call": float(np.median(r["cpu"]) * 1e3),
            "ratio_to_first_median": float(np.median(np.array(r["s"]) / np.array(first["s"])))}


if __name__ == "__main__":
    raise SystemExit(main())
