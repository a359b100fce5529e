"""hil_sim's MuJoCo Panda as a driver ``Backend``: what ``runtime.franka_driver``'s server drives in the rig.

The world is shared with a physics thread (and in hil_sim's server a camera thread): every access holds
``lock``.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

import mujoco
import numpy as np

from hil_sim.world import ARM_JOINTS, EE_SITE, World
from runtime.franka_driver.backend import Reading
from runtime.franka_driver.kinematics import HIL_SIM_Q_OFFSET

BASE_BODY = "robot_base"


class MujocoBackend:
    """``Backend`` over a ``World``. Joint angles cross it in libfranka's convention, as with the real arm:
    the model's joint 6 reads ``HIL_SIM_Q_OFFSET`` less."""

    def __init__(self, world: World, lock: threading.Lock, *,
                 on_close: Callable[[], None] | None = None) -> None:
        self.world, self.lock = world, lock
        m = world.model
        self._qadr = m.jnt_qposadr[[m.joint(n).id for n in ARM_JOINTS]]
        self._site = m.site(EE_SITE).id
        self._base = m.body(BASE_BODY).id
        self._scratch = mujoco.MjData(m)  # forward kinematics of targets, never of the live state
        self._gripper_closed = False
        self._on_close = on_close
        self._offset = np.asarray(HIL_SIM_Q_OFFSET)

    def read(self) -> Reading:
        with self.lock:
            q, dq, width = self.world.q, self.world.dq, self.world.gripper_opening
        return Reading(time.monotonic(), q + self._offset, dq, width)

    def command(self, *, q_target: np.ndarray, gripper_closed: bool) -> None:
        with self.lock:
            self.world.set_targets(np.asarray(q_target) - self._offset, 1.0 if gripper_closed else -1.0)
        self._gripper_closed = gripper_closed

    def hold(self) -> None:
        with self.lock:
            self.world.set_targets(self.world.q, 1.0 if self._gripper_closed else -1.0)

    def tcp(self, q: np.ndarray) -> np.ndarray:
        d = self._scratch
        d.qpos[self._qadr] = np.asarray(q) - self._offset
        mujoco.mj_kinematics(self.world.model, d)
        return d.site_xpos[self._site] - d.xpos[self._base]

    def close(self) -> None:
        self.hold()
        if self._on_close is not None:
            self._on_close()
