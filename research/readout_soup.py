"""Depth students of one lineage averaged weight by weight into one checkpoint (a "model soup", Wortsman et
al. 2022): the readouts' mean at one network's cost (issue 42).

``research/ensemble_readout.py`` averages two readouts' *outputs* (two encoders per step). Students
refitted from one checkpoint stay close in weight space (the shipped readout and ``big/fit``, refitted from
it 1200 steps: perception tensors 2.2 % apart, median relative norm, 14 % at most), where the mean of the
weights can read as the mean of the outputs. The first checkpoint gives the settings, normalisers and
everything else; the named tensors' EMA weights are averaged.

    PYTHONPATH=. python research/readout_soup.py FIRST.pt OTHER.pt ... --out SOUP.pt [--prefix perception.]
    python -m trainer student compose --perception SOUP.pt --head M0.pt --out C.pt
    python -m export C.pt --ddim-steps 4 --out soup.onnx
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

import torch

from trainer.student import checkpoint


def soup(paths: list[Path], prefix: str) -> checkpoint.Checkpoint:
    """The first checkpoint with each EMA tensor under ``prefix`` replaced by the mean over all of them."""
    ckpts = [checkpoint.load(p) for p in paths]
    first = ckpts[0]
    for other, path in zip(ckpts[1:], paths[1:], strict=True):
        if other.config != first.config:
            raise SystemExit(f"error: {path} has other settings than {paths[0]}: no soup of unlike networks")
    ema = dict(first.ema)
    for name, tensor in first.ema.items():
        if name.startswith(prefix) and tensor.dtype.is_floating_point:
            ema[name] = torch.stack([c.ema[name] for c in ckpts]).mean(0)
    data = {**first.info.data, "soup": [str(p) for p in paths], "soup_prefix": prefix}
    return replace(first, ema=ema, model=ema, optimizer=None, info=replace(first.info, data=data))


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("checkpoints", type=Path, nargs="+",
                   help="two or more depth students of the same settings")
    p.add_argument("--prefix", default="perception.", help="average only the tensors named so ('' = all)")
    p.add_argument("--out", type=Path, required=True)
    args = p.parse_args()
    if len(args.checkpoints) < 2:
        raise SystemExit("error: a soup needs at least two checkpoints")
    checkpoint.save(args.out, soup(args.checkpoints, args.prefix))
    print(args.out)


if __name__ == "__main__":
    main()
