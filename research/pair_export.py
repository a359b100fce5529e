"""A composed student whose readout is the mean of its own and another depth student's, exported as one policy
file (issue 42): ``ensemble_readout.py``'s pair through the runtime's path, for ``trainer evaluate``,
``export.check`` and ``hil_sim`` to measure as they measure the shipped file.

    PYTHONPATH=. python research/pair_export.py COMPOSED.pt OTHER.pt --out pair.onnx [--ddim-steps 4]
    PYTHONPATH=. python research/pair_export.py COMPOSED.pt MLP0.pt --mlp --out pair.onnx

COMPOSED is a ``trainer student compose`` checkpoint (its readout already speaks its head's units); OTHER's
facts are taken into those units through both students' label normalisers. The head reads only the facts
(``head_features=False``), so the other student's features and keypoints are not used. With ``--mlp`` the
other is a second readout MLP on COMPOSED's own features (``mlp_pair.py --save``, fitted in COMPOSED's units):
the pair at one encoder's cost.
"""

from __future__ import annotations

import argparse
import copy
from pathlib import Path

import onnx
import torch
from torch import nn

from export import reference
from export.graph import policy_metadata, set_metadata, trace
from trainer.student import checkpoint


class PairPerception(nn.Module):
    """Both perceptions on the same stack: the first's features and keypoints, the two readouts'
    mean."""

    def __init__(self, first: nn.Module, first_norm: nn.Module, other: nn.Module,
                 other_norm: nn.Module) -> None:
        super().__init__()
        self.first, self.first_norm, self.other, self.other_norm = first, first_norm, other, other_norm

    def forward(self, depth: torch.Tensor, hand: torch.Tensor) -> tuple[torch.Tensor, ...]:
        features, facts, fine = self.first(depth, hand)
        _, other, _ = self.other(depth, hand)
        other = self.first_norm.normalise(self.other_norm.unnormalise(other))
        return features, (facts + other) / 2, fine


class MlpPairPerception(nn.Module):
    """One perception, two readout MLPs on its features: their mean."""

    def __init__(self, first: nn.Module, mlp: nn.Module) -> None:
        super().__init__()
        self.first, self.mlp = first, mlp

    def forward(self, depth: torch.Tensor, hand: torch.Tensor) -> tuple[torch.Tensor, ...]:
        features, facts, fine = self.first(depth, hand)
        return features, (facts + self.mlp(torch.cat([features, hand], dim=-1))) / 2, fine


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("composed", type=Path, help="a composed student checkpoint (trainer student compose)")
    p.add_argument("other", type=Path, help="another depth student of the same resolution (or, with --mlp, "
                   "a readout MLP's weights)")
    p.add_argument("--mlp", action="store_true", help="OTHER is a second readout MLP (mlp_pair.py --save)")
    p.add_argument("--ddim-steps", type=int, default=4)
    p.add_argument("--out", type=Path, required=True)
    args = p.parse_args()
    ckpt = checkpoint.load(args.composed)
    if ckpt.config.head_features or ckpt.config.perception != "depth":
        raise SystemExit(f"error: {args.composed} is not a composed depth student "
                         "(perception depth, head_features off)")
    policy = ckpt.policy()
    if args.mlp:
        mlp = copy.deepcopy(policy.perception.readout)
        mlp.load_state_dict(torch.load(args.other, weights_only=True)["readout"])
        policy.perception = MlpPairPerception(policy.perception, mlp)
    else:
        other = checkpoint.load(args.other)
        if other.info.depth_spec != ckpt.info.depth_spec:
            raise SystemExit(f"error: {args.other} sees another depth crop or resolution than "
                             f"{args.composed}")
        eye = other.policy()
        policy.perception = PairPerception(policy.perception, policy.label_norm, eye.perception,
                                           eye.label_norm)
    meta = policy_metadata(ckpt, args.ddim_steps, args.composed)
    meta.training_data["pair"] = str(args.other)
    model = trace(policy.eval(), meta)
    set_metadata(model, meta, reference.record(policy, meta))
    onnx.checker.check_model(model, full_check=True)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    onnx.save(model, str(args.out))
    print(args.out)


if __name__ == "__main__":
    main()
