"""Several depth students' readouts averaged into one set of facts for the privileged head (issue 42).

Two readouts of one lineage that grasp as often (the shipped file's and ``big/fit``'s: 435 and 444 of 540
unseen) fail on different episodes: of 540 unseen seeds they fail 105 and 96, both 57. If their errors near
the object are that independent, their mean reads the object nearer than either. Here the first student's
``ComposedPolicy`` (its frames, chunks and head) reads the facts as the mean of every listed readout's.

    PYTHONPATH=. python research/ensemble_readout.py FIRST.onnx HEAD_CKPT --also OTHER/ckpt.pt ... \
        [--objects unseen] [--episodes 180] [--seed 10000] [--out R.json]

Seeds ``--seed``.. as ``trainer evaluate``, but the start noise is drawn as ``OraclePolicy`` draws it, not as
the runtime does: pair with another torch run (``composed_policy.py``), not with ``trainer evaluate``'s JSON
(here the pair grasped 457 of 540 unseen, through the runtime 448: ``pair_export.py``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from research.composed_policy import ComposedPolicy, grasp_rate, parser, report
from trainer.policies import Observation
from trainer.student import checkpoint


class EnsemblePolicy(ComposedPolicy):
    """``ComposedPolicy`` whose facts are the mean of its own readout's and the ``others``' on the same
    stack."""

    def __init__(self, onnx_path: Path, head_path: Path, others: list[Path]) -> None:
        super().__init__(onnx_path, head_path)
        self.others = [checkpoint.load(p).policy() for p in others]

    def read_facts(self, obs: Observation) -> np.ndarray:
        rows = [super().read_facts(obs)] + [self.perceive(obs, eye)[0] for eye in self.others]
        return np.mean(rows, axis=0)


def main() -> None:
    p = parser(__doc__, "unseen", 180)
    p.add_argument("--also", type=Path, nargs="+", required=True,
                   help="more depth students' checkpoints")
    args = p.parse_args()
    policy = EnsemblePolicy(args.student, args.head, args.also)
    result = grasp_rate(policy, args.objects, args.episodes, args.seed)
    report({"also": [str(a) for a in args.also], **result}, args.out)


if __name__ == "__main__":
    main()
