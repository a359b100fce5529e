"""Forward and inverse kinematics of the Panda's grasp site on a robot-only copy of the world's model.

Used by the scripted expert (IK waypoints) and by the student's trainer (where the hand was in each demo
step, from the recorded joint state alone).
"""

from __future__ import annotations

from typing import Protocol

import mujoco
import numpy as np

from hil_sim.world import HOME_Q, World


class IKSettings(Protocol):
    ik_iters: int
    ik_damping: float
    null_gain: float


class ArmKinematics:
    """A robot-only copy of the world for forward kinematics and Jacobians of the ``end_effector`` site."""

    def __init__(self) -> None:
        world = World(kinds=())
        self.model = world.model
        self.data = mujoco.MjData(world.model)
        self._site_id = world.model.site("end_effector").id
        self._n = 9

    def _set(self, q9: np.ndarray) -> None:
        self.data.qpos[: self._n] = q9
        mujoco.mj_kinematics(self.model, self.data)

    def site(self, q9: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Grasp-site position (world frame, m) and rotation matrix at joint angles ``q9`` (7 arm joints +
        2 finger slides)."""
        self._set(q9)
        sid = self._site_id
        return self.data.site_xpos[sid].copy(), self.data.site_xmat[sid].reshape(3, 3).copy()

    def solve(self, q9: np.ndarray, pos: np.ndarray, rot: np.ndarray, c: IKSettings) -> np.ndarray:
        """Joint angles putting the grasp site at ``pos`` with frame ``rot`` (damped least squares)."""
        q = np.array(q9, float)
        for _ in range(c.ik_iters):
            err, J = self._error_jacobian(q, pos, rot)
            if np.linalg.norm(err) < 1e-4:
                break
            q[:7] += J.T @ np.linalg.solve(J @ J.T + c.ik_damping**2 * np.eye(6), err)
        _, J = self._error_jacobian(q, pos, rot)
        null = np.eye(7) - np.linalg.pinv(J) @ J
        return q[:7] + null @ (c.null_gain * (np.asarray(HOME_Q) - q[:7]))

    def _error_jacobian(self, q: np.ndarray, pos: np.ndarray, rot: np.ndarray) -> tuple[np.ndarray, ...]:
        self._set(q)
        mujoco.mj_comPos(self.model, self.data)
        jacp, jacr = np.zeros((3, self.model.nv)), np.zeros((3, self.model.nv))
        mujoco.mj_jacSite(self.model, self.data, jacp, jacr, self._site_id)
        cur = self.data.site_xmat[self._site_id].reshape(3, 3)
        err = np.concatenate([pos - self.data.site_xpos[self._site_id], rotation_error(cur, rot)])
        return err, np.vstack([jacp[:, :7], jacr[:, :7]])


def rotation_error(rot: np.ndarray, goal: np.ndarray) -> np.ndarray:
    """Small-angle rotation vector taking ``rot`` to ``goal``."""
    return 0.5 * sum(np.cross(rot[:, i], goal[:, i]) for i in range(3))
