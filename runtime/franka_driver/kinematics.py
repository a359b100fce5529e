"""Forward kinematics of the Franka Panda from its published modified-DH (Craig) parameters.

The real backend needs the end-effector position of a *target* (not only of the measured pose, which
libfranka reports as ``O_T_EE``) to check the workspace box before the arm gets there.
"""

from __future__ import annotations

import numpy as np

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


def _link(a: float, d: float, alpha: float, theta: float) -> np.ndarray:
    ca, sa, ct, st = np.cos(alpha), np.sin(alpha), np.cos(theta), np.sin(theta)
    return np.array([[ct, -st, 0.0, a],
                     [st * ca, ct * ca, -sa, -d * sa],
                     [st * sa, ct * sa, ca, d * ca],
                     [0.0, 0.0, 0.0, 1.0]])


def panda_tcp(q: np.ndarray) -> np.ndarray:
    """Position (3,) of the Franka Hand's TCP in the robot base frame, metres."""
    q = np.asarray(q, dtype=float)
    if q.shape != (7,):
        raise ValueError(f"panda_tcp needs 7 joint angles, got shape {q.shape}")
    pose = np.eye(4)
    for (a, d, alpha), theta in zip(_DH, q, strict=True):
        pose = pose @ _link(a, d, alpha, theta)
    return (pose @ np.array([0.0, 0.0, FLANGE_D + HAND_TCP_D, 1.0]))[:3]
