"""``python -m export.check student.onnx [--checkpoint CKPT] --json``: parity of onnxruntime against the
torch DDIM loop (diffusers' DDIMScheduler driving the checkpoint's network, same inputs and noise) and the
latency of both, measured in one process with the same thread count.

The file is opened exactly as the runtime opens it (``runtime.policy.Policy``). Parity needs the checkpoint
and the [train] extra (torch); a clone has neither the checkpoint, which is not shipped, nor, after
``make demo``, torch: then parity is reported as not checked, in one line, and the latency of onnxruntime
alone is measured. A missing or unreadable file is one error line."""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import onnxruntime as ort

from runtime.metadata import PolicyMetadata
from runtime.policy import Policy, PolicyError, SessionConfig

if TYPE_CHECKING:
    import torch

    from trainer.student.model import StudentPolicy


class CheckError(RuntimeError):
    """The policy file and checkpoint do not belong together, or one of them cannot be found."""


def reference_actions(policy: StudentPolicy, meta: PolicyMetadata, depth: torch.Tensor, state: torch.Tensor,
                      noise: torch.Tensor) -> torch.Tensor:
    """The eager torch loop the graph must reproduce: diffusers' DDIM steps, then robot units."""
    import torch

    from trainer.student.ddim import reference_scheduler

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
    """A plain CPU session with ``threads`` intra-op threads (export.quantize times its variants with it)."""
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


def find_checkpoint(meta: PolicyMetadata, model_path: Path, given: Path | None) -> Path | None:
    """The checkpoint the file was exported from: ``given``, else the path in its metadata, else a file of
    that name beside the model. None when none is found and none was given (a clone: not shipped)."""
    from trainer.student import checkpoint

    recorded = Path(meta.training_data.get("checkpoint", ""))
    candidates = [given] if given else [recorded, model_path.parent / recorded.name]
    path = next((c for c in candidates if c.name and c.is_file()), None)
    if path is None:
        if given:
            raise CheckError(f"checkpoint {str(given)!r} not found")
        return None
    want = meta.training_data.get("checkpoint_sha256")
    if want and checkpoint.sha256(path) != want:
        raise CheckError(f"checkpoint {path} does not match the one this policy was exported from (sha256)")
    return path


def example_feeds(meta: PolicyMetadata, seed: int = 0) -> dict[str, np.ndarray]:
    """Random inputs of the graph's static shapes: depth in [0, 1] with 10 % holes, state, start noise."""
    rng, shapes = np.random.default_rng(seed), meta.input_shapes()
    depth = rng.random(shapes["depth"], dtype=np.float32)
    depth[rng.random(shapes["depth"]) < 0.1] = meta.preprocess.invalid_value
    return {"depth": depth, "state": (rng.standard_normal(shapes["state"]) * 0.5).astype(np.float32),
            "noise": rng.standard_normal(shapes["noise"], dtype=np.float32)}


def parity_skipped(meta: PolicyMetadata, model_path: Path, given: Path | None) -> tuple[Path | None, str]:
    """(checkpoint, "") when parity can be checked here, else (None, why not, in words)."""
    try:
        import torch  # noqa: F401  (the [train] extra)
    except ImportError:
        return None, "torch is not installed (the [train] extra: `make test` installs it)"
    ckpt = find_checkpoint(meta, model_path, given)
    if ckpt is None:
        recorded = meta.training_data.get("checkpoint") or "(none recorded)"
        return None, f"its checkpoint {Path(recorded).name} is not shipped; pass --checkpoint CKPT"
    return ckpt, ""


def run_check(model_path: Path, ckpt_path: Path | None = None, repeats: int = 30, threads: int = 2,
              trials: int = 3) -> dict:
    policy = Policy(model_path, SessionConfig(threads, False))
    meta = policy.metadata
    ckpt, skipped = parity_skipped(meta, model_path, ckpt_path)
    feeds = example_feeds(meta)

    def run_ort() -> np.ndarray:
        return policy.session.run(["actions"], feeds)[0]

    doc = {"model": str(model_path), "ddim_steps": meta.ddim_steps, "ddim_spacing": meta.ddim_spacing,
           "threads": threads, "repeats": repeats, "parity_skipped": skipped or None}
    if ckpt is None:
        ort_ms = timed(run_ort, repeats)
        doc.update(max_abs_err=None, torch_ms=None, torch_p99_ms=None, speedup=None)
    else:
        ort_ms = _torch_parity(doc, policy, ckpt, repeats, threads, trials)
    doc.update(ort_ms=statistics.median(ort_ms), ort_p99_ms=float(np.percentile(ort_ms, 99)),
               metadata=json.loads(meta.to_json()))
    return doc


def _torch_parity(doc: dict, policy: Policy, ckpt: Path, repeats: int, threads: int,
                  trials: int) -> list[float]:
    """Fill ``doc`` with the parity error and torch's latency; return onnxruntime's latency (ms per call),
    the two timed side by side."""
    import torch

    from trainer.student import checkpoint

    try:
        net, meta = checkpoint.load(ckpt).policy(), policy.metadata
    except checkpoint.CheckpointError as exc:
        raise CheckError(str(exc)) from None
    torch.set_num_threads(threads)
    errors = []
    for seed in range(trials):
        feeds = example_feeds(meta, seed)
        depth, state, noise = (torch.from_numpy(feeds[k]) for k in ("depth", "state", "noise"))
        got = policy.session.run(["actions"], feeds)[0]
        errors.append(float(np.abs(got - reference_actions(net, meta, depth, state, noise).numpy()).max()))
    ort_ms, torch_ms = timed_side_by_side([lambda: policy.session.run(["actions"], feeds),
                                           lambda: reference_actions(net, meta, depth, state, noise)],
                                          repeats)
    doc.update(max_abs_err=max(errors), torch_ms=statistics.median(torch_ms),
               torch_p99_ms=float(np.percentile(torch_ms, 99)),
               speedup=statistics.median(torch_ms) / statistics.median(ort_ms))
    return ort_ms


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
    except (CheckError, PolicyError) as exc:
        print(f"export.check: {exc}", file=sys.stderr)
        return 2
    if report["parity_skipped"]:
        print(f"export.check: parity not checked: {report['parity_skipped']}; latency of onnxruntime only",
              file=sys.stderr)
    if args.json:
        print(json.dumps(report))
    elif report["max_abs_err"] is None:
        print(f"{args.model}: K={report['ddim_steps']} ort {report['ort_ms']:.2f} ms (p99 "
              f"{report['ort_p99_ms']:.2f})")
    else:
        print(f"{args.model}: K={report['ddim_steps']} max_abs_err={report['max_abs_err']:.2e} "
              f"ort {report['ort_ms']:.2f} ms, torch {report['torch_ms']:.2f} ms, "
              f"speedup {report['speedup']:.2f}x")
    return 0

if __name__ == "__main__":
    sys.exit(main())
