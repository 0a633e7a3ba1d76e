"""The study engine's estimator steps: the EKF of ``guidance.core.model`` as compiled steps.

Predict from wheel increments, the gated compass update behind the interference
detector, and the gated landmark update (Joseph form), each in place on (x, P).
They are what the app's filterpy ``PoseEstimator`` computes; ``filter_sequence``
runs them over fixed inputs so that tests and ``benchmarks/study_speed.py`` can
compare the two step by step. ``hal_sim.engine`` runs them inside a trial.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from guidance.core import model
from hal_sim.params import (
    I_COMPASS_GATE,
    I_COMPASS_SIGMA,
    I_LM_GATE,
    I_LM_SIGMA,
    I_MAG_ALPHA,
    I_MAG_DETECT,
    I_MAG_OFF,
    I_MAG_ON,
    I_MAX_WHEEL_STEP,
    I_QUANTUM,
    I_SLIP,
    I_TRACK,
)


@njit(cache=True, error_model="numpy")
def predict(
    x: np.ndarray,
    P: np.ndarray,
    P_next: np.ndarray,
    F: np.ndarray,
    G: np.ndarray,
    Q: np.ndarray,
    dl: float,
    dr: float,
    track: float,
    quantum: float,
    slip: float,
) -> None:
    """EKF predict from wheel increments (SPEC 2), in place, with the functions filterpy gets."""
    d, dth = model.odometry_increment(dl, dr, track)
    model.motion_jacobians(x[2], dl, dr, track, F, G)
    model.process_noise(
        G, model.wheel_noise_var(dl, quantum, slip), model.wheel_noise_var(dr, quantum, slip), Q
    )
    x[0], x[1], x[2] = model.motion_predict(x[0], x[1], x[2], d, dth)
    model.predict_covariance(P, F, Q, P_next)
    P[:, :] = P_next


COMPASS_ACCEPTED = 0
COMPASS_GATED = 1
COMPASS_INTERFERENCE = 2


@njit(cache=True, error_model="numpy")
def compass_update(
    x: np.ndarray, P: np.ndarray, z: float, var: float, p: np.ndarray, det: np.ndarray
) -> int:
    """Compass update in place, after the interference detector and the gate.

    ``det`` holds the detector's (level, active) between calls. While it is
    active readings are rejected: the heading is left to odometry and its
    variance grows honestly, instead of being dragged by a biased field.
    Returns COMPASS_ACCEPTED, COMPASS_GATED or COMPASS_INTERFERENCE.
    """
    y, S = model.heading_innovation(x, P, z, var)
    nis = y * y / S
    if p[I_MAG_DETECT] > 0.0:
        level, active = model.interference_update(
            det[0], det[1] > 0.0, nis, p[I_MAG_ALPHA], p[I_MAG_ON], p[I_MAG_OFF]
        )
        det[0] = level
        det[1] = 1.0 if active else 0.0
        if active:
            return COMPASS_INTERFERENCE
    if nis > p[I_COMPASS_GATE]:
        return COMPASS_GATED
    model.heading_update(x, P, y, S, var)
    return COMPASS_ACCEPTED


@njit(cache=True, error_model="numpy")
def landmark_update_xy(
    x: np.ndarray,
    P: np.ndarray,
    zx: float,
    zy: float,
    var: float,
    gate: float,
    work: np.ndarray,
) -> bool:
    """Gated landmark position update in place; False when the gate rejects it."""
    y0, y1, s00, s01, s11 = model.position_innovation(x, P, zx, zy, var)
    if model.mahalanobis_sq_2d(y0, y1, s00, s01, s11) > gate:
        return False
    model.position_update(x, P, y0, y1, s00, s01, s11, var, work)
    return True


@njit(cache=True, error_model="numpy")
def filter_sequence(
    x0: np.ndarray, P0: np.ndarray, inputs: np.ndarray, p: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Run the study engine's filter over fixed inputs; returns every step's (x, P).

    ``inputs`` rows are (dl, dr, compass or NaN, landmark x or NaN, landmark y).
    Used to check the engine against the app's filterpy estimator.
    """
    n = inputs.shape[0]
    xs = np.empty((n, 3))
    Ps = np.empty((n, 3, 3))
    x = x0.copy()
    P = P0.copy()
    P_next = np.empty((3, 3))
    F = np.empty((3, 3))
    G = np.empty((3, 2))
    Q = np.empty((3, 3))
    work = np.empty((3, 3))
    det = np.array([1.0, 0.0])
    for i in range(n):
        dl, dr = inputs[i, 0], inputs[i, 1]
        if abs(dl) <= p[I_MAX_WHEEL_STEP] and abs(dr) <= p[I_MAX_WHEEL_STEP]:
            predict(x, P, P_next, F, G, Q, dl, dr, p[I_TRACK], p[I_QUANTUM], p[I_SLIP])
        if p[I_COMPASS_SIGMA] > 0.0 and not math.isnan(inputs[i, 2]):
            compass_update(x, P, inputs[i, 2], p[I_COMPASS_SIGMA] ** 2, p, det)
        if not math.isnan(inputs[i, 3]):
            landmark_update_xy(
                x, P, inputs[i, 3], inputs[i, 4], p[I_LM_SIGMA] ** 2, p[I_LM_GATE], work
            )
        xs[i] = x
        Ps[i] = P
    return xs, Ps
