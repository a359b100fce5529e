"""How a policy's failed episodes closed the gripper, beside its successful ones (issue 42, lever 3).

Runs the policy over the same seeds as ``trainer evaluate`` (10000..) on the given kinds (clean depth) and, at
the first step it commands the gripper shut, reads the simulator's labels (``trainer.sim.labels``): the object
centre's offset from the grasp site, and how far the fingers' closing axis is turned from the object's narrow
axis (0 degrees: the fingers close across the object's narrow side; round kinds have no such axis), and that
offset split along the fingers' closing axis and across the pads, and along the camera's line of sight and
across it (the fingers forgive ~1.5 cm along their closing axis, ~0.7 cm across the pads; the readout errs
along the sight). Prints the medians for the successes and the failures apart, then each failure. With
``--takeover`` the expert (``ReactiveExpert``) drives from the policy's first close on: if that grasps, the
policy's approach and close were good enough and what it did after them lost the episode. With ``--retry`` a
scripted reflex opens the gripper and lifts the hand 8 cm whenever it has closed on nothing, then gives the
policy back: the ceiling of teaching the policy to try again after a missed close (its own perception still
aims the second try). ``--sensor`` (a ``trainer.sim.sensors`` spec, e.g. stereo) is what the policy reads.

    python research/m0_failures.py oracle:CKPT [--kinds banana pear] [--episodes 40] [--sensor stereo]
        [--takeover | --retry]
"""

from __future__ import annotations

import argparse

import numpy as np
import torch

from research.own_frame_readout import ACROSS, SIGHT
from trainer.policies import NEEDS_DEPTH, Observation, depth_spec, make_policy, parse
from trainer.sim.env import EnvConfig, GraspEnv
from trainer.sim.labels import GRASP_YAW, OFFSET, frame_labels
from trainer.sim.rollout import run_episode, schedule
from trainer.sim.sensors import make_sensor, reads_clean_depth
from trainer.student.model import hand_pose, into_fingers
from trainer.teacher.scripted import _SHUT_M, Phase, ReactiveExpert, ScriptedExpert


def yaw_error_deg(labels: np.ndarray, state: np.ndarray) -> float:
    """Angle between the fingers' closing axis and the object's narrow axis (nan for a round kind)."""
    doubled = torch.from_numpy(labels[None, GRASP_YAW].astype(np.float32))
    if float(doubled.norm()) == 0.0:
        return float("nan")
    cos2, sin2 = into_fingers(doubled, hand_pose(torch.from_numpy(state[None].astype(np.float32))))[0]
    return abs(float(np.degrees(np.arctan2(float(sin2), float(cos2)) / 2)))


def split_cm(offset: np.ndarray, state: np.ndarray) -> np.ndarray:
    """A horizontal offset (cm) -> |its part| along the fingers' closing axis, across the pads, along the
    camera's line of sight and across it."""
    axis = hand_pose(torch.from_numpy(state[None].astype(np.float32)))[0, 6:8].numpy()
    axis = axis / np.linalg.norm(axis)
    pads = np.array([-axis[1], axis[0]])
    return np.abs([offset[:2] @ axis, offset[:2] @ pads, offset[:2] @ SIGHT, offset[:2] @ ACROSS])


class FirstClose:
    """Wraps a policy and reads the labels (offset in cm, yaw error in degrees, ``split_cm``) at its first
    close."""

    NONE = (np.full(3, np.nan), float("nan"), np.full(4, np.nan))

    def __init__(self, policy, env: GraspEnv) -> None:
        self.policy, self.env = policy, env
        self.close = self.NONE

    def reset(self, info: dict) -> None:
        self.policy.reset(info)
        self.close = self.NONE

    @property
    def closed(self) -> bool:
        return not np.isnan(self.close[0]).all()

    def act(self, observation: Observation) -> np.ndarray:
        action = np.asarray(self.policy.act(observation), np.float32)
        if not self.closed and action[7] > 0:
            labels, state = frame_labels(self.env), observation.state
            offset = labels[OFFSET] * 100
            self.close = (offset, yaw_error_deg(labels, state), split_cm(offset, state))
        return action


class Takeover(FirstClose):
    """The policy until its first close, the expert from then on."""

    def __init__(self, policy, env: GraspEnv) -> None:
        super().__init__(policy, env)
        self.expert = ReactiveExpert()

    def reset(self, info: dict) -> None:
        super().reset(info)
        self.expert.reset(info)

    def act(self, observation: Observation) -> np.ndarray:
        if self.closed:
            return self.expert.act(observation)
        action = super().act(observation)
        return self.expert.act(observation) if self.closed else action


