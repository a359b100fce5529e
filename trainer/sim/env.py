"""``GraspEnv``: the paper's teacher interface over ``hil_sim.world.World`` (gymnasium API).

Observation, 40 float32 (privileged; paper III-A lists 36 of them, the last 4 are ours):
    [0:9]   joint positions: 7 arm joints (rad) + 2 finger slides (m)
    [9:18]  joint velocities, same order
    [18:25] grasp-site pose: position (m, world frame) + quaternion (w, x, y, z)
    [25:32] object pose: position + quaternion
    [32:35] target position p_target: the object's start x, y at ``lift_height_m`` above the table
    [35]    log(category id) (built-ins 1..12, user objects 13+)
    [36:39] object position minus grasp-site position
    [39]    last gripper command (-1 open, +1 close)
Action, 8 in [-1, 1]: a[:7] joint-position deltas, q_target = q + s * a (eq. 1, s = ``action_scale``);
a[7] gripper, > 0 closes. One step = 1 / ``control_rate_hz`` s of physics.
Success: the object is held by both fingers within ``success_tol_m`` of p_target (its centre 40 cm above
the table top, over its start position) for ``hold_steps`` consecutive steps, i.e. grasped, lifted and
not dropped. The episode ends there, when the object leaves the table, or after ``max_steps``.
``info`` carries what students see: ``depth`` (uint16 mm: the episode's crop window rendered at the policy
resolution, ``EnvConfig.depth``, 96x128 by default; equal to ``runtime.preprocess.crop_resize`` of the 848x480
stream up to sub-pixel sampling, see ``exact_frame``) and ``state`` (7 joints + gripper opening, m).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import gymnasium as gym
import numpy as np

from hil_sim import objects
from hil_sim.world import TABLE_Z, Randomisation, World
from runtime.preprocess import DepthSpec, crop_resize
from trainer.sim.reward import Measures, RewardWeights, Status, reward

OBS_DIM = 40
ACTION_DIM = 8
# The layout above by name: every reader of the 40 numbers indexes them with these.
FINGERS = slice(7, 9)
FINGER_VELOCITIES = slice(16, 18)
HAND_POSITION = slice(18, 21)
HAND_QUAT = slice(21, 25)
OBJECT_POSITION = slice(25, 28)
OBJECT_QUAT = slice(28, 32)
LOG_CATEGORY = 35
OBJECT_FROM_HAND = slice(36, 39)
GRIPPER_COMMAND = 39


@dataclass(frozen=True)
class EnvConfig:
    objects: tuple[str, ...] = objects.SEEN
    """Object kinds drawn at reset (built-in names or user object paths)."""
    action_scale: float = 0.05
    """s of eq. 1: radians per unit action per control step."""
    control_rate_hz: float = 10.0
    max_steps: int = 150
    """15 s at 10 Hz: the scripted expert needs 60-110 steps (joint speed is capped at s * rate)."""
    lift_height_m: float = 0.40
    success_tol_m: float = 0.04
    hold_steps: int = 5
    """Consecutive steps at the target (0.5 s at 10 Hz) that count as lifted without dropping."""
    randomise: bool = True
    """Domain randomisation (dynamics, initial joints, camera pose, crop window)."""
    wrist_noise: float = Randomisation.wrist_noise
    """Uniform +- noise on the wrist's home angle at reset, rad (``Randomisation.wrist_noise``)."""
    render_depth: bool = True
    """Render the depth frame every step (off for state-only teachers: much faster)."""
    render_rgb: bool = False
    depth: DepthSpec = DepthSpec()
    """Crop and resolution of the policy's depth (a student file's own: ``trainer.policies.depth_spec``)."""
    weights: RewardWeights = field(default_factory=RewardWeights)

    def __post_init__(self) -> None:
        if not self.objects:
            raise ValueError("EnvConfig.objects must name at least one object kind")
        if not (self.action_scale > 0 and self.control_rate_hz > 0 and self.max_steps > 0):
            raise ValueError(f"action_scale, control_rate_hz and max_steps must be positive, got "
                             f"{self.action_scale}, {self.control_rate_hz}, {self.max_steps}")


