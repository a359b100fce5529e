"""Scripted privileged expert: a top-down grasp planner on the true object pose.

Phases: approach (10 cm above the grasp point, hand turned so the fingers close across the object's
narrowest horizontal axis), descend, close, lift (object centre to p_target), hold. Each control step
solves damped-least-squares inverse kinematics on MuJoCo Jacobians of a kinematic copy of the arm for a
waypoint at most ``max_step_m`` from the hand, the hand's yaw kept (joint 7 alone turns it), and emits the
env action a = (q_ik - q) / s, joints 1-6 scaled down together to fit [-1, 1], plus the gripper command: the
same 8-d actions a learned teacher emits at 10 Hz.

``ReactiveExpert`` is the same planner without phase memory (its phase is read off each observation): the
labeller of the PPO teacher's DAgger warm start (``trainer.teacher.warmstart``).
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

import mujoco
import numpy as np

from hil_sim.kinematics import ArmKinematics, rotation_error
from hil_sim.world import TABLE_Z
from trainer.sim.env import FINGER_VELOCITIES, FINGERS, GRIPPER_COMMAND, OBJECT_POSITION, OBJECT_QUAT

_Goal = tuple[np.ndarray, np.ndarray, float]
_ANGLE_TOL = 0.05
"""Hand angle from the goal orientation that counts as arrived (rad)."""
_SHUT_M = 0.004
"""Finger opening (both slides) below which a closed gripper holds nothing."""


@dataclass(frozen=True)
class ExpertConfig:
    approach_height_m: float = 0.10
    """Height of the pre-grasp point above the grasp point."""
    max_step_m: float = 0.04
    """Longest Cartesian move asked of the hand per control step on the way to the pre-grasp point."""
    fine_step_m: float = 0.025
    """The same while descending and lifting, where a bent path would knock the object."""
    pad_offset_m: float = 0.015
    """Grasp site height above the object centre: puts the finger pads' middle on the centre."""
    tip_clearance_m: float = 0.054
    """Lowest grasp-site height above the table: fingertips (5.2 cm below it) clear it by 2 mm. Thin kinds
    (banana 1.8 cm, wheel 2.4 cm) are held only with the site between 5.0 and 5.8 cm; the middle of that
    window leaves an imitator 4 mm of height error either way."""
    palm_clearance_m: float = 0.034
    """Lowest grasp-site height below the object's top: the palm (4.5 cm above it) must not press on
    tall objects such as the can, which tips them out of the fingers."""
    close_steps: int = 6
    """Steps to wait for the fingers to close before lifting."""
    pos_tol_m: float = 0.004
    """How close the hand must be to the pre-grasp and grasp points: fingers clear an object by ~6 mm."""
    funnel_radius_m: float = 0.02
    """ReactiveExpert: horizontal offset from the grasp point at which the hand must be at the pre-grasp
    height; nearer, it may be proportionally lower."""
    funnel_rad: float = 0.3
    """ReactiveExpert: the same for the hand's angle from the grasp orientation (the two add up)."""
    finger_still_mps: float = 0.003
    """ReactiveExpert: finger speed under which a closed gripper has finished closing."""
    ik_iters: int = 15
    ik_damping: float = 0.05
    null_gain: float = 0.05
    """Pull towards the home pose in the Jacobian's null space (keeps the elbow tidy)."""


class Phase(enum.IntEnum):
    APPROACH = 0
    DESCEND = 1
    CLOSE = 2
    LIFT = 3


