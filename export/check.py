"""``python -m export.check student.onnx [--checkpoint CKPT] --json``: parity of onnxruntime against the
torch DDIM loop (diffusers' DDIMScheduler driving the checkpoint's network, same inputs and noise) and the
latency of both, measured in one process with the same thread count.

The file is opened exactly as the runtime opens it (``runtime.policy.Policy``). Torch parity and torch's
latency need the checkpoint and the [train] extra (torch); a clone has neither the checkpoint, which is not
shipped, nor, after ``make demo``, torch: there onnxruntime is compared with the torch actions recorded in
the file at export (``export.reference``) and timed alone. A file exported before references were recorded
says in one line that parity was not checked. A missing or unreadable file is one error line."""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import onnxruntime as ort

from export import reference
from export.reference import example_feeds, reference_actions
from runtime.metadata import PolicyMetadata
from runtime.policy import Policy, PolicyError, SessionConfig


class CheckError(RuntimeError):
    """The policy file and checkpoint do not belong together, or one of them cannot be found."""


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

    recorded = Path(meta.training_data.get("checkpoint", "")).expanduser()
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


def checkpoint_here(meta: PolicyMetadata, model_path: Path, given: Path | None) -> Path | None:
    """The checkpoint to run torch parity against, or None where torch (the [train] extra) or the
    checkpoint is not here; a checkpoint that is given must be found."""
    try:
        import torch  # noqa: F401
    except ImportError:
        if given:
            raise CheckError("--checkpoint needs torch (the [train] extra; `make test` installs it)") \
                from None
        return None
    return find_checkpoint(meta, model_path, given)


def run_check(model_path: Path, ckpt_path: Path | None = None, repeats: int = 30, threads: int = 2,
              trials: int = 3) -> dict:
    """Parity against the checkpoint where it is here, else against the reference actions recorded at export
    (``export.reference``), else none (a file exported before references were recorded); and latency."""
    policy = Policy(model_path, SessionConfig(threads, False))
    meta = policy.metadata
    ckpt = checkpoint_here(meta, model_path, ckpt_path)
    recorded = reference.recorded(policy.session.get_modelmeta().custom_metadata_map)
    doc = {"model": str(model_path), "ddim_steps": meta.ddim_steps, "ddim_spacing": meta.ddim_spacing,
           "threads": threads, "repeats": repeats, "parity_against": None, "parity_skipped": None,
           "max_abs_err": None, "torch_ms": None, "torch_p99_ms": None, "speedup": None}
    if ckpt is not None:
        ort_ms = _torch_parity(doc, policy, ckpt, repeats, threads, trials)
    else:
        feeds = example_feeds(meta, recorded[0] if recorded else reference.REFERENCE_SEED)
        if recorded is not None:
            got = policy.session.run(["actions"], feeds)[0]
            doc.update(parity_against="reference recorded at export",
                       max_abs_err=float(np.abs(got - recorded[1]).max()))
        else:
            name = Path(meta.training_data.get("checkpoint") or "(none recorded)").name
            doc["parity_skipped"] = (f"the file records no reference actions and its checkpoint {name} "
                                     "is not here; pass --checkpoint CKPT")
        ort_ms = timed(lambda: policy.session.run(["actions"], feeds), repeats)
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
        got = policy.session.run(["actions"], feeds)[0]
        errors.append(float(np.abs(got - reference_actions(net, meta, feeds)).max()))
    ort_ms, torch_ms = timed_side_by_side([lambda: policy.session.run(["actions"], feeds),
                                           lambda: reference_actions(net, meta, feeds)], repeats)
    doc.update(parity_against="checkpoint", max_abs_err=max(errors), torch_ms=statistics.median(torch_ms),
               torch_p99_ms=float(np.percentile(torch_ms, 99)),
               speedup=statistics.median(torch_ms) / statistics.median(ort_ms))
    return ort_ms


def summary(model: Path, report: dict) -> str:
    line = f"{model}: K={report['ddim_steps']} ort {report['ort_ms']:.2f} ms (p99 {report['ort_p99_ms']:.2f})"
    if report["max_abs_err"] is not None:
        line += f", max_abs_err {report['max_abs_err']:.2e} against the {report['parity_against']}"
    if report["torch_ms"] is not None:
        line += f", torch {report['torch_ms']:.2f} ms, speedup {report['speedup']:.2f}x"
    return line


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
    else:
        print(summary(args.model, report))
    return 0


if __name__ == "__main__":
    sys.exit(main())
