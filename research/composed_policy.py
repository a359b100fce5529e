"""The depth student's perception feeding the privileged head (issue 42: which half of the student misses).

A depth student (``perception="depth"``) reads the object's facts from depth (its readout) and its own head
also reads the raw depth features. Here the readout's facts go instead into a ``perception="privileged"``
head (M0: trained on the true facts only), in torch, with chunks executed as the exported students' are. If
this grasps far more often than the depth student itself, its head is what loses the grasps (it leans on the
raw features, which its own states never taught), not the readout's error.

    python research/composed_policy.py DEPTH_STUDENT.onnx HEAD_CKPT [--objects seen] [--episodes 60] \
        [--true offset | offset_xy offset_z, yaw size]

``--true`` takes those facts from the simulator instead of the readout: which fact's error costs the grasps.

The ONNX file names the depth crop and frame stack; its checkpoint (``DEPTH_STUDENT.onnx``'s folder,
``ckpt.pt``) is the perception. Seeds ``--seed``.. (10000..), as ``trainer evaluate``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch

from hil_sim.objects import select_kinds
from runtime.policy import Policy as RuntimePolicy
from runtime.preprocess import FrameStack, normalise
from trainer.dataset import DEPTH_SCALE
from trainer.eval.stats import wilson_interval
from trainer.policies import Observation
from trainer.sim.env import EnvConfig, GraspEnv
from trainer.sim.labels import GRASP_YAW, OFFSET, SIZE, facts
from trainer.sim.rollout import Job, run_episode
from trainer.sim.sensors import make_sensor
from trainer.student import checkpoint
from trainer.student.model import hand_pose
from trainer.student.oracle_policy import OraclePolicy

GROUPS = {"offset": OFFSET, "offset_xy": slice(0, 2), "offset_z": slice(2, 3), "yaw": GRASP_YAW, "size": SIZE}


class ComposedPolicy(OraclePolicy):
    """``OraclePolicy``'s head and chunk execution, on the facts the depth student's readout reads."""

    def __init__(self, onnx_path: Path, head_path: Path, true: tuple[str, ...] = ()) -> None:
        super().__init__(head_path)
        self.meta = RuntimePolicy(onnx_path).metadata
        self.eye = checkpoint.load(onnx_path.parent / "ckpt.pt").policy()
        self.frames = FrameStack(self.meta.obs_horizon)
        self.true = [GROUPS[name] for name in true]
        self.stack = np.zeros(0, np.float32)

    def reset(self, env_info: dict) -> None:
        super().reset(env_info)
        self.frames.reset()

    def perceive(self, obs: Observation, eye: torch.nn.Module | None = None) -> tuple[np.ndarray, np.ndarray]:
        """The readout's facts (metres) of the current stack and its fine keypoints [K, 2] ([-1, 1]); with
        ``eye``, another depth student's on the same stack."""
        eye = self.eye if eye is None else eye
        state = torch.from_numpy(obs.state[None].astype(np.float32))
        with torch.no_grad():
            _, seen, fine = eye.perceive(torch.from_numpy(self.stack[None]), state)
            return eye.label_norm.unnormalise(seen)[0].numpy(), fine[0].numpy()

    @staticmethod
    def hand(obs: Observation) -> np.ndarray:
        """The grasp site (base frame, m) by the Panda's forward kinematics, as the student's graph has it."""
        return hand_pose(torch.from_numpy(obs.state[None].astype(np.float32)))[0, :3].numpy()

    def read_facts(self, obs: Observation) -> np.ndarray:
        row, _ = self.perceive(obs)
        truth = facts(obs.privileged, self._extent)
        for group in self.true:
            row[group] = truth[group]
        return row

    def act(self, obs: Observation) -> np.ndarray:
        if len(self.queue) < self.meta.obs_horizon:  # the frames the next chunk's stack holds
            self.stack = self.frames.push(normalise(obs.depth, DEPTH_SCALE, self.meta.preprocess))
        return super().act(obs)


def grasp_rate(policy: ComposedPolicy, args: argparse.Namespace) -> dict:
    """``policy``'s success over ``args.episodes`` of ``args.objects`` (seeds ``args.seed``.., kinds in turn,
    as ``trainer evaluate``) under the depth sensor ``args.sensor``: with its interval, by kind and episode by
    episode (to pair two policies on the same seeds)."""
    kinds, episodes, seed = select_kinds(args.objects), args.episodes, args.seed
    env = GraspEnv(EnvConfig(objects=kinds, randomise=True, depth=policy.meta.preprocess))
    sensor = None if args.sensor == "clean" else make_sensor(args.sensor)
    by_kind: dict[str, list[bool]] = {}
    grasped = []
    for i in range(episodes):
        job = Job(seed + i, kinds[i % len(kinds)])
        grasped.append(bool(run_episode(env, policy, job, sensor=sensor).success))
        by_kind.setdefault(job.kind, []).append(grasped[-1])
        print(f"{i + 1}/{episodes}: {sum(grasped)} grasped", flush=True)
    wins = sum(grasped)
    return {"success": wins / episodes, "ci95": list(wilson_interval(wins, episodes)), "episodes": episodes,
            "by_kind": {k: sum(v) / len(v) for k, v in by_kind.items()}, "grasped": grasped}


def parser(doc: str, objects: str, episodes: int) -> argparse.ArgumentParser:
    """The arguments every composed-policy experiment takes: the depth student, the head, what to run on."""
    p = argparse.ArgumentParser(description=doc.split("\n\n")[0])
    p.add_argument("student", type=Path, help="a depth student's ONNX file (its folder's ckpt.pt reads)")
    p.add_argument("head", type=Path, help="the privileged head (M0) checkpoint")
    p.add_argument("--objects", default=objects)
    p.add_argument("--episodes", type=int, default=episodes)
    p.add_argument("--seed", type=int, default=10_000, help="the first episode's seed")
    p.add_argument("--sensor", default="clean", help="the depth sensor the policy sees (trainer evaluate's)")
    p.add_argument("--out", type=Path, help="the result as JSON (with each episode's outcome, for pairing)")
    return p


def report(result: dict, out: Path | None) -> None:
    print(json.dumps(result))
    if out:
        out.write_text(json.dumps(result, indent=1))


def main() -> None:
    p = parser(__doc__, "seen", 60)
    p.add_argument("--true", nargs="*", default=[], choices=sorted(GROUPS))
    args = p.parse_args()
    policy = ComposedPolicy(args.student, args.head, tuple(args.true))
    report({"true": args.true, **grasp_rate(policy, args)}, args.out)


if __name__ == "__main__":
    main()
