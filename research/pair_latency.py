"""What two encoders a step would cost at deploy: one policy file against two copies run in parallel threads
(one intra-op thread each, as a graph with two parallel branches would run) and in turn, side by side in
onnxruntime on this machine (issue 42: `ensemble_readout.py`'s pair of readouts against the 25 ms p99 budget).

    python research/pair_latency.py [models/student.onnx] [--repeats 60] [--no-spin]

``--no-spin`` turns off onnxruntime's spin-waiting threads (on by default, as the runtime runs).
"""

from __future__ import annotations

import argparse
import threading
import time
from pathlib import Path

import numpy as np
import onnxruntime as ort


def session(path: Path, threads: int, spin: bool) -> ort.InferenceSession:
    options = ort.SessionOptions()
    options.intra_op_num_threads, options.inter_op_num_threads = threads, 1
    options.add_session_config_entry("session.intra_op.allow_spinning", "1" if spin else "0")
    return ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])


def timed(fn, repeats: int) -> tuple[float, float]:
    """Median and p99 of ``fn``'s wall time, ms, after 5 warm-up calls."""
    for _ in range(5):
        fn()
    ms = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        ms.append((time.perf_counter() - start) * 1000)
    return float(np.median(ms)), float(np.percentile(ms, 99))


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("model", type=Path, nargs="?", default=Path("models/student.onnx"))
    p.add_argument("--repeats", type=int, default=60)
    p.add_argument("--no-spin", action="store_true")
    args = p.parse_args()
    spin = not args.no_spin
    one, a, b = session(args.model, 2, spin), session(args.model, 1, spin), session(args.model, 1, spin)
    inputs = {i.name: np.random.default_rng(0).random([d if isinstance(d, int) else 1 for d in i.shape],
                                                      dtype=np.float32) for i in one.get_inputs()}

    def parallel() -> None:
        other = threading.Thread(target=a.run, args=(None, inputs))
        other.start()
        b.run(None, inputs)
        other.join()

    runs = {"one file, 2 threads": lambda: one.run(None, inputs), "two in parallel threads, 1 each": parallel,
            "two in turn, 2 threads": lambda: (one.run(None, inputs), one.run(None, inputs))}
    for _ in range(2):  # twice, interleaved, so that a drift of the machine shows
        for name, fn in runs.items():
            print(f"{name}: median %.1f ms, p99 %.1f ms" % timed(fn, args.repeats))


if __name__ == "__main__":
    main()
