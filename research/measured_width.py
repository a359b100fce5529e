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
import torch

from hil_sim.camera import d455_intrinsics
from hil_sim.world import CAMERA_POS
from research.composed_policy import ComposedPolicy, grasp_rate, parser, report
from research.width_probe import row_half_width
from trainer.policies import Observation
from trainer.sim.labels import GRASP_YAW, OFFSET, SIZE
from trainer.student.model import hand_pose

ROUND_READ = 0.5
"""A read grasp direction shorter than this counts as a round object."""


class MeasuredWidthPolicy(ComposedPolicy):
    def __init__(self, onnx_path: Path, head_path: Path, gain: float, size: bool, high_cm: float,
                 jump_cm: float) -> None:
        super().__init__(onnx_path, head_path)
        self.gain, self.size, self.high_m, self.jump_mm = gain, size, high_cm / 100, jump_cm * 10
        spec = self.meta.preprocess
        self.fx = d455_intrinsics(spec).fx * spec.out_width / spec.crop_width
        self.latched: list[float] = []

    def reset(self, env_info: dict) -> None:
        super().reset(env_info)
        self.latched = []

    def read_facts(self, obs: Observation) -> np.ndarray:
        state = torch.from_numpy(obs.state[None].astype(np.float32))
        with torch.no_grad():
            _, seen, fine = self.eye.perceive(torch.from_numpy(self.stack[None]), state)
            row = self.eye.label_norm.unnormalise(seen)[0].numpy()
            site = hand_pose(state)[0, :3].numpy()
        if -row[OFFSET][2] >= self.high_m:
            spec = self.meta.preprocess
            u, v = (fine[0, 0].numpy() + 1) / 2 * np.array([spec.out_width - 1, spec.out_height - 1])
            self.latched.append(row_half_width(obs.depth, u, v, self.jump_mm, self.fx))
        if self.latched and np.linalg.norm(row[GRASP_YAW]) < ROUND_READ:
            radius = float(np.median(self.latched))
            sight = site[:2] + row[OFFSET][:2] - np.asarray(CAMERA_POS[:2])
            row[0:2] += self.gain * (radius - row[SIZE][0]) * sight / np.linalg.norm(sight)
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
    result = grasp_rate(policy, args.objects, args.episodes)
    report({"gain": args.gain, "size": args.size, **result}, args.out)


if __name__ == "__main__":
    main()
