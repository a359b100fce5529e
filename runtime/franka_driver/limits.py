"""Franka Panda joint limits (vendor datasheet, "Robot and interface specifications")."""

from __future__ import annotations

import numpy as np

DOF = 7
Q_MIN = np.array([-2.8973, -1.7628, -2.8973, -3.0718, -2.8973, -0.0175, -2.8973])
Q_MAX = np.array([2.8973, 1.7628, 2.8973, -0.0698, 2.8973, 3.7525, 2.8973])
DQ_MAX = np.array([2.1750, 2.1750, 2.1750, 2.1750, 2.6100, 2.6100, 2.6100])
"""Joint velocity limits, rad/s."""
GRIPPER_MAX_WIDTH = 0.08
"""Franka Hand opening, metres."""
READY_Q = np.array([0.0, -np.pi / 4, 0.0, -3 * np.pi / 4, 0.0, np.pi / 2, np.pi / 4])
"""The vendor's 'ready' pose: well inside every limit."""
