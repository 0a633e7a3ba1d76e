"""Odometry gaps (pure math): what the car may have driven while the wheel speeds were silent.

A CAN dropout leaves the heading known (the compass goes on) and the speed known up to the
gap; only the distance along the road is not. So the estimate is dead-reckoned at the last
speed along the estimated heading, and widened *along* the road by what the car could have
gained or lost meanwhile (``GAP_ACCEL_MPS2``: 1/2 a t^2 as the 2-sigma bound), and *across*
it only through the heading's own uncertainty (the Jacobian of the move), not as a circle.
"""

from __future__ import annotations

import math

import numpy as np

GAP_ACCEL_MPS2 = 3.0
"""The most a car gains or loses in speed per second in town (0-100 km/h in 9 s; braking
harder than this ends within v/a seconds, after which the distance lost, v t - v^2 / 2a, stays
below 1/2 a t^2): bounds what it may have driven beyond or short of its last speed."""

GAP_YAW_RATE_RADPS = 0.6
"""How fast a town car's heading can change: a 7 m radius corner at 15 km/h (v / r). Through
a gap the heading is a random walk with this rate per root second, so the compass, the only
heading input left, is not gated out when the car turns a corner meanwhile."""


def along_sigma_m(gap_s: float) -> float:
    """1-sigma along-road uncertainty after ``gap_s`` of dead reckoning (2-sigma = a t^2 / 2)."""
    return 0.25 * GAP_ACCEL_MPS2 * gap_s * gap_s


def placeable_s(tol_m: float) -> float:
    """The longest dead reckoning whose along-road 2-sigma bound (``a t^2 / 2``) stays within
    ``tol_m``: beyond it a place ahead on the road can no longer be told from the next one."""
    return math.sqrt(2.0 * tol_m / GAP_ACCEL_MPS2)


def dead_reckon(
    x: np.ndarray, P: np.ndarray, speed_mps: float, gap_from_s: float, gap_to_s: float
) -> tuple[np.ndarray, np.ndarray]:
    """The state moved from ``gap_from_s`` to ``gap_to_s`` seconds into a gap, at ``speed_mps``
    along its heading: (x, P) new arrays. The covariance is carried by the move's Jacobian (the
    heading's uncertainty becomes across-road spread) plus the along-road growth of
    ``along_sigma_m``."""
    dt = gap_to_s - gap_from_s
    x2 = np.array(x, dtype=float)
    P2 = np.array(P, dtype=float)
    if not (dt > 0 and math.isfinite(dt) and math.isfinite(speed_mps)):
        return x2, P2
    d = abs(speed_mps) * dt
    c, s = math.cos(float(x2[2])), math.sin(float(x2[2]))
    x2[0] += d * c
    x2[1] += d * s
    F = np.eye(P2.shape[0])
    F[0, 2] = -d * s
    F[1, 2] = d * c
    P2 = F @ P2 @ F.T
    grow = along_sigma_m(gap_to_s) ** 2 - along_sigma_m(max(0.0, gap_from_s)) ** 2
    u = np.array([c, s])
    P2[:2, :2] += grow * np.outer(u, u)
    P2[2, 2] += GAP_YAW_RATE_RADPS**2 * dt
    return x2, 0.5 * (P2 + P2.T)
