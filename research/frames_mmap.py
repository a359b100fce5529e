"""Milliseconds per batch gather of a fit's depth stacks from frames held in process memory against the same
frames in an unlinked memory-mapped file (``trainer.student.steps``, since 2026-11-30), side by side: the two
alternate so that a busy machine slows each alike. Random 16-bit frames at 192 x 144; a batch is 128 stacks of
3 frames gathered as ``LabelledSteps.batch`` gathers them.

    python research/frames_mmap.py [--frames 40000] [--repeats 6] [--dir ~/.cache/diffudepgrasp]

Medians printed as one JSON line. Both copies must fit in memory at once (40000 frames: 2.2 GB each).
"""

import argparse
import json
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

H, W, STACK, BATCH = 144, 192, 3, 128


def fill(frames: np.ndarray) -> None:
    for i in range(0, len(frames), 1000):
        part = frames[i:i + 1000]
        part[:] = np.random.default_rng(i).integers(0, 2 ** 16, part.shape, dtype=np.uint16)


def gather_ms(frames: torch.Tensor, batches: int, rng: torch.Generator) -> float:
    start = time.perf_counter()
    for _ in range(batches):
        index = torch.randint(0, len(frames), (BATCH * STACK,), generator=rng)
        _ = frames[index].int() & 0xFFFF
    return (time.perf_counter() - start) / batches * 1e3


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--frames", type=int, default=40000)
    p.add_argument("--repeats", type=int, default=6)
    p.add_argument("--batches", type=int, default=50, help="batches per timed repeat")
    p.add_argument("--dir", type=Path, default=Path.home() / ".cache" / "diffudepgrasp",
                   help="where the mapped file goes (a disk, as beside a recipe's stores)")
    args = p.parse_args()
    torch.set_num_threads(1)
    shape = (args.frames, H, W)
    memory = np.empty(shape, np.uint16)
    args.dir.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryFile(dir=args.dir) as file:
        mapped = np.memmap(file, np.uint16, "w+", shape=shape)
    for frames in (memory, mapped):
        fill(frames)
    tensors = {name: torch.from_numpy(frames.view(np.int16))
               for name, frames in (("memory", memory), ("mapped", mapped))}
    rng = torch.Generator().manual_seed(0)
    times: dict[str, list[float]] = {name: [] for name in tensors}
    for _ in range(args.repeats):
        for name, frames in tensors.items():
            times[name].append(gather_ms(frames, args.batches, rng))
    median = {name: statistics.median(t) for name, t in times.items()}
    print(json.dumps({"frames": args.frames, **{f"{k}_ms": round(v, 2) for k, v in median.items()},
                      "mapped_over_memory": round(median["mapped"] / median["memory"], 3)}))


if __name__ == "__main__":
    main()
