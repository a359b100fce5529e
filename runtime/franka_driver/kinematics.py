"""The Franka Panda's published numbers: joint limits (datasheet, "Robot and interface specifications") and
forward kinematics from its modified-DH (Craig) parameters. The driver needs the end-effector position of a
*target* (libfranka reports only the measured pose's, ``O_T_EE``) to check the workspace box before the arm
gets there.
"""

from __future__ import annotations

import numpy as np

DOF = 7
Q_MIN = np.array([-2.8973, -1.7628, -2.8973, -3.0718, -2.8973, -0.0175, -2.8973])
Q_MAX = np.array([2.8973, 1.7628, 2.8973, -0.0698, 2.8973, 3.7525, 2.8973])
DQ_MAX = np.array([2.1750, 2.1750, 2.1750, 2.1750, 2.6100, 2.6100, 2.6100])  # rad/s
GRIPPER_MAX_WIDTH = 0.08  # Franka Hand opening, metres
READY_Q = np.array([0.0, -np.pi / 4, 0.0, -3 * np.pi / 4, 0.0, np.pi / 2, np.pi / 4])  # vendor's 'ready'

# (a, d, alpha) per joint, metres and radians; then the flange and the Franka Hand's TCP offset.
_DH = np.array([
    [0.0, 0.333, 0.0],
    [0.0, 0.0, -np.pi / 2],
    [0.0, 0.316, np.pi / 2],
    [0.0825, 0.0, np.pi / 2],
    [-0.0825, 0.384, -np.pi / 2],
    [0.0, 0.0, np.pi / 2],
    [0.088, 0.0, np.pi / 2],
])
FLANGE_D = 0.107
HAND_TCP_D = 0.1034
HIL_SIM_Q_OFFSET = (0.0, 0.0, 0.0, 0.0, 0.0, np.pi / 2, 0.0)
"""libfranka's joint angles minus hil_sim's for the same pose: the Franka Kitchen MJCF that hil_sim's arm is
built from turns link 6 a quarter turn from the DH frames above, so its joint 6 reads pi/2 less."""


def link_transform(a: float, d: float, alpha: float, theta, xp=np):
    """Modified-DH transform of one link, [..., 4, 4], for joint angles ``theta`` of any batch shape.
    ``xp`` is the array module (numpy here; the student network passes torch to build the same chain into
    its graph), so there is one implementation of the arm's kinematics."""
    ct, st = xp.cos(theta), xp.sin(theta)
    ca, sa = float(np.cos(alpha)), float(np.sin(alpha))
    zero = theta * 0.0
    rows = [[ct, -st, zero, zero + a],
            [st * ca, ct * ca, zero - sa, zero - d * sa],
            [st * sa, ct * sa, zero + ca, zero + d * ca],
            [zero, zero, zero, zero + 1.0]]
    return xp.stack([xp.stack(row, axis=-1) for row in rows], axis=-2)


def tcp_frame(q, xp=np):
    """Position [..., 3] (base frame, metres) and rotation [..., 3, 3] of the Franka Hand's TCP (the hand's
    own -45 degree turn about the flange axis left out) for joint angles ``q`` [..., 7]."""
    pose = link_transform(*_DH[0], q[..., 0], xp)
    for i in range(1, 7):
        pose = pose @ link_transform(*_DH[i], q[..., i], xp)
    rot = pose[..., :3, :3]
    return pose[..., :3, 3] + (FLANGE_D + HAND_TCP_D) * rot[..., :, 2], rot


def panda_tcp(q: np.ndarray) -> np.ndarray:
    """Position (3,) of the Franka Hand's TCP in the robot base frame, metres."""
    q = np.asarray(q, dtype=float)
    if q.shape != (7,):
        raise ValueError(f"panda_tcp needs 7 joint angles, got shape {q.shape}")
    return tcp_frame(q)[0]
