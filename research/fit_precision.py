"""Seconds per fit step of the recipe's depth student in fp32 and under bf16 autocast, side by side on this
machine, CPU or GPU (``DistillConfig.precision``, the recipe's ``--precision``), in the layout the fit uses
(``distill.training_layout``). ``research/device/run.sh`` sizes round 0's fit by its fp32 figure,
``research/device/probe.sh`` runs it by batch size on the device. With ``--layouts``, instead the encoder's
memory layouts at ``--precision``: contiguous against the fit's channels-last.

    python research/fit_precision.py [--width 16] [--batch 512] [--threads 2] [--repeats 4] \
        [--layouts --precision bf16]

Random inputs of the recipe's shapes (3 stacked 96 x 128 frames, shift 4, near loss 1); the variants alternate
so that a busy machine slows each alike; medians printed as one JSON line.
"""

import argparse
import json
import statistics
import time

import torch

from trainer.student.config import StudentConfig
from trainer.student.ddim import training_scheduler
from trainer.student.distill import DistillConfig, device, losses, training_layout
from trainer.student.model import PerceptionStudent
from trainer.student.steps import StepBatch


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--width", type=int, default=16, help="the student's --width")
    p.add_argument("--batch", type=int, default=512)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--repeats", type=int, default=4)
    p.add_argument("--layouts", action="store_true", help="compare the layouts at --precision instead")
    p.add_argument("--precision", default="bf16", choices=("fp32", "bf16"), help="with --layouts")
    a = p.parse_args()
    torch.set_num_threads(a.threads)
    dev = device()
    cfg = StudentConfig(perception="depth", width=a.width, head_dims=(32, 64, 128), state_features=128,
                        prediction="v_prediction", exec_horizon=4)
    sch = training_scheduler(100, "v_prediction")
    sch.alphas_cumprod = sch.alphas_cumprod.to(dev)
    gen = torch.Generator(device=dev).manual_seed(0)
    b = a.batch
    batch = StepBatch(torch.rand(b, 3, 96, 128, device=dev), torch.rand(b, 8, device=dev),
                      torch.rand(b, 12, device=dev) * 2 - 1, torch.rand(b, 16, 8, device=dev))
    layouts = {"contiguous": lambda net: net, "channels_last": training_layout}
    variants = ({name: (layout, a.precision) for name, layout in layouts.items()} if a.layouts
                else {name: (training_layout, name) for name in ("fp32", "bf16")})
    fits = {}
    for name, (layout, _) in variants.items():
        torch.manual_seed(0)
        net = layout(PerceptionStudent(cfg).to(dev))
        fits[name] = (net, torch.optim.AdamW(net.parameters(), 3e-4))
    sync = torch.cuda.synchronize if dev.type == "cuda" else (lambda: None)

    def step(name: str) -> float:
        net, optim = fits[name]
        sync()
        began = time.perf_counter()
        fit = DistillConfig(shift_px=4, near_loss=1, precision=variants[name][1])
        loss, _ = losses(net, sch, batch, gen, fit)
        optim.zero_grad()
        loss.backward()
        optim.step()
        sync()
        return time.perf_counter() - began

    times = {name: [] for name in fits}
    for name in fits:
        step(name)  # warm-up
    for _ in range(a.repeats):
        for name in fits:
            times[name].append(step(name))
    medians = {name: statistics.median(t) for name, t in times.items()}
    slow, fast = medians  # the baseline first: fp32, or the contiguous layout
    print(json.dumps({**{f"{k}_s_per_step": round(v, 4) for k, v in medians.items()},
                      f"{fast}_speedup": round(medians[slow] / medians[fast], 2), "device": str(dev),
                      "width": a.width, "batch": b, **({"precision": a.precision} if a.layouts else {})}))


if __name__ == "__main__":
    main()