class GraspEnv(gym.Env):
    metadata = {"render_modes": []}

    def __init__(self, config: EnvConfig | None = None) -> None:
        self.config = config or EnvConfig()
        self.spec = self.config.depth
        self.world = World(self.config.objects, spec=self.spec,
                           randomisation=Randomisation(wrist_noise=self.config.wrist_noise))
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, (OBS_DIM,), np.float32)
        self.action_space = gym.spaces.Box(-1.0, 1.0, (ACTION_DIM,), np.float32)
        self._dt = 1.0 / self.config.control_rate_hz
        self._target = np.zeros(3)
        self._gripper = -1.0
        self._steps = self._n_success = 0
        self._prev: Measures | None = None
        self._prev_dq = np.zeros(7)

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[np.ndarray, dict]:
        super().reset(seed=seed)
        options = options or {}
        episode_seed = int(seed if seed is not None else self.np_random.integers(2**31))
        kinds = list(self.world.kinds)
        kind = options.get("kind") or kinds[np.random.default_rng(episode_seed).integers(len(kinds))]
        episode = self.world.reset(kind, episode_seed, randomise=self.config.randomise)
        obj_pos, _ = self.world.object_pose()
        self._target = np.array([obj_pos[0], obj_pos[1], TABLE_Z + self.config.lift_height_m])
        self._gripper, self._steps, self._n_success = -1.0, 0, 0
        self._prev, self._prev_dq = self._measures(), self.world.dq
        info = self._info(success=False)
        info.update(episode=episode.to_dict(), kind=kind, p_target=self._target.copy(),
                    object_half_extent=self.world.object_extent(), control_dt=self._dt,
                    action_scale=self.config.action_scale)
        return self.observation(), info

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict]:
        action = np.asarray(action, dtype=np.float64)
        if action.shape != (ACTION_DIM,) or not np.all(np.isfinite(action)):
            raise ValueError(f"action must be {ACTION_DIM} finite numbers, got shape {action.shape}")
        self._act(action)
        self._steps += 1
        if not np.all(np.isfinite(self.world.data.qpos)):
            return self.observation(), 0.0, True, False, {**self._info(False), "unstable": True}
        now, status = self._measures(), self._status()
        self._n_success = self._n_success + 1 if status.at_target and status.grasped else 0
        dq = self.world.dq
        r, terms = reward(self.config.weights, self._prev, now, status, self._n_success,
                          (dq - self._prev_dq) / self._dt)
        self._prev, self._prev_dq = now, dq
        success = self._n_success >= self.config.hold_steps
        fell = self.world.object_pose()[0][2] < TABLE_Z - 0.1
        info = {**self._info(success), "terms": terms, "grasped": status.grasped}
        return self.observation(), r, success or fell, self._steps >= self.config.max_steps, info

    def lookahead(self, actor: Callable[[np.ndarray], np.ndarray], steps: int) -> np.ndarray:
        """The actions [steps, 8] ``actor`` (a function of the 40-d observation, e.g. ``ReactiveExpert.act``)
        takes over the next ``steps`` steps from this state, found by running the physics ahead and restoring
        it: an expert's action chunk at a state the expert did not reach itself, DAgger's label. The env is
        left as it was (physics state, gripper command, counters); no frame is rendered."""
        saved, gripper, actions = self.world.snapshot(), self._gripper, []
        try:
            for _ in range(steps):
                actions.append(np.asarray(actor(self.observation()), np.float32))
                self._act(actions[-1])
        finally:
            self.world.restore(saved)
            self._gripper = gripper
        return np.stack(actions)

    def observation(self) -> np.ndarray:
        w = self.world
        fingers_q, fingers_dq = w.finger_state()
        ee_pos, ee_quat = w.ee_pose()
        obj_pos, obj_quat = w.object_pose()
        obs = np.concatenate([w.q, fingers_q, w.dq, fingers_dq,
                              ee_pos, ee_quat, obj_pos, obj_quat, self._target,
                              [np.log(w.kind.category_id)], obj_pos - ee_pos, [self._gripper]])
        return obs.astype(np.float32)

    def frame(self) -> np.ndarray:
        """The policy-resolution uint16 depth frame the student would see now: the episode's crop window
        rendered directly at the policy resolution (``World.render_policy_depth``, 8x cheaper than the
        848x480 stream at 96x128)."""
        return self.world.render_policy_depth()

    def exact_frame(self) -> np.ndarray:
        """The same through the deploy path: the full stream frame, then ``crop_resize``."""
        return crop_resize(self.world.render_depth(), self.spec, self.world.episode.crop_window)

    def rgb_frame(self) -> np.ndarray:
        """RGB of the same crop window at the policy resolution, uint8 [H, W, 3]."""
        return self.world.render_policy_rgb()

    def close(self) -> None:
        self.world.close()

    # --- internals ---------------------------------------------------------------------------------
    def _act(self, action: np.ndarray) -> None:
        """Paper eq. 1 and the gripper command, then one control period of physics."""
        self._gripper = 1.0 if action[7] > 0 else -1.0
        q_target = self.world.q + self.config.action_scale * np.clip(action[:7], -1.0, 1.0)
        self.world.set_targets(q_target, self._gripper)
        self.world.step(self._dt)

    def _info(self, success: bool) -> dict:
        info = {"state": self.world.joint_state(), "success": success, "steps": self._steps}
        if self.config.render_depth:
            info["depth"] = self.frame()
        if self.config.render_rgb:
            info["rgb"] = self.rgb_frame()
        return info

    def _measures(self) -> Measures:
        ee_pos, _ = self.world.ee_pose()
        obj_pos, _ = self.world.object_pose()
        points = np.vstack([ee_pos, self.world.finger_positions()])
        hand_axis = self.world.ee_xmat()[:, 2]
        dphi = float(np.arccos(np.clip(-hand_axis[2], -1.0, 1.0)))
        return Measures(float(np.linalg.norm(points - obj_pos, axis=1).sum()),
                        float(np.linalg.norm(obj_pos - self._target)), dphi)

    def _status(self) -> Status:
        left, right = self.world.finger_contacts()
        grasped = self._gripper > 0 and left and right
        obj_pos = self.world.object_pose()[0]
        lifted = grasped and obj_pos[2] > TABLE_Z + self.world.object_extent()[2] + 0.02
        at_target = bool(np.linalg.norm(obj_pos - self._target) < self.config.success_tol_m)
        return Status(bool(grasped), bool(lifted), at_target)

