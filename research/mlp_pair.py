"""Two readout MLPs on one frozen encoder (issue 42): does the readout pair's gain (two whole depth students
averaged, 753 against 718 of 900 unseen, at two encoders' cost; `history.md` 2026-12-01) come from the MLP
that maps the features to the facts, so that a second MLP alone, at no encoder's cost, buys it?

The encoder's features of every frame are cached as ``frozen_readout.features`` caches them; ``--mlps N``
new readout MLPs (the shipped one's layout) are fitted on the ``--train`` stores, from fresh weights (seeds
0..N-1) or, with ``--from-shipped``, from the composed student's own. On each ``--test`` store it reports,
near the object: the shipped MLP, each new one, their mean with the shipped one, the mean of all, and how
alike the shipped and a new MLP's errors are (correlation of the horizontal error components).

    PYTHONPATH=. python research/mlp_pair.py $R/recovered/shipped/student.pt \
        --train $R/research/mlp/train.zarr --test $R/research/mlp/own_unseen.zarr \
        --mlps 2 --steps 4000 --out $R/research/mlp/fresh
"""

from __future__ import annotations

import argparse
import copy
import json
from pathlib import Path

import numpy as np
import torch

from research.frozen_readout import features, fit
from trainer.dataset import DemoStore
from trainer.student import checkpoint
from trainer.student.readout import by_kind, errors, offset_errors


def fresh_like(mlp: torch.nn.Module, seed: int) -> torch.nn.Module:
    torch.manual_seed(1000 + seed)
    new = copy.deepcopy(mlp)
    for layer in new:
        if hasattr(layer, "reset_parameters"):
            layer.reset_parameters()
    return new


def summary(read: np.ndarray, labels: np.ndarray, store: DemoStore) -> dict:
    e = errors(read, labels, store.episode_ends)
    return {"near": e["near"], "yaw_p90": e.get("grasp_yaw_deg_p90"),
            "near_by_kind": {k: v["offset_cm_median"]
                             for k, v in by_kind(read, labels, store.episode_ends, store.kinds).items()}}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("checkpoint", type=Path, help="a composed depth student (export.recover's student.pt)")
    p.add_argument("--train", type=Path, nargs="+", required=True)
    p.add_argument("--test", type=Path, nargs="+", required=True)
    p.add_argument("--mlps", type=int, default=2)
    p.add_argument("--from-shipped", action="store_true", help="start each new MLP from the shipped weights")
    p.add_argument("--steps", type=int, default=4000)
    p.add_argument("--lr", type=float, default=1e-3)
    p.add_argument("--batch", type=int, default=512)
    p.add_argument("--out", type=Path, required=True)
    args = p.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    ckpt = checkpoint.load(args.checkpoint)
    net = ckpt.policy().eval()
    shipped, norm = net.perception.readout, net.label_norm
    cache = args.out.parent
    train = [features(args.checkpoint, s, cache / f"{s.stem}.npz") for s in args.train]
    x = torch.from_numpy(np.concatenate([t["x"] for t in train]))
    y = norm.normalise(torch.from_numpy(np.concatenate([t["labels"] for t in train])))
    torch.set_num_threads(2)
    mlps = []
    for i in range(args.mlps):
        start = copy.deepcopy(shipped) if args.from_shipped else fresh_like(shipped, i)
        mlps.append(fit(start, x, y, args.steps, args.lr, args.batch, seed=i, cosine=True))
    report = {}
    for s in args.test:
        t = features(args.checkpoint, s, cache / f"{s.stem}.npz")
        store, feats = DemoStore.open(s), torch.from_numpy(t["x"])
        with torch.no_grad():
            reads = [norm.unnormalise(m(feats)).numpy() for m in [shipped, *mlps]]
        rows = {"shipped": summary(reads[0], t["labels"], store)}
        base_error, near = offset_errors(reads[0], t["labels"])
        for i, read in enumerate(reads[1:]):
            error, _ = offset_errors(read, t["labels"])
            corr = [float(np.corrcoef(base_error[near, a], error[near, a])[0, 1]) for a in (0, 1)]
            rows[f"new{i}"] = {**summary(read, t["labels"], store),
                               "error_corr_xy": [round(c, 3) for c in corr]}
            rows[f"shipped+new{i}"] = summary((reads[0] + read) / 2, t["labels"], store)
        rows["mean_all"] = summary(np.mean(reads, 0), t["labels"], store)
        report[s.stem] = rows
        for name, r in rows.items():
            print(f"{s.stem} {name:16s} near median {r['near']['offset_cm_median']} bias p90 "
                  f"{r['near']['bias_cm_p90']} yaw p90 {r['yaw_p90']} {r.get('error_corr_xy', '')}")
    (args.out / "report.json").write_text(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
