"""The readout's guess of a round object's width replaced by a measurement, in closed loop (issue 42).

The readout places an unseen round kind's centre at its visible front plus the half width it reads, and reads
the can as narrow as the training boxes (`width_probe.py`: 0.83 cm narrow, 0.61 cm too near the camera with
the hand high). With the hand at least ``--high-cm`` above the object (as read) the image row through the read
object pixel measures the width to ~0.2 cm (p90); lower, the fingers join the row. So the measurement is
latched while the hand is high, and every chunk of the episode then moves the read centre ``--gain`` x
(measured - read half width) away from the nominal camera, for objects the readout reads as round.

    PYTHONPATH=. python research/measured_width.py STUDENT.onnx HEAD_CKPT --objects unseen --episodes 180 \
        [--gain 0 | 0.5 | 1] [--size] [--out J]

``--gain 0`` is the composed policy as read (the pairing baseline); ``--size`` hands the head the measured
half width as well.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from research.composed_policy import ComposedPolicy, grasp_rate, parser, report
from research.width_probe import half_width, sight
from trainer.policies import Observation
from trainer.sim.labels import GRASP_YAW, OFFSET, SIZE

ROUND_READ = 0.5
"""A read grasp direction shorter than this counts as a round object."""


class MeasuredWidthPolicy(ComposedPolicy):
    def __init__(self, onnx_path: Path, head_path: Path, gain: float, size: bool, high_cm: float,
                 jump_cm: float) -> None:
        super().__init__(onnx_path, head_path)
        self.gain, self.size, self.high_m, self.jump_mm = gain, size, high_cm / 100, jump_cm * 10
        self.latched: list[float] = []

    def reset(self, env_info: dict) -> None:
        super().reset(env_info)
        self.latched = []

    def read_facts(self, obs: Observation) -> np.ndarray:
        row, fine = self.perceive(obs)
        if -row[OFFSET][2] >= self.high_m:
            self.latched.append(half_width(obs.depth, fine[0], self.meta.preprocess, self.jump_mm))
        if self.latched and np.linalg.norm(row[GRASP_YAW]) < ROUND_READ:
            radius = float(np.median(self.latched))
            row[0:2] += self.gain * (radius - row[SIZE][0]) * sight(self.hand(obs)[:2] + row[OFFSET][:2])
            if self.size:
                row[5:7] = radius
        return row


def main() -> None:
    p = parser(__doc__, "unseen", 180)
    p.add_argument("--gain", type=float, default=1.0)
    p.add_argument("--size", action="store_true")
    p.add_argument("--high-cm", type=float, default=6.0)
    p.add_argument("--jump-cm", type=float, default=1.5)
    args = p.parse_args()
    policy = MeasuredWidthPolicy(args.student, args.head, args.gain, args.size, args.high_cm, args.jump_cm)
    result = grasp_rate(policy, args)
    report({"gain": args.gain, "size": args.size, **result}, args.out)


if __name__ == "__main__":
    main()