class ScriptedExpert:
    """``reset(env_info)`` then ``act(obs)`` with ``obs.privileged`` the env's 40-d observation."""

    def __init__(self, config: ExpertConfig | None = None) -> None:
        self.config = config or ExpertConfig()
        self._kin = ArmKinematics()
        self._phase, self._count = Phase.APPROACH, 0
        self._target = np.zeros(3)
        self._extent = np.full(3, 0.03)
        self._scale = 0.05
        self._lift_offset = np.zeros(3)

    def reset(self, env_info: dict) -> None:
        self._target = np.asarray(env_info["p_target"], float)
        self._extent = np.asarray(env_info["object_half_extent"], float)
        self._scale = float(env_info["action_scale"])
        self._phase, self._count = Phase.APPROACH, 0

    @property
    def phase(self) -> Phase:
        return self._phase

    def act(self, obs) -> np.ndarray:
        priv = np.asarray(getattr(obs, "privileged", obs), float)
        q = priv[:7]
        ee, rot = self._kin.site(priv[:9])
        goal, rot_goal, gripper = self._plan(priv, ee, rot)
        step = self.config.max_step_m if self._phase == Phase.APPROACH else self.config.fine_step_m
        waypoint = ee + _clip_norm(goal - ee, step)
        # Joint 7 alone turns the hand: the IK keeps the hand's yaw, and the turn is added to joint 7. Asked
        # for the turn, damped least squares shares it among joints 1, 3, 5 and 7 (all near vertical here),
        # and the others' share, scaled down with them, slows and bends the hand's path while it turns.
        now = fingers_yaw(rot)
        q_ik = self._kin.solve(priv[:9], waypoint, _top_down(now), self.config)
        q_ik[6] -= nearest_turn(now, fingers_yaw(rot_goal)) - now  # d(yaw)/d(q7) = -1: z points down
        delta = (q_ik - q) / self._scale
        # Scale joints 1-6 together, not one by one: clipping them separately bends the hand's path.
        # Joint 7 turns the hand about its own axis, which holds the grasp site, so it may clip alone.
        delta[:6] /= max(1.0, float(np.abs(delta[:6]).max()))
        delta[6] = np.clip(delta[6], -1.0, 1.0)
        return np.append(delta, gripper).astype(np.float32)

    def _grasp_pose(self, priv: np.ndarray, rot: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Grasp-site position and top-down hand frame of the grasp on the object as it lies now."""
        c = self.config
        obj = priv[OBJECT_POSITION]
        height = max(obj[2] + c.pad_offset_m, obj[2] + self._extent[2] - c.palm_clearance_m,
                     TABLE_Z + c.tip_clearance_m)
        return np.array([obj[0], obj[1], height]), _top_down(self._grasp_yaw(priv[OBJECT_QUAT], rot))

    def _plan(self, priv: np.ndarray, ee: np.ndarray, rot: np.ndarray) -> _Goal:
        """Goal position and hand frame for this step, and the gripper command."""
        c = self.config
        obj = priv[OBJECT_POSITION]
        grasp, rot_goal = self._grasp_pose(priv, rot)
        self._count += 1
        if self._phase == Phase.APPROACH:
            goal = grasp + [0.0, 0.0, c.approach_height_m]
            if _arrived(ee, goal, rot, rot_goal, c.pos_tol_m) or self._count > 60:
                self._next(Phase.DESCEND)
            return goal, rot_goal, -1.0
        if self._phase == Phase.DESCEND:
            if _arrived(ee, grasp, rot, rot_goal, c.pos_tol_m) or self._count > 25:
                self._next(Phase.CLOSE)
                self._lift_offset = ee - obj
            return grasp, rot_goal, -1.0
        if self._phase == Phase.CLOSE:
            if self._count >= c.close_steps:
                self._next(Phase.LIFT)
            return ee, rot, 1.0
        return self._target + self._lift_offset, rot, 1.0

    def _next(self, phase: Phase) -> None:
        self._phase, self._count = phase, 0

    def round_in_plan(self) -> bool:
        """Whether the object is round seen from above: any closing direction works on it."""
        return abs(self._extent[0] - self._extent[1]) < 0.1 * max(self._extent[:2])

    def _grasp_yaw(self, obj_quat: np.ndarray, rot: np.ndarray) -> float:
        """Closing direction across the object's narrow horizontal axis, the one nearest the hand's now."""
        now = fingers_yaw(rot)
        if self.round_in_plan():
            return now  # turning the wrist only costs time
        mat = np.zeros(9)
        mujoco.mju_quat2Mat(mat, obj_quat)
        axis = mat.reshape(3, 3)[:, 0 if self._extent[0] <= self._extent[1] else 1]
        return nearest_turn(now, np.arctan2(axis[1], axis[0]))


class ReactiveExpert(ScriptedExpert):
    """The same planner with its phase read off the current observation instead of remembered: open ->
    down a funnel onto the grasp point (approach, descend); at it -> close; closed on the object -> lift
    (or wait while the fingers still move); closed on nothing -> open and start again.

    A memoryless policy can represent this map (the phase machine's hidden state is what made cloning
    ``ScriptedExpert`` fail), and it labels any state, the learner's included, as DAgger needs."""

    def _plan(self, priv: np.ndarray, ee: np.ndarray, rot: np.ndarray) -> _Goal:
        c = self.config
        grasp, rot_goal = self._grasp_pose(priv, rot)
        if priv[GRIPPER_COMMAND] > 0 and _holding(priv, ee):
            if np.abs(priv[FINGER_VELOCITIES]).max() > c.finger_still_mps:
                self._phase = Phase.CLOSE
                return ee, rot, 1.0
            self._phase = Phase.LIFT
            return self._target + ee - priv[OBJECT_POSITION], rot, 1.0
        rel = ee - grasp
        angle = np.linalg.norm(rotation_error(rot, rot_goal))
        offset = np.linalg.norm(rel[:2])
        if offset < c.pos_tol_m and rel[2] < c.pos_tol_m and angle < _ANGLE_TOL:
            self._phase = Phase.CLOSE
            return ee, rot, 1.0
        # A funnel over the grasp point instead of a switch between "approach" and "descend": the hand
        # may be lower the better it is aligned (fully down within the arrival tolerances), so the labels
        # change smoothly with the state.
        misalignment = (max(0.0, offset - c.pos_tol_m) / c.funnel_radius_m
                        + max(0.0, angle - _ANGLE_TOL) / c.funnel_rad)
        self._phase = Phase.DESCEND if misalignment < 1.0 else Phase.APPROACH
        return grasp + [0.0, 0.0, c.approach_height_m * min(1.0, misalignment)], rot_goal, -1.0


def aim_bias(rng: np.random.Generator, bias_m: float) -> np.ndarray:
    """The constant horizontal error, ``bias_m`` long, of a biased policy's reading of where the object is,
    in a direction drawn from ``rng``: the episode's own, fresh from its seed, so every kind of biased policy
    errs the same way in the same episode and their tolerance cells pair."""
    angle = rng.uniform(0, 2 * np.pi)
    return bias_m * np.array([np.cos(angle), np.sin(angle), 0.0])


class BiasedExpert(ReactiveExpert):
    """``ReactiveExpert`` reading the object ``bias_m`` off, in a horizontal direction drawn per episode
    (``aim_bias``): how far off a grasp may be aimed before it fails, the expert's own
    tolerance beside the head's (``oracle:CKPT@B``). Never a labeller."""

    def __init__(self, bias_m: float) -> None:
        super().__init__()
        self.bias_m, self._bias = bias_m, np.zeros(3)

    def reset(self, env_info: dict) -> None:
        super().reset(env_info)
        self._bias = aim_bias(np.random.default_rng(env_info["episode"]["seed"]), self.bias_m)

    def act(self, obs) -> np.ndarray:
        priv = np.array(getattr(obs, "privileged", obs), float)
        priv[OBJECT_POSITION] += self._bias
        return super().act(priv)


def _holding(priv: np.ndarray, ee: np.ndarray) -> bool:
    """The object is between the fingers (centre at most a fingertip's length, 7 cm, below the grasp site,
    fingers stopped short of shut)."""
    rel = priv[OBJECT_POSITION] - ee
    return bool(np.linalg.norm(rel[:2]) < 0.03 and -0.07 < rel[2] < 0.03
                and priv[FINGERS].sum() > _SHUT_M)


def fingers_yaw(rot: np.ndarray) -> float:
    """The yaw of the fingers' closing axis (the hand frame's y, ``_top_down``) of a hand rotation."""
    return float(np.arctan2(rot[1, 1], rot[0, 1]))


def nearest_turn(now: float, yaw: float) -> float:
    """The closing yaw equivalent to ``yaw`` (the fingers are symmetric: modulo pi) nearest the hand's
    ``now``."""
    return now + (yaw - now + np.pi / 2) % np.pi - np.pi / 2


def _top_down(yaw: float) -> np.ndarray:
    """Hand frame with z down and the finger closing axis (y) at ``yaw``."""
    y = np.array([np.cos(yaw), np.sin(yaw), 0.0])
    z = np.array([0.0, 0.0, -1.0])
    return np.column_stack([np.cross(y, z), y, z])


def _arrived(pos: np.ndarray, goal: np.ndarray, rot: np.ndarray, rot_goal: np.ndarray, tol: float) -> bool:
    angle = np.linalg.norm(rotation_error(rot, rot_goal))
    return bool(np.linalg.norm(goal - pos) < tol and angle < _ANGLE_TOL)


def _clip_norm(v: np.ndarray, limit: float) -> np.ndarray:
    n = np.linalg.norm(v)
    return v if n <= limit else v * (limit / n)
