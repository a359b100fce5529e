"""Several depth students' readouts averaged into one set of facts for the privileged head (issue 42).

Two readouts of one lineage that grasp as often (the shipped file's and ``big/fit``'s: 435 and 444 of 540
unseen) fail on different episodes: of 540 unseen seeds they fail 105 and 96, both 57. If their errors near
the object are that independent, their mean reads the object nearer than either. Here the first student's
``ComposedPolicy`` (its frames, chunks and head) reads the facts as the mean of every listed readout's.

    PYTHONPATH=. python research/ensemble_readout.py FIRST.onnx HEAD_CKPT --also OTHER/ckpt.pt ... \
        [--objects unseen] [--episodes 180] [--seed 10000] [--out R.json]

``--stagger N`` reads the others N ticks before each chunk's inference instead (a runtime could run them on a
tick that runs no inference, so no tick pays for two encoders), their offsets carried to the inference tick by
the hand's move by forward kinematics (the object stands still until it is grasped).

Seeds ``--seed``.. as ``trainer evaluate``, but the start noise is drawn as ``OraclePolicy`` draws it, not as
the runtime does: pair with another torch run (``composed_policy.py``), not with ``trainer evaluate``'s JSON
(here the pair grasped 457 of 540 unseen, through the runtime 448: ``trainer student compose --also``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from research.composed_policy import ComposedPolicy, grasp_rate, parser, report
from runtime.preprocess import normalise
from trainer.dataset import DEPTH_SCALE
from trainer.policies import Observation
from trainer.sim.labels import OFFSET
from trainer.student import checkpoint


class EnsemblePolicy(ComposedPolicy):
    """``ComposedPolicy`` whose facts are the mean of its own readout's and the ``others``' on the same
    stack."""

    def __init__(self, onnx_path: Path, head_path: Path, others: list[Path], stagger: int = 0) -> None:
        super().__init__(onnx_path, head_path)
        self.others = [checkpoint.load(p).policy() for p in others]
        self.stagger = stagger
        self.early: list[np.ndarray] = []
        """With ``stagger``: the others' facts read ``stagger`` ticks before the next inference, their offsets
        already carried to the hand's position then subtracted (added back at the inference tick)."""

    def reset(self, env_info: dict) -> None:
        super().reset(env_info)
        self.early = []

    def read_facts(self, obs: Observation) -> np.ndarray:
        if not self.stagger or not self.early:  # the first chunk has no earlier tick
            others = [self.perceive(obs, eye)[0] for eye in self.others]
        else:
            others = [row.copy() for row in self.early]
            for row in others:
                row[OFFSET] -= self.hand(obs)
        return np.mean([super().read_facts(obs)] + others, axis=0)

    def act(self, obs: Observation) -> np.ndarray:
        if self.stagger:
            self.stack = self.frames.push(normalise(obs.depth, DEPTH_SCALE, self.meta.preprocess))
            if len(self.queue) == self.stagger:
                self.early = [self.perceive(obs, eye)[0] for eye in self.others]
                for row in self.early:
                    row[OFFSET] += self.hand(obs)  # the object's place: offset from the hand + the hand
            return super(ComposedPolicy, self).act(obs)
        return super().act(obs)


def main() -> None:
    p = parser(__doc__, "unseen", 180)
    p.add_argument("--also", type=Path, nargs="+", required=True,
                   help="more depth students' checkpoints")
    p.add_argument("--stagger", type=int, default=0, help="read the others this many ticks before inference")
    args = p.parse_args()
    policy = EnsemblePolicy(args.student, args.head, args.also, args.stagger)
    result = grasp_rate(policy, args)
    report({"also": [str(a) for a in args.also], "stagger": args.stagger, **result}, args.out)


if __name__ == "__main__":
    main()
