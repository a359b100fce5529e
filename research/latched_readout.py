"""Look before you reach, at test time (issue 42): the object's place latched while the hand is high.

On its own episodes the depth student's readout reads the object's offset from the hand well while the hand
is high over the table and poorly once the fingers are down beside the object (along the camera's line of
sight: 0.46 cm off with the hand 6-15 cm above the object, 0.87 cm at grasp height; ``keyframe_readout.py
score``): at grasp height hand and object overlap in the image. Until the fingers touch it the object does
not move, so its place in the robot's base frame, the hand's (forward kinematics) plus the readout's offset,
can be averaged over the frames in which the hand was high and the readout said the object was near, and the
head given that place minus the hand's instead of the readout's offset. A close (the gripper no longer fully
open) empties the average: the object may have moved; it fills again once the hand is high and open.

The readout, the head (M0) and the chunk execution are ``research/composed_policy.py``'s, in torch; only the
offset the head reads changes. ``--plain`` runs the same policy without the latch, for pairing.

    python research/latched_readout.py ROUND.onnx M0.pt [--objects seen] [--episodes 180] [--plain] [--out J]
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from research.composed_policy import ComposedPolicy, grasp_rate, parser
from runtime.preprocess import normalise
from trainer.dataset import DEPTH_SCALE
from trainer.sim.labels import OFFSET
from trainer.student.oracle_policy import OraclePolicy

HIGH_M = (0.12, 0.30)
"""Heights of the grasp site over the table whose readings are averaged: above every seen kind's top."""
NEAR_M = 0.10
"""Only readings that put the object this near the hand (horizontally) are averaged."""
OPEN_M = 0.075
"""A gripper opening below this (fully open: 0.08 m) is a close: the latch empties."""


class LatchedPolicy(ComposedPolicy):
    def __init__(self, onnx_path: Path, head_path: Path, latch: bool = True) -> None:
        super().__init__(onnx_path, head_path)
        self.latch, self.total, self.count, self.row = latch, np.zeros(3), 0, None

    def reset(self, env_info: dict) -> None:
        super().reset(env_info)
        self.total, self.count = np.zeros(3), 0

    def act(self, obs) -> np.ndarray:
        """Every frame enters the stack and, while the gripper is open, the latch; the head runs per chunk."""
        if not self.latch:
            return super().act(obs)
        self.stack = self.frames.push(normalise(obs.depth, DEPTH_SCALE, self.meta.preprocess))
        self.row = super().read_facts(obs)  # this frame's readout, which the head reads if it runs now
        if obs.state[7] < OPEN_M:
            self.total, self.count = np.zeros(3), 0
        else:
            hand = self.hand(obs)
            if HIGH_M[0] <= hand[2] < HIGH_M[1] and np.linalg.norm(self.row[OFFSET][:2]) < NEAR_M:
                self.total, self.count = self.total + hand + self.row[OFFSET], self.count + 1
        return OraclePolicy.act(self, obs)

    def read_facts(self, obs) -> np.ndarray:
        if not self.latch:
            return super().read_facts(obs)
        row = self.row.copy()
        if self.count and obs.state[7] >= OPEN_M:
            row[OFFSET] = self.total / self.count - self.hand(obs)
        return row


def main() -> None:
    p = parser(__doc__, "seen", 180)
    p.add_argument("--plain", action="store_true", help="without the latch")
    args = p.parse_args()
    policy = LatchedPolicy(args.student, args.head, latch=not args.plain)
    result = {"latch": not args.plain, **grasp_rate(policy, args)}
    print(json.dumps({k: v for k, v in result.items() if k != "grasped"}))
    if args.out:
        args.out.write_text(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