class Rise(ScriptedExpert):
    """Opens the gripper and moves the hand straight up by ``RISE_M`` from where ``start`` found it."""

    RISE_M = 0.08
    goal = np.zeros(3)

    def start(self, privileged: np.ndarray) -> None:
        self.goal = self._kin.site(np.asarray(privileged)[:9])[0] + [0.0, 0.0, self.RISE_M]

    def _plan(self, priv, ee, rot):
        self._phase = Phase.APPROACH
        return self.goal, rot, -1.0


class Retry(FirstClose):
    """The policy, but whenever its gripper has shut on nothing a reflex opens it and lifts the hand
    (``Rise``, for ``STEPS`` steps), then the policy drives again from an empty action queue."""

    STEPS = 8

    def __init__(self, policy, env: GraspEnv) -> None:
        super().__init__(policy, env)
        self.rise, self.left, self.retries, self.last_gripper = Rise(), 0, 0, -1.0

    def reset(self, info: dict) -> None:
        super().reset(info)
        self.rise.reset(info)
        self.left, self.retries, self.last_gripper = 0, 0, -1.0

    def act(self, observation: Observation) -> np.ndarray:
        state = observation.state
        shut = self.closed and self.last_gripper > 0 and state[7] < _SHUT_M
        if shut and not self.left:
            self.left, self.retries = self.STEPS, self.retries + 1
            self.rise.start(observation.privileged)
        if self.left:
            self.left -= 1
            if not self.left:
                self.policy.queue.clear()
            action = self.rise.act(observation)
            self.last_gripper = -1.0
            return action
        action = super().act(observation)
        self.last_gripper = float(action[7])
        return action


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("policy")
    p.add_argument("--kinds", nargs="+", default=["banana", "pear"])
    p.add_argument("--episodes", type=int, default=40)
    p.add_argument("--sensor", default="clean", help="the depth the policy reads (trainer.sim.sensors)")
    mode = p.add_mutually_exclusive_group()
    mode.add_argument("--takeover", action="store_true",
                      help="the expert drives from the policy's first close")
    mode.add_argument("--retry", action="store_true", help="a reflex opens and lifts after each missed close")
    args = p.parse_args()
    kinds = tuple(args.kinds)
    reads_env_depth = NEEDS_DEPTH[parse(args.policy)[0]] and reads_clean_depth(args.sensor)
    env = GraspEnv(EnvConfig(objects=kinds, randomise=True, depth=depth_spec(args.policy),
                             render_depth=reads_env_depth))
    wrapper = Takeover if args.takeover else Retry if args.retry else FirstClose
    policy = wrapper(make_policy(args.policy), env)
    sensor = None if args.sensor == "clean" else make_sensor(args.sensor)
    rows = []
    for job in schedule(kinds, 10_000, args.episodes):
        rollout = run_episode(env, policy, job, sensor=sensor)
        rows.append((job.kind, rollout.success, rollout.steps, *policy.close))
        if args.retry and policy.retries:
            outcome = "grasped" if rollout.success else "lost"
            print(f"  {job.kind} seed {job.seed}: {policy.retries} retries, {outcome}")
    for success in (True, False):
        chosen = [row for row in rows if row[1] == success]
        if chosen:
            offsets = np.array([row[3] for row in chosen])
            apart = np.nanmedian(np.linalg.norm(offsets[:, :2], axis=1))
            yaw = np.nanmedian([row[4] for row in chosen])
            split = np.nanmedian([row[5] for row in chosen], axis=0)
            print(f"{'successes' if success else 'failures'} {len(chosen)}: closes {apart:.2f} cm apart "
                  f"horizontally ({split[0]:.2f} along the closing axis, {split[1]:.2f} across the pads; "
                  f"{split[2]:.2f} along the sight, {split[3]:.2f} across it), height offset "
                  f"{np.nanmedian(offsets[:, 2]):.2f} cm, fingers {yaw:.0f} deg off the narrow axis "
                  "(medians)")
    for kind, success, steps, offset, yaw, split in rows:
        if not success:
            print(f"  failed {kind}: {steps} steps, closed at object - hand {np.round(offset, 2)} cm "
                  f"(closing axis, pads, sight, across it: {np.round(split, 2)}), {yaw:.0f} deg")


if __name__ == "__main__":
    main()
