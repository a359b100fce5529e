"""``python -m export.check student.onnx [--checkpoint CKPT] --json``: parity of onnxruntime against the
torch DDIM loop (diffusers' DDIMScheduler driving the checkpoint's network, same inputs and noise) and the
latency of both, measured in one process with the same thread count."""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import onnx
import onnxruntime as ort
import torch

from export.graph import example_inputs, read_metadata
from runtime.metadata import MetadataError, PolicyMetadata
from trainer.student import checkpoint
from trainer.student.ddim import reference_scheduler
from trainer.student.model import StudentPolicy


class CheckError(RuntimeError):
    """The policy file and checkpoint do not belong together, or one of them cannot be found."""


def reference_actions(policy: StudentPolicy, meta: PolicyMetadata, depth: torch.Tensor, state: torch.Tensor,
                      noise: torch.Tensor) -> torch.Tensor:
    """The eager torch loop the graph must reproduce: diffusers' DDIM steps, then robot units."""
    sched = reference_scheduler(policy.config.train_timesteps, meta.ddim_steps, meta.ddim_spacing,
                                policy.config.prediction)
    with torch.no_grad():
        obs = policy.encode(depth, state)
        x = noise
        for t in sched.timesteps:
            x = sched.step(policy(x, t.expand(x.shape[0]), obs), t, x).prev_sample
        actions = policy.action_norm.unnormalise(x)
    actions[..., :7] *= meta.action_scale
    return actions


def session(path: Path, threads: int) -> ort.InferenceSession:
    opts = ort.SessionOptions()
    opts.intra_op_num_threads = threads
    opts.inter_op_num_threads = 1
    return ort.InferenceSession(str(path), opts, providers=["CPUExecutionProvider"])


def timed(fn: Callable[[], object], repeats: int, warmup: int = 3) -> list[float]:
    return timed_side_by_side([fn], repeats, warmup)[0]


def timed_side_by_side(fns: list[Callable[[], object]], repeats: int, warmup: int = 3) -> list[list[float]]:
    """Milliseconds per call of each function, calls interleaved so that load from other processes on
    this shared machine hits every contender alike."""
    for _ in range(warmup):
        for fn in fns:
            fn()
    times: list[list[float]] = [[] for _ in fns]
    for _ in range(repeats):
        for fn, out in zip(fns, times, strict=True):
            start = time.perf_counter()
            fn()
            out.append((time.perf_counter() - start) * 1e3)
    return times


def find_checkpoint(meta: PolicyMetadata, given: Path | None) -> Path:
    path = given or Path(meta.training_data.get("checkpoint", ""))
    if not path.is_file():
        raise CheckError(f"checkpoint {str(path)!r} not found: pass --checkpoint")
    want = meta.training_data.get("checkpoint_sha256")
    if want and checkpoint.sha256(path) != want:
        raise CheckError(f"checkpoint {path} does not match the one this policy was exported from (sha256)")
    return path


def run_check(model_path: Path, ckpt_path: Path | None = None, repeats: int = 30, threads: int = 2,
              trials: int = 3) -> dict:
    meta = read_metadata(onnx.load(str(model_path)))
    policy = checkpoint.load(find_checkpoint(meta, ckpt_path)).policy()
    torch.set_num_threads(threads)
    sess = session(model_path, threads)
    errors = []
    for seed in range(trials):
        depth, state, noise = example_inputs(meta, seed)
        feeds = {"depth": depth.numpy(), "state": state.numpy(), "noise": noise.numpy()}
        got = sess.run(["actions"], feeds)[0]
        errors.append(float(np.abs(got - reference_actions(policy, meta, depth, state, noise).numpy()).max()))
    ort_ms, torch_ms = timed_side_by_side([lambda: sess.run(["actions"], feeds),
                                           lambda: reference_actions(policy, meta, depth, state, noise)],
                                          repeats)
    return {"model": str(model_path), "max_abs_err": max(errors), "ddim_steps": meta.ddim_steps,
            "ddim_spacing": meta.ddim_spacing, "threads": threads, "repeats": repeats,
            "ort_ms": statistics.median(ort_ms), "ort_p99_ms": float(np.percentile(ort_ms, 99)),
            "torch_ms": statistics.median(torch_ms), "torch_p99_ms": float(np.percentile(torch_ms, 99)),
            "speedup": statistics.median(torch_ms) / statistics.median(ort_ms),
            "metadata": json.loads(meta.to_json())}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m export.check", description=__doc__.split("\n\n")[0])
    p.add_argument("model", type=Path, help="student.onnx to check")
    p.add_argument("--checkpoint", type=Path, help="checkpoint it came from (default: path in its metadata)")
    p.add_argument("--repeats", type=int, default=30, help="timed runs of each backend (median reported)")
    p.add_argument("--threads", type=int, default=2, help="intra-op threads for both backends")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of a summary")
    args = p.parse_args(argv)
    try:
        report = run_check(args.model, args.checkpoint, args.repeats, args.threads)
    except (CheckError, checkpoint.CheckpointError, MetadataError) as exc:
        print(f"export.check: {exc}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps(report))
    else:
        print(f"{args.model}: K={report['ddim_steps']} max_abs_err={report['max_abs_err']:.2e} "
              f"ort {report['ort_ms']:.2f} ms, torch {report['torch_ms']:.2f} ms, "
              f"speedup {report['speedup']:.2f}x")
    return 0


if __name__ == "__main__":
    sys.exit(main())
