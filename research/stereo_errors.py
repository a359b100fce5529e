"""Which of the stereo sensor's errors move a depth readout (issue 45): its offset errors near the object on
a store's stereo frames, and on the same frames with only the sensor's holes (the clean depth elsewhere), only
its wrong depth (its holes filled with the clean depth), its holes inpainted as the runtime's ``--restore
inpaint`` does, and the clean frames; with ``--generated``, also every generator's frames of the same
views the store holds: how well a readout trained on a generated source reads its own source, against the
sensor that source stands in for.

    python -m trainer student readout CKPT --store S.zarr --episodes 60 --no-chunks --sensor stereo \
        --seed 30000
    python -m trainer ddg generate --generator residual_edges --demos S.zarr --steps 5    # for --generated
    PYTHONPATH=. python research/stereo_errors.py CKPT S.zarr [--generated] [--json OUT.json]

Also prints how far the sensor's depth is from the clean depth where both have some (all pixels).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch

from runtime.preprocess import restore_holes
from trainer.dataset import DemoStore, generator_of
from trainer.sim.labels import READOUT
from trainer.student import checkpoint
from trainer.student.readout import errors
from trainer.student.steps import LabelledSteps


def variants(stereo: np.ndarray, clean: np.ndarray) -> dict[str, np.ndarray]:
    """uint16 mm frames [N, H, W] of the same views -> each variant's frames."""
    return {"stereo": stereo, "holes_only": np.where(stereo == 0, 0, clean).astype(np.uint16),
            "depth_only": np.where(stereo == 0, clean, stereo).astype(np.uint16),
            "inpainted": np.stack([restore_holes(f, "inpaint") for f in stereo]), "clean": clean}


def read(net, steps: LabelledSteps, frames: np.ndarray, batch: int = 256) -> np.ndarray:
    steps.frames = torch.from_numpy(np.ascontiguousarray(frames).view(np.int16))
    facts = []
    with torch.no_grad():
        for i in range(0, len(steps), batch):
            b = steps.batch(torch.arange(i, min(i + batch, len(steps))))
            _, fact, _ = net.perceive(b.depth, b.state)
            facts.append(net.label_norm.unnormalise(fact).float().numpy())
    return np.concatenate(facts)


def sensor_error(stereo: np.ndarray, clean: np.ndarray) -> dict:
    both = (stereo > 0) & (clean > 0)
    off = np.abs(stereo.astype(np.float32) - clean)[both]
    share = {"holes": stereo == 0, "clean_holes": clean == 0, "over_2cm": off > 20, "over_5cm": off > 50}
    return {name: round(float(mask.mean()), 4) for name, mask in share.items()}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("checkpoint", type=Path)
    p.add_argument("store", type=Path, help="a store collected with --sensor stereo")
    p.add_argument("--generated", action="store_true",
                   help="also read every generator's frames the store holds (`trainer ddg generate`)")
    p.add_argument("--json", type=Path)
    args = p.parse_args()
    torch.set_num_threads(2)
    net = checkpoint.load(args.checkpoint).policy()
    cfg = net.config
    store = DemoStore.open(args.store)
    generated = [s for s in store.depth_sources if generator_of(s)] if args.generated else []
    steps = LabelledSteps([args.store], cfg.obs_horizon, cfg.action_horizon, depth=True, chunks=False)
    # one store's steps hold its frames in store order: each source's array is read as is, not labelled anew
    frames_of = {src: store.depth(src, store.n_steps) for src in ("sensor", "gt", *generated)}
    stereo, clean = frames_of["sensor"], frames_of["gt"]
    result = {"checkpoint": str(args.checkpoint), "store": str(args.store),
              "sensor": sensor_error(stereo, clean)}
    labels = steps.labels_np[:, :READOUT]
    for name, frames in {**variants(stereo, clean), **{s: frames_of[s] for s in generated}}.items():
        err = errors(read(net, steps, frames), labels, store.episode_ends)
        result[name] = {**{k: err["near"][k] for k in ("offset_cm_median", "offset_cm_p90", "bias_cm_median",
                                                       "bias_cm_p90")},
                        "every_frame_cm_p90": err["all"]["offset_cm_p90"]}  # the gate's second figure
        print(name, result[name], flush=True)
    if args.json:
        args.json.write_text(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
