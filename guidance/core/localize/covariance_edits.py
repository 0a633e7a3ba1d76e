"""The filter's covariance edits outside predict and update (pure: arrays in, new arrays out).

What the estimator's own methods write into its filter when the car's knowledge changes other
than by a measurement: the starting and prior covariances, a pose put in the car-model state,
the heading forgotten (no compass yet) or taken from the first compass reading, the position
widened (a start anywhere, a restart), error states started from known values (a car's learned
parameters), the position restarted where a lost car found a place (the relocalisation), and
the "lost" covariance after a non-finite result. Dead reckoning through a CAN gap is
``guidance.core.odometry_gap.dead_reckon``. The estimator is the only caller: it alone writes
what these return into its filter.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from guidance.core import model
from guidance.core.localize.estimator_config import EstimatorConfig


def prior(cfg: EstimatorConfig) -> np.ndarray:
    """The starting covariance of every state (pose block: the initial sigmas)."""
    sp = cfg.initial_position_sigma_m
    sh = math.radians(cfg.initial_heading_sigma_deg)
    diag = [sp * sp, sp * sp, sh * sh]
    if cfg.n_state > model.N_STATE:
        sb = math.radians(cfg.compass_bias_sigma_deg)
        diag += [cfg.scale_sigma**2, cfg.diff_sigma**2, sb * sb, cfg.turn_scale_sigma**2]
    if cfg.gyro is not None:
        diag += [cfg.gyro.bias_var, cfg.gyro.scale_sigma**2]
    return np.diag(diag)


def of_pose(cfg: EstimatorConfig, covariance: np.ndarray | None) -> np.ndarray:
    """The filter's covariance for a pose put in place: ``covariance`` whole, or a pose's
    (3 x 3) with the error states at their priors; None: the initial sigmas."""
    if covariance is None:
        sp = cfg.initial_position_sigma_m
        sh = math.radians(cfg.initial_heading_sigma_deg)
        covariance = np.diag([sp * sp, sp * sp, sh * sh])
    cov = np.array(covariance, dtype=float)
    n = cfg.n_state
    if cov.shape == (n, n):
        return cov
    P = prior(cfg)  # a pose covariance for the car model: the error states keep their priors
    P[:3, :3] = cov.reshape(3, 3)
    return P


def heading_forgotten(P: np.ndarray) -> np.ndarray:
    """No heading known (the first compass reading gives it): its variance a full turn's,
    uncorrelated with the position."""
    P = np.array(P, dtype=float)
    P[2, 2] = math.pi**2
    P[0, 2] = P[2, 0] = P[1, 2] = P[2, 1] = 0.0
    return P


def position_widened(P: np.ndarray, spread_m: float) -> np.ndarray:
    """The position widened by ``spread_m`` (a 2-sigma distance, both axes)."""
    P = np.array(P, dtype=float)
    var = (spread_m / 2.0) ** 2
    P[0, 0] += var
    P[1, 1] += var
    return P


def heading_from_compass(
    x: np.ndarray, P: np.ndarray, theta_rad: float, compass_var: float
) -> tuple[float, np.ndarray]:
    """The heading and covariance when a compass reading gives the heading (none known yet).

    The compass measures heading + bias, so the heading inherits the bias uncertainty and
    is anti-correlated with the bias state."""
    P = np.array(P, dtype=float)
    if x.shape[0] > model.N_STATE:
        b = model.STATE_BIAS
        theta = model.wrap_angle(theta_rad - x[b])
        P[2, :] = 0.0
        P[:, 2] = 0.0
        P[2, 2] = compass_var + P[b, b]
        P[2, b] = P[b, 2] = -P[b, b]
    else:
        theta = theta_rad
        P[2, 2] = compass_var
    return theta, P


def adopted(
    x: np.ndarray, P: np.ndarray, states: Sequence[tuple[int, float, float]]
) -> tuple[np.ndarray, np.ndarray]:
    """Error states started from known values: each (index, mean, sigma) set, its
    correlations with the other states cleared."""
    x, P = np.array(x, dtype=float), np.array(P, dtype=float)
    for i, value, sigma in states:
        x[i] = value
        P[i, :] = 0.0
        P[:, i] = 0.0
        P[i, i] = sigma * sigma
    return x, P


def relocalised(
    x: np.ndarray, P: np.ndarray, x_m: float, y_m: float, var: float
) -> tuple[np.ndarray, np.ndarray]:
    """A place found by a whole-database search while lost: the position restarts there with
    the fix's variance (its sigma: the sighting range plus the place's, so the 2-sigma ellipse
    holds every point it is seen from), uncorrelated with the rest; the heading and the error
    states keep theirs (an update would be gated out, or pulled by the lost mean). The math is
    ``model.reset_position``'s, shared with the study engine."""
    x, P = np.array(x, dtype=float), np.array(P, dtype=float)
    model.reset_position(x, P, x_m, y_m, var)
    return x, P


def lost(cfg: EstimatorConfig, P_before: np.ndarray) -> np.ndarray:
    """After a non-finite result: a "lost" covariance (position ``lost_major_axis_m`` 1-sigma,
    the heading a full turn), never tighter than the last finite one."""
    big = cfg.lost_major_axis_m**2
    cov = prior(cfg)
    cov[0, 0], cov[1, 1], cov[2, 2] = big, big, math.pi**2
    if np.all(np.isfinite(P_before)):
        cov = np.maximum(cov, P_before)
    return cov
