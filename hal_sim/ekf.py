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
from hal_sim import world
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

N_STATE = 5
"""The engine's estimate vector: the filter's (x, y, theta), then cos theta and sin theta,
kept by ``predict`` and ``compass_update`` and set afresh by ``sync_heading`` (after a
landmark update, and at each decision in ``hal_sim.engine``)."""


@njit(cache=True, error_model="numpy")
def state(x: float, y: float, theta: float) -> np.ndarray:
    """The estimate vector (``N_STATE``) at (x, y, theta)."""
    return np.array([x, y, theta, math.cos(theta), math.sin(theta)])


@njit(cache=True, error_model="numpy", inline="always")
def sync_heading(x: np.ndarray) -> None:
    """cos and sin of the heading afresh (after an update the turns do not follow)."""
    x[3] = math.cos(x[2])
    x[4] = math.sin(x[2])


@njit(cache=True, error_model="numpy", inline="always")
def turn(t: float) -> tuple[float, float]:
    """(cos t, sin t) of a small turn from ``world.arc_factors``' series (the library's
    beyond 0.5 rad): the kept cos and sin of the heading are turned by it."""
    sinc, cosc = world.arc_factors(t)
    return 1.0 - t * cosc, t * sinc


@njit(cache=True, error_model="numpy", inline="always")
def half_turn(dth: float) -> tuple[float, float]:
    """``turn(dth / 2)``: twice over, the heading's whole turn of a predict."""
    return turn(0.5 * dth)


@njit(cache=True, error_model="numpy", inline="always", fastmath={"contract", "arcp"})
def predict(
    x: np.ndarray,
    P: np.ndarray,
    dl: float,
    dr: float,
    track: float,
    quantum: float,
    slip: float,
) -> None:
    """EKF predict from wheel increments (SPEC 2), in place: F P F^T + G diag(vl, vr) G^T.

    The functions filterpy gets (``model.motion_jacobians``, ``process_noise``,
    ``predict_covariance``), unrolled for the 3x3 case: F is the identity but for
    F[0, 2] = -d sin(mid) and F[1, 2] = d cos(mid), so F P F^T is six scalar lines on the
    symmetric P, and one sine and cosine serve the Jacobians and the motion. Inlined, so the
    compiled loop passes no arrays (each array passed costs two reference counts).

    ``x`` is (x, y, theta, cos theta, sin theta) (``state``): the mid-point heading's cosine
    and sine are the kept ones turned by dtheta / 2 (``turn``), no library call.
    """
    d, dth = model.odometry_increment(dl, dr, track)
    ch, sh = half_turn(dth)
    c = x[3] * ch - x[4] * sh  # cos(theta + dth / 2)
    s = x[4] * ch + x[3] * sh
    a = -d * s  # F[0, 2]
    b = d * c  # F[1, 2]
    h = 0.5 / track
    g00 = 0.5 * c + d * s * h
    g01 = 0.5 * c - d * s * h
    g10 = 0.5 * s - d * c * h
    g11 = 0.5 * s + d * c * h
    g20 = -1.0 / track
    g21 = 1.0 / track
    vl = model.wheel_noise_var(dl, quantum, slip)
    vr = model.wheel_noise_var(dr, quantum, slip)
    p00, p01, p02 = P[0, 0], P[0, 1], P[0, 2]
    p11, p12, p22 = P[1, 1], P[1, 2], P[2, 2]
    q00 = g00 * vl * g00 + g01 * vr * g01
    q01 = g00 * vl * g10 + g01 * vr * g11
    q02 = g00 * vl * g20 + g01 * vr * g21
    q11 = g10 * vl * g10 + g11 * vr * g11
    q12 = g10 * vl * g20 + g11 * vr * g21
    q22 = g20 * vl * g20 + g21 * vr * g21
    r02 = p02 + a * p22  # row 0 of F P, column 2
    r12 = p12 + b * p22
    n00 = q00 + (p00 + a * p02) + r02 * a
    n01 = q01 + (p01 + a * p12) + r02 * b
    n11 = q11 + (p11 + b * p12) + r12 * b
    P[0, 0] = n00
    P[0, 1] = n01
    P[1, 0] = n01
    P[0, 2] = q02 + r02
    P[2, 0] = q02 + r02
    P[1, 1] = n11
    P[1, 2] = q12 + r12
    P[2, 1] = q12 + r12
    P[2, 2] = q22 + p22
    x[0] = x[0] + d * c
    x[1] = x[1] + d * s
    x[2] = model.wrap_angle(x[2] + dth)
    x[3] = c * ch - s * sh  # cos(theta + dth)
    x[4] = s * ch + c * sh


