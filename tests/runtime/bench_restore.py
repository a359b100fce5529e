"""Per-tick cost of the runtime's hole restoration on real D4xx frames (not a test; run by hand).

    nice -n 10 python -m tests.runtime.bench_restore --repeats 200

Times ``runtime.preprocess.preprocess`` (crop + resize + restoration + normalisation: the runtime's whole
per-tick preprocessing) with each ``--restore`` method, interleaved frame by frame in one run so both
see the same machine load, on the D4xx captures of ``../shared/data/real_depth`` at their own stream size.
Prints median / p99 per method and the median of the per-frame ratios inpaint / none.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from runtime.preprocess import RESTORE_METHODS, preprocess
from trainer.ddg.data import crop_spec, load_real_dir

REAL = Path(__file__).resolve().parents[3] / "shared" / "data" / "real_depth"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--real", type=Path, default=REAL, help="real capture folder (default %(default)s)")
    p.add_argument("--repeats", type=int, default=200, help="passes over the frames")
    p.add_argument("--out", type=Path, help="write the summary JSON here")
    args = p.parse_args(argv)
    frames = [(f.depth_mm, crop_spec(*f.depth_mm.shape)) for f in load_real_dir(args.real)]
    times: dict[str, list[float]] = {m: [] for m in RESTORE_METHODS}
    for _ in range(args.repeats):
        for depth, spec in frames:
            for method in RESTORE_METHODS:
                start = time.perf_counter()
                preprocess(depth, 0.001, spec, restore=method)
                times[method].append(time.perf_counter() - start)
    ms = {m: np.array(t) * 1e3 for m, t in times.items()}
    summary = {"frames": len(frames), "repeats": args.repeats,
               "holes_in_policy_view": round(float(np.mean([np.mean(preprocess(d, 0.001, s) < 0)
                                                             for d, s in frames])), 4),
               **{f"{m}_ms": _stats(v) for m, v in ms.items()},
               "ratio_inpaint_over_none_p50": round(float(np.median(ms["inpaint"] / ms["none"])), 2)}
    print(json.dumps(summary, indent=2))
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(summary, indent=2) + "\n")
    return 0


def _stats(v: np.ndarray) -> dict[str, float]:
    return {"p50": round(float(np.median(v)), 3), "p99": round(float(np.percentile(v, 99)), 3)}


if __name__ == "__main__":
    raise SystemExit(main())
