"""Where should the fingers close on a round object, given what the camera cannot see (issue 42)?

The depth student's near misses on its own episodes lie mostly along the camera's line of sight
(horizontally), and its readout reports ~8 % of them there, ~74 % across it
(``research/own_frame_readout.py``). Across the finger pads a constant aim error of ~0.7 cm loses grasps;
along the closing axis 1.5 cm does not (issue 42). ``ReactiveExpert`` closes on round kinds at whatever yaw
the wrist has. This sweep gives it a constant aim error of B cm along or across the line of sight and closes
on round kinds either as it does (``wrist``) or with the closing axis along the line of sight (``sight``),
the same seeds (10000..) everywhere.

    python research/view_aligned_grasp.py [--kinds apple peach pear cube] [--bias-cm 0 1 1.5] [--episodes 30]
"""

from __future__ import annotations

import argparse

import numpy as np

from research.own_frame_readout import ACROSS, SIGHT
from trainer.sim.env import EnvConfig, GraspEnv
from trainer.sim.rollout import run_episode, schedule
from trainer.teacher.scripted import ReactiveExpert, fingers_yaw, nearest_turn


class AimedExpert(ReactiveExpert):
    """Aims ``bias`` (m, base frame, horizontal) off the object; on round kinds closes along ``closing``."""

    def __init__(self, bias: np.ndarray, closing: str) -> None:
        super().__init__()
        self.bias, self.closing = np.append(bias, 0.0), closing

    def _grasp_pose(self, priv: np.ndarray, rot: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        position, frame = super()._grasp_pose(priv, rot)
        return position + self.bias, frame

    def _grasp_yaw(self, obj_quat: np.ndarray, rot: np.ndarray) -> float:
        if self.closing == "wrist" or not self.round_in_plan():
            return super()._grasp_yaw(obj_quat, rot)
        return nearest_turn(fingers_yaw(rot), np.arctan2(SIGHT[1], SIGHT[0]))


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--kinds", nargs="+", default=["apple", "peach", "pear", "cube"])
    p.add_argument("--bias-cm", nargs="+", type=float, default=[0.0, 1.0, 1.5])
    p.add_argument("--episodes", type=int, default=30)
    args = p.parse_args()
    cells = [(d, b, c) for d in ("sight", "across") for b in args.bias_cm for c in ("wrist", "sight")
             if b > 0 or d == "sight"]
    print("aim error direction, cm, closing: " + "  ".join(f"{d[:5]} {b:g} {c}" for d, b, c in cells))
    for kind in args.kinds:
        env = GraspEnv(EnvConfig(objects=(kind,), randomise=True, render_depth=False))
        counts = []
        for direction, bias_cm, closing in cells:
            bias = (SIGHT if direction == "sight" else ACROSS) * bias_cm / 100
            counts.append(sum(run_episode(env, AimedExpert(bias, closing), job).success
                              for job in schedule((kind,), 10_000, args.episodes)))
        env.close()
        print(f"{kind:>8} of {args.episodes}: " + "  ".join(f"{c:>14d}" for c in counts), flush=True)


if __name__ == "__main__":
    main()
