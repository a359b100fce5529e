"""The readout MLP refitted on a frozen encoder's features (issue 42): can a few hundred episodes of new
shapes teach it the unseen kinds without the forgetting a whole-network refit showed (`history.md`,
2026-12-01)?

The encoder's features of every frame are computed once (cached beside ``--out``); then only the readout MLP
(3 layers, from the composed student's own weights) is fitted, on ``--train`` stores with group shares, and
measured on ``--test`` stores (near the object, by kind: `trainer student readout`'s report). With ``--save``
the composed student with the new MLP is written (``ckpt.pt``), ready for ``python -m export``.

    PYTHONPATH=. python research/frozen_readout.py $R/recovered/shipped/student.pt \
        --train $R/research/fam/fam.zarr --test $R/research/own_unseen.zarr --shares seen=0.4 squares=0.15 \
        --steps 4000 --out $R/research/frozen [--rows -4 -2 0 2 4 6] [--save]

Shares are ``DistillConfig.shares``: the rest of each batch (here 0.45) comes from the other kinds' steps
(here the superquadrics, no longer kinds of ``hil_sim.objects``). ``--rows`` adds ``width_probe.half_width``
on those image rows below the read object pixel as inputs (their weights from zero).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch

from research.width_probe import half_width
from trainer.dataset import DemoStore
from trainer.sim.labels import READOUT
from trainer.student import checkpoint
from trainer.student.distill import batch_weights
from trainer.student.model import hand_pose
from trainer.student.readout import by_kind, errors
from trainer.student.steps import LabelledSteps

FINE_AT = 64
"""Column of the first fine keypoint in the features (after the 32 coarse keypoints' x, y)."""


def features(ckpt_path: Path, store: Path, cache: Path) -> dict[str, np.ndarray]:
    """The frozen encoder's features with the normalised hand pose appended (the MLP's input) and the
    labels of every frame of ``store``, cached in ``cache``."""
    if cache.exists():
        return dict(np.load(cache))
    net = checkpoint.load(ckpt_path).policy()
    torch.set_num_threads(2)
    steps = LabelledSteps([store], net.config.obs_horizon, net.config.action_horizon, depth=True)
    rows = []
    with torch.no_grad():
        for start in range(0, len(steps), 256):
            b = steps.batch(torch.arange(start, min(start + 256, len(steps))))
            feats, _, _ = net.perceive(b.depth, b.state)
            rows.append(torch.cat([feats, net.hand_norm.normalise(hand_pose(b.state))], -1).numpy())
    out = {"x": np.concatenate(rows), "labels": steps.labels_np[:, :READOUT], "kinds": steps.kinds}
    np.savez(cache, **out)
    return out


def probe_widths(store: Path, x: np.ndarray, rows: tuple[int, ...], cache: Path) -> np.ndarray:
    """``width_probe.row_half_width`` on image rows ``rows`` (pixels from the read object pixel, the first
    fine keypoint) of each frame's newest depth, in units of 3 cm (the training kinds' half widths)."""
    if cache.exists():
        return np.load(cache)
    demos = DemoStore.open(store)
    depth = demos.depth("gt", demos.n_steps)
    kp = x[:, FINE_AT:FINE_AT + 2]
    out = np.array([[half_width(depth[i], kp[i], demos.depth_spec, 15.0, dv) for dv in rows]
                    for i in range(len(kp))], np.float32) / 0.03
    np.save(cache, out)
    return out


def fit(mlp: torch.nn.Module, x: torch.Tensor, y: torch.Tensor, steps: int, lr: float, batch: int,
        weights: torch.Tensor | None = None, seed: int = 0, cosine: bool = False) -> torch.nn.Module:
    """``mlp`` fitted in place to ``y`` from cached features ``x`` (batches drawn by ``weights`` when given;
    ``cosine``: the learning rate annealed to zero over the steps); returned in eval mode."""
    torch.manual_seed(seed)
    opt = torch.optim.AdamW(mlp.parameters(), lr=lr, weight_decay=1e-4)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, steps) if cosine else None
    for step in range(steps):
        index = (torch.randint(len(x), (batch,)) if weights is None
                 else torch.multinomial(weights, batch, replacement=True))
        loss = torch.nn.functional.mse_loss(mlp(x[index]), y[index])
        opt.zero_grad()
        loss.backward()
        opt.step()
        if sched is not None:
            sched.step()
        if step % 500 == 0:
            print(f"seed {seed} step {step}: loss {loss.item():.4f}", flush=True)
    return mlp.eval()


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("checkpoint", type=Path)
    p.add_argument("--train", type=Path, nargs="+", required=True)
    p.add_argument("--test", type=Path, nargs="+", required=True)
    p.add_argument("--shares", nargs="*", default=[])
    p.add_argument("--steps", type=int, default=4000)
    p.add_argument("--lr", type=float, default=1e-4)
    p.add_argument("--batch", type=int, default=512)
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--save", action="store_true")
    p.add_argument("--rows", type=int, nargs="*", default=[], help="width probes on these rows (pixels)")
    args = p.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    ckpt = checkpoint.load(args.checkpoint)
    net = ckpt.policy()
    mlp = net.perception.readout
    norm = net.label_norm
    train = [features(args.checkpoint, s, args.out / f"{s.stem}.npz") for s in args.train]
    if args.rows:  # the probes as more inputs of the first layer, their weights from zero
        for s, t in zip(args.train, train, strict=True):
            t["x"] = np.concatenate([t["x"], probe_widths(s, t["x"], tuple(args.rows),
                                                          args.out / f"{s.stem}_w{len(args.rows)}.npy")], 1)
        first = mlp[0]
        wider = torch.nn.Linear(first.in_features + len(args.rows), first.out_features)
        with torch.no_grad():
            wider.weight.zero_()
            wider.weight[:, :first.in_features] = first.weight
            wider.bias.copy_(first.bias)
        mlp[0] = wider
    x = torch.from_numpy(np.concatenate([t["x"] for t in train]))
    y = norm.normalise(torch.from_numpy(np.concatenate([t["labels"] for t in train])))
    weights = batch_weights(np.concatenate([t["kinds"] for t in train]), tuple(args.shares))
    fit(mlp, x, y, args.steps, args.lr, args.batch, weights)
    report = {}
    for s in args.test:
        t = features(args.checkpoint, s, args.out / f"{s.stem}.npz")
        if args.rows:
            t["x"] = np.concatenate([t["x"], probe_widths(s, t["x"], tuple(args.rows),
                                                          args.out / f"{s.stem}_w{len(args.rows)}.npy")], 1)
        with torch.no_grad():
            read = norm.unnormalise(mlp(torch.from_numpy(t["x"]))).numpy()
        store = DemoStore.open(s)
        report[s.stem] = {**errors(read, t["labels"], store.episode_ends),
                          "near_by_kind": by_kind(read, t["labels"], store.episode_ends, store.kinds)}
    print(json.dumps(report, indent=1))
    (args.out / "report.json").write_text(json.dumps(report, indent=1))
    if args.save:
        state = net.state_dict()
        for weights in (ckpt.ema, ckpt.model):
            weights.update({k: v.clone() for k, v in state.items() if k.startswith("perception.readout")})
        checkpoint.save(args.out / "ckpt.pt", ckpt)


if __name__ == "__main__":
    main()
