"""The real `runtime` process against the in-test fake camera + driver (not a test; run by hand).

    nice -n 10 python -m tests.runtime.bench_loop --model student.onnx --seconds 30 --rate 10 --fps 30

Prints ticks, late/skipped counts and p50/p99/max of frame age (capture -> inference start), latency
(frame received by the runtime -> command received by the driver), capture -> command, and inference time,
from the runtime's --metrics file joined with the fake driver's receive times. hil_sim's report is the
full-system version of this; this one isolates the runtime (no simulator on the cores).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from tests.runtime.fakes import FakeWorld


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--model", required=True)
    p.add_argument("--seconds", type=float, default=30.0)
    p.add_argument("--rate", type=float, default=10.0)
    p.add_argument("--fps", type=float, default=30.0, help="fake camera frame rate")
    p.add_argument("--out", type=Path, help="write the summary JSON here")
    args = p.parse_args(argv)
    metrics = Path(tempfile.mkdtemp()) / "metrics.jsonl"
    with FakeWorld(args.fps) as world:
        proc = subprocess.run([sys.executable, "-m", "runtime", "--model", args.model, "--camera",
                               f"hil:{world.camera}", "--robot", world.robot, "--rate", str(args.rate),
                               "--seconds", str(args.seconds), "--metrics", str(metrics)],
                              capture_output=True, text=True, timeout=args.seconds + 60)
        time.sleep(0.2)
    print(proc.stderr.strip().splitlines()[-1])
    summary = _summary([json.loads(line) for line in metrics.read_text().splitlines()],
                       {c["seq"]: c["t_receive"] for c in world.commands})
    print(json.dumps(summary, indent=1))
    if args.out:
        args.out.write_text(json.dumps(summary, indent=2))
    return proc.returncode


def _summary(ticks: list[dict], received: dict[int, float]) -> dict:
    delivered = [t for t in ticks if t["cmd_seq"] is not None and t["cmd_seq"] in received]
    sent = [t for t in delivered if not t["hold"]]
    inferred = [t for t in sent if t["t_inference"] is not None]
    span = ticks[-1]["deadline"] - ticks[0]["deadline"]
    return {"ticks": len(ticks), "late": sum(t["late"] for t in ticks),
            "skipped": sum(t["skipped"] for t in ticks),
            "holds": len(delivered) - len(sent),
            "statuses": sorted({t["status"] for t in ticks if t["status"]}),
            "rate_hz_achieved": (len(delivered) - 1) / (delivered[-1]["t_send"] - delivered[0]["t_send"]),
            "rate_hz_deadlines": (len(ticks) - 1) / span,
            "frame_age_ms": _stats([t["t_preprocess"] - t["t_capture"] for t in inferred]),
            "latency_ms": _stats([received[t["cmd_seq"]] - t["t_receive"] for t in inferred]),
            "capture_to_command_ms": _stats([received[t["cmd_seq"]] - t["t_capture"] for t in inferred]),
            "inference_ms": _stats([t["t_inference"] - t["t_preprocess"] for t in inferred]),
            "all_ticks_latency_ms": _stats([received[t["cmd_seq"]] - t["t_receive"] for t in sent])}


def _stats(seconds: list[float]) -> dict:
    ms = np.array(seconds) * 1e3
    return {"n": len(ms), "p50": round(float(np.median(ms)), 2),
            "p99": round(float(np.percentile(ms, 99)), 2), "max": round(float(ms.max()), 2)}


if __name__ == "__main__":
    raise SystemExit(main())