COMPASS_ACCEPTED = 0
COMPASS_GATED = 1
COMPASS_INTERFERENCE = 2


@njit(cache=True, error_model="numpy")
def _release_here(x: np.ndarray, P: np.ndarray, p: np.ndarray, det: np.ndarray) -> None:
    """Nothing: see the end of ``compass_update``."""


@njit(cache=True, error_model="numpy", fastmath={"contract", "arcp"})
def compass_update(
    x: np.ndarray, P: np.ndarray, z: float, var: float, p: np.ndarray, det: np.ndarray
) -> int:
    """Compass update in place, after the interference detector and the gate.

    ``det`` holds the detector's (level, active) between calls. While it is
    active readings are rejected: the heading is left to odometry and its
    variance grows honestly, instead of being dragged by a biased field.
    Returns COMPASS_ACCEPTED, COMPASS_GATED or COMPASS_INTERFERENCE.

    ``model.heading_innovation`` and ``model.heading_update`` (Joseph form, as filterpy
    computes it) for the three-state filter, unrolled, with one exit: a function with early
    returns that passes its arrays on is charged reference counts at every call.
    """
    y = model.heading_residual(z, x[2])
    S = P[2, 2] + var
    nis = y * y / S
    code = COMPASS_ACCEPTED
    if p[I_MAG_DETECT] > 0.0:
        level, active = model.interference_update(
            det[0], det[1] > 0.0, nis, p[I_MAG_ALPHA], p[I_MAG_ON], p[I_MAG_OFF]
        )
        det[0] = level
        det[1] = 1.0 if active else 0.0
        if active:
            code = COMPASS_INTERFERENCE
    if code == COMPASS_ACCEPTED and nis > p[I_COMPASS_GATE]:
        code = COMPASS_GATED
    if code == COMPASS_ACCEPTED:
        p02, p12, p22 = P[0, 2], P[1, 2], P[2, 2]
        k0, k1, k2 = p02 / S, p12 / S, p22 / S
        x[0] += k0 * y
        x[1] += k1 * y
        x[2] = model.wrap_angle(x[2] + k2 * y)
        ct, st = turn(k2 * y)
        c, s = x[3], x[4]
        x[3] = c * ct - s * st
        x[4] = s * ct + c * st
        # P_ij - K_i pc_j - K_j (pc_i - K_i p22) + K_i K_j var, pc = P[:, 2] (heading_update)
        v00 = P[0, 0] - k0 * p02 - k0 * (p02 - k0 * p22) + k0 * k0 * var
        v01 = P[0, 1] - k0 * p12 - k1 * (p02 - k0 * p22) + k0 * k1 * var
        v02 = P[0, 2] - k0 * p22 - k2 * (p02 - k0 * p22) + k0 * k2 * var
        v11 = P[1, 1] - k1 * p12 - k1 * (p12 - k1 * p22) + k1 * k1 * var
        v12 = P[1, 2] - k1 * p22 - k2 * (p12 - k1 * p22) + k1 * k2 * var
        v22 = P[2, 2] - k2 * p22 - k2 * (p22 - k2 * p22) + k2 * k2 * var
        P[0, 0] = v00
        P[0, 1] = v01
        P[1, 0] = v01
        P[0, 2] = v02
        P[2, 0] = v02
        P[1, 1] = v11
        P[1, 2] = v12
        P[2, 1] = v12
        P[2, 2] = v22
    # Every array used once more in the last block, so numba's reference-count pruning can
    # pair each release with the acquire at entry and drop both (as world.step_core does):
    # otherwise a compass update costs eight atomic operations.
    _release_here(x, P, p, det)
    return code


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
    sync_heading(x)
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
    x = state(x0[0], x0[1], x0[2])
    P = P0.copy()
    work = np.empty((3, 3))
    det = np.array([1.0, 0.0])
    for i in range(n):
        dl, dr = inputs[i, 0], inputs[i, 1]
        if abs(dl) <= p[I_MAX_WHEEL_STEP] and abs(dr) <= p[I_MAX_WHEEL_STEP]:
            predict(x, P, dl, dr, p[I_TRACK], p[I_QUANTUM], p[I_SLIP])
        if p[I_COMPASS_SIGMA] > 0.0 and not math.isnan(inputs[i, 2]):
            compass_update(x, P, inputs[i, 2], p[I_COMPASS_SIGMA] ** 2, p, det)
        if not math.isnan(inputs[i, 3]):
            landmark_update_xy(
                x, P, inputs[i, 3], inputs[i, 4], p[I_LM_SIGMA] ** 2, p[I_LM_GATE], work
            )
        xs[i] = x[:3]
        Ps[i] = P
    return xs, Ps
