"""Dense teacher reward, paper eq. 2-7, and the grasp/lift/success predicates it uses.

r_t = w1 r_reach + w2 r_lift + w3 r_orient + r_bonus - w4 p_accel                      (eq. 2)
r_reach  = d_hand(t-1) - d_hand(t); d_hand = sum of distances grasp site, left finger, right finger
           to the object centre                                                       (eq. 3)
r_lift   = is_grasped * (d_obj(t-1) - d_obj(t)); d_obj = |p_obj - p_target|             (eq. 4)
r_orient = is_lifted * (dphi(t-1) - dphi(t)); dphi = angle between the hand axis and
           straight down (the target orientation of a top-down grasp)                  (eq. 5)
r_bonus  = is_success * c1 * c2 ** min(N_success, n_cap)                              (eq. 6)
p_accel  = |ddq|^2 over the 7 arm joints, ddq from velocities 0.1 s apart (rad/s^2)    (eq. 7)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class RewardWeights:
    """Weights of eq. 2 and constants of eq. 6 (distances in m, angles in rad)."""

    w1: float = 10.0
    """Reach: 1 cm closer (on the 3-point composite distance) is worth 0.1."""
    w2: float = 20.0
    """Lift: moving a grasped object 1 cm towards the target is worth 0.2."""
    w3: float = 2.0
    """Orientation while lifted."""
    w4: float = 1e-4
    """Joint acceleration penalty: 10 rad/s^2 on one joint costs 0.01."""
    c1: float = 2.0
    c2: float = 1.1
    n_cap: int = 20
    """Caps N_success in c2**N so the bonus stays bounded (1.1**20 = 6.7)."""


@dataclass(frozen=True)
class Status:
    """Predicates at one control step."""

    grasped: bool
    lifted: bool
    at_target: bool


@dataclass(frozen=True)
class Measures:
    """The distances the shaping terms difference between steps."""

    d_hand: float
    d_obj: float
    dphi: float


def reward(w: RewardWeights, prev: Measures, now: Measures, status: Status, n_success: int,
           ddq: np.ndarray) -> tuple[float, dict[str, float]]:
    """Eq. 2 and its terms (already weighted, penalty negative) for logging."""
    terms = {
        "reach": w.w1 * (prev.d_hand - now.d_hand),
        "lift": w.w2 * float(status.grasped) * (prev.d_obj - now.d_obj),
        "orient": w.w3 * float(status.lifted) * (prev.dphi - now.dphi),
        "bonus": float(status.at_target and status.grasped) * w.c1 * w.c2 ** min(n_success, w.n_cap),
        "accel": -w.w4 * float(np.sum(np.square(ddq))),
    }
    return float(sum(terms.values())), terms
