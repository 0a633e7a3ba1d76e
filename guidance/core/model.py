"""The estimator's math (SPEC section 2) as plain functions on floats and arrays.

This module is the single definition of the motion model, its Jacobians, the
process noise, the measurement models, the Kalman update and the uncertainty
ellipse. The live estimator (``guidance.estimator``) and the Monte Carlo study
engine (``hal_sim.engine``) both call these functions; they are compiled with
numba so the study engine can run them inside one compiled trial loop.

Frames and units (SPEC section 7): x east, y north, metres; heading ``theta``
counter-clockwise from east, radians. Compass degrees appear only in
``compass_to_heading`` / ``heading_to_compass``, which the drivers call at the
input edge.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from guidance.core import angles

# Chi-square quantiles with 2 degrees of freedom: P(d^2 <= k) = 1 - exp(-k / 2).
# A "2-sigma ellipse" (d^2 = 4) holds 1 - e^-2 = 86.47% of the mass, not 95%.
CHI2_2D_2SIGMA = 4.0
CHI2_2D_P95 = 5.991464547107979
CHI2_2D_P99 = 9.21034037197618
# One degree of freedom (heading residual): P(d^2 <= 6.635) = 0.99.
CHI2_1D_P99 = 6.634896601021214
CHI2_1D_P999 = 10.827566170662733

# Magnetic interference detector (SPEC 2 extension, docs/reliability.md): an
# exponentially weighted mean of the compass normalised innovation squared
# (NIS = y^2 / S, expected value 1 when the compass behaves as modelled). Each
# reading's NIS is clipped so one outlier cannot trip it alone.
NIS_CLIP = 16.0


@njit(cache=True, error_model="numpy")
def interference_update(
    level: float, active: bool, nis: float, alpha: float, on: float, off: float
) -> tuple[float, bool]:
    """Update the NIS level with one compass reading; hysteresis between ``on`` and ``off``."""
    level = (1.0 - alpha) * level + alpha * min(nis, NIS_CLIP)
    if active:
        return level, level > off
    return level, level > on


STATE_X = 0
STATE_Y = 1
STATE_THETA = 2
N_STATE = 3
"""The paper's state: position and heading."""
STATE_SCALE = 3
"""Common wheel-speed scale error, a fraction: true distance = measured x (1 + k)."""
STATE_DIFF = 4
"""Right-minus-left wheel scale difference, a fraction (a tyre radius difference)."""
STATE_BIAS = 5
"""Compass bias in the filter frame, rad: the compass measures theta + bias."""
STATE_TURN = 6
"""Turn scale error, a fraction: the true heading change is the wheels' x (1 + kt) (the
effective track differs from the configured one; a gyro's sensitivity error)."""
N_STATE_CAR = 7
"""The car model's state: the paper's plus the persistent errors as states (docs/estimation.md)."""


wrap_angle = njit(cache=True, error_model="numpy")(angles.wrap_angle)
"""Wrap an angle to (-pi, pi] (``guidance.core.angles``, compiled)."""


@njit(cache=True, error_model="numpy")
def odometry_increment(d_left_m: float, d_right_m: float, track_m: float) -> tuple[float, float]:
    """Distance and heading change from rear-wheel distance increments (SPEC 2).

    Distance is the mean of the two wheels; the heading change is the
    differential distance over the track width (counter-clockwise positive).
    """
    return 0.5 * (d_left_m + d_right_m), (d_right_m - d_left_m) / track_m


@njit(cache=True, error_model="numpy")
def motion_predict(
    x: float, y: float, theta: float, d: float, dtheta: float
) -> tuple[float, float, float]:
    """Move the rear-axle centre by distance ``d`` while turning by ``dtheta``.

    Second-order (mid-point) odometry model: the chord is travelled at the mean
    heading of the interval, which is exact for a circular arc up to the chord
    length factor sin(dtheta/2)/(dtheta/2) (below 1e-4 relative for the
    heading changes of one odometry interval).
    """
    mid = theta + 0.5 * dtheta
    return x + d * math.cos(mid), y + d * math.sin(mid), wrap_angle(theta + dtheta)


@njit(cache=True, error_model="numpy")
def motion_jacobians(
    theta: float, d_left_m: float, d_right_m: float, track_m: float, F: np.ndarray, G: np.ndarray
) -> None:
    """Fill the state Jacobian F (3x3) and the input Jacobian G (3x2, w.r.t. wheel distances).

    Outputs are caller-provided arrays so the compiled study loop allocates nothing per step.
    """
    d = 0.5 * (d_left_m + d_right_m)
    dtheta = (d_right_m - d_left_m) / track_m
    mid = theta + 0.5 * dtheta
    c = math.cos(mid)
    s = math.sin(mid)
    F[0, 0] = 1.0
    F[0, 1] = 0.0
    F[0, 2] = -d * s
    F[1, 0] = 0.0
    F[1, 1] = 1.0
    F[1, 2] = d * c
    F[2, 0] = 0.0
    F[2, 1] = 0.0
    F[2, 2] = 1.0
    # d(d)/d(dl) = 1/2, d(dtheta)/d(dl) = -1/b, d(mid)/d(dl) = -1/(2b); symmetric for dr.
    G[0, 0] = 0.5 * c + d * s / (2.0 * track_m)
    G[0, 1] = 0.5 * c - d * s / (2.0 * track_m)
    G[1, 0] = 0.5 * s - d * c / (2.0 * track_m)
    G[1, 1] = 0.5 * s + d * c / (2.0 * track_m)
    G[2, 0] = -1.0 / track_m
    G[2, 1] = 1.0 / track_m


@njit(cache=True, error_model="numpy")
def wheel_noise_var(d_wheel_m: float, quantum_m: float, slip_frac: float) -> float:
    """Variance of one wheel's distance increment (SPEC 2).

    Quantisation of +-1/2 count is uniform, variance quantum^2 / 12; slip has a
    standard deviation proportional to the distance travelled.
    """
    slip = slip_frac * d_wheel_m
    return quantum_m * quantum_m / 12.0 + slip * slip


@njit(cache=True, error_model="numpy")
def corrected_wheels(
    d_left_m: float, d_right_m: float, scale: float, diff: float
) -> tuple[float, float]:
    """Wheel increments corrected by the scale states: x (1 + k -/+ diff/2) left/right."""
    return d_left_m * (1.0 + scale - 0.5 * diff), d_right_m * (1.0 + scale + 0.5 * diff)


@njit(cache=True, error_model="numpy")
def effective_track(track_m: float, turn: float) -> float:
    """The track that turns the heading by (1 + kt) of the wheels' difference over ``track_m``."""
    return track_m / (1.0 + turn)


@njit(cache=True, error_model="numpy")
def turn_jacobian(d_left_m: float, d_right_m: float, track_m: float, F: np.ndarray) -> None:
    """Fill F[0:3, STATE_TURN] for corrected wheel increments, from the pose Jacobian already
    in F[0:3, 0:3] (``motion_jacobians``): with q = (dr - dl) / track the uncorrected heading
    change, the turn is (1 + kt) q, so d(turn)/d(kt) = q, and the chord's mid-point heading,
    which the position follows as it follows the heading (F[i, 2]), moves by q / 2."""
    q = (d_right_m - d_left_m) / track_m
    F[0, STATE_TURN] = F[0, STATE_THETA] * 0.5 * q
    F[1, STATE_TURN] = F[1, STATE_THETA] * 0.5 * q
    F[2, STATE_TURN] = q


@njit(cache=True, error_model="numpy")
def scale_jacobian(G: np.ndarray, d_left_m: float, d_right_m: float, F: np.ndarray) -> None:
    """Fill F[0:3, 3:5]: how the pose moves with the scale states, through the input Jacobian.

    d(dl_c)/dk = dl, d(dr_c)/dk = dr; d(dl_c)/d(diff) = -dl/2, d(dr_c)/d(diff) = dr/2.
    """
    for i in range(3):
        F[i, STATE_SCALE] = G[i, 0] * d_left_m + G[i, 1] * d_right_m
        F[i, STATE_DIFF] = 0.5 * (G[i, 1] * d_right_m - G[i, 0] * d_left_m)


@njit(cache=True, error_model="numpy")
def wheel_walk_var(d_wheel_m: float, var_per_m: float) -> float:
    """Variance of one wheel's increment in the car model: a random walk in distance.

    Independent of how the distance was cut into increments (the CAN message rate), unlike
    the paper's slip term (slip x d)^2 per increment."""
    return var_per_m * abs(d_wheel_m)


def camber_heading_var(d_m: float, sigma: float, length_m: float, track_m: float) -> float:
    """Heading variance over ``d_m`` from the part of the left/right difference that changes
    from street to street (road camber, each side's tyre temperature): a Gauss-Markov process
    of stationary 1-sigma ``sigma`` and correlation length ``length_m``. Its integral over the
    distance, the heading it turns, is a random walk of ``2 sigma^2 L / track^2`` per metre:
    exact for drives much longer than ``L``, wider than the process for shorter ones. Unlike a
    random walk of the difference itself, it does not let the difference grow without bound
    (docs/estimation.md)."""
    return 2.0 * sigma * sigma * length_m * abs(d_m) / (track_m * track_m)


@njit(cache=True, error_model="numpy")
def process_noise(G: np.ndarray, var_left: float, var_right: float, Q: np.ndarray) -> None:
    """Fill Q = G diag(var_l, var_r) G^T: wheel noise propagated through the input Jacobian."""
    for i in range(3):
        for j in range(3):
            Q[i, j] = G[i, 0] * var_left * G[j, 0] + G[i, 1] * var_right * G[j, 1]


@njit(cache=True, error_model="numpy")
def predict_covariance(P: np.ndarray, F: np.ndarray, Q: np.ndarray, out: np.ndarray) -> None:
    """Fill out = F P F^T + Q (``out`` must not alias ``P``)."""
    for i in range(3):
        for j in range(3):
            acc = Q[i, j]
            for k in range(3):
                fik = F[i, k]
                if fik == 0.0:
                    continue
                for m in range(3):
                    acc += fik * P[k, m] * F[j, m]
            out[i, j] = acc


@njit(cache=True, error_model="numpy")
def heading_innovation(
    x: np.ndarray, P: np.ndarray, z_theta: float, var: float
) -> tuple[float, float]:
    """Compass measurement model h(x) = theta (+ bias in the car model): residual y and S."""
    if x.shape[0] > STATE_BIAS:
        b = STATE_BIAS
        return (
            wrap_angle(z_theta - x[2] - x[b]),
            P[2, 2] + 2.0 * P[2, b] + P[b, b] + var,
        )
    return wrap_angle(z_theta - x[2]), P[2, 2] + var


@njit(cache=True, error_model="numpy")
def heading_update(x: np.ndarray, P: np.ndarray, y: float, S: float, var: float) -> None:
    """Kalman update for h(x) = theta, in place, Joseph form (as filterpy computes it)."""
    k0 = P[0, 2] / S
    k1 = P[1, 2] / S
    k2 = P[2, 2] / S
    p02, p12, p22 = P[0, 2], P[1, 2], P[2, 2]
    x[0] += k0 * y
    x[1] += k1 * y
    x[2] = wrap_angle(x[2] + k2 * y)
    K = (k0, k1, k2)
    pc = (p02, p12, p22)
    for i in range(3):
        for j in range(i, 3):
            v = P[i, j] - K[i] * pc[j] - K[j] * (pc[i] - K[i] * p22) + K[i] * K[j] * var
            P[i, j] = v
            P[j, i] = v


@njit(cache=True, error_model="numpy")
def position_innovation(
    x: np.ndarray, P: np.ndarray, zx: float, zy: float, var: float
) -> tuple[float, float, float, float, float]:
    """Landmark measurement model h(x) = (x, y): residual (y0, y1) and S = (s00, s01, s11)."""
    return zx - x[0], zy - x[1], P[0, 0] + var, P[0, 1], P[1, 1] + var


@njit(cache=True, error_model="numpy")
def mahalanobis_sq_2d(y0: float, y1: float, s00: float, s01: float, s11: float) -> float:
    """y^T S^-1 y for a 2-vector and a symmetric 2x2 S."""
    det = s00 * s11 - s01 * s01
    return (s11 * y0 * y0 - 2.0 * s01 * y0 * y1 + s00 * y1 * y1) / det


@njit(cache=True, error_model="numpy")
def position_update(
    x: np.ndarray,
    P: np.ndarray,
    y0: float,
    y1: float,
    s00: float,
    s01: float,
    s11: float,
    var: float,
    work: np.ndarray,
) -> None:
    """Kalman update for h(x) = (x, y), in place, Joseph form. ``work``: 3x3 scratch."""
    det = s00 * s11 - s01 * s01
    i00, i01, i11 = s11 / det, -s01 / det, s00 / det
    for i in range(3):
        for j in range(3):
            work[i, j] = P[i, j]
    # K = P H^T S^-1, with P H^T the first two columns of P.
    ka = (
        work[0, 0] * i00 + work[0, 1] * i01,
        work[1, 0] * i00 + work[1, 1] * i01,
        work[2, 0] * i00 + work[2, 1] * i01,
    )
    kb = (
        work[0, 0] * i01 + work[0, 1] * i11,
        work[1, 0] * i01 + work[1, 1] * i11,
        work[2, 0] * i01 + work[2, 1] * i11,
    )
    x[0] += ka[0] * y0 + kb[0] * y1
    x[1] += ka[1] * y0 + kb[1] * y1
    x[2] = wrap_angle(x[2] + ka[2] * y0 + kb[2] * y1)
    # (I - K H) P (I - K H)^T + K R K^T with H = [I2 0] and R = var I2:
    # AP[i, j] = P[i, j] - ka[i] P[0, j] - kb[i] P[1, j]; out = AP (I - K H)^T + var K K^T.
    for i in range(3):
        ap0 = work[i, 0] - ka[i] * work[0, 0] - kb[i] * work[1, 0]
        ap1 = work[i, 1] - ka[i] * work[0, 1] - kb[i] * work[1, 1]
        for j in range(i, 3):
            apj = work[i, j] - ka[i] * work[0, j] - kb[i] * work[1, j]
            v = apj - ap0 * ka[j] - ap1 * kb[j] + var * (ka[i] * ka[j] + kb[i] * kb[j])
            P[i, j] = v
            P[j, i] = v


@njit(cache=True, error_model="numpy")
def heading_residual(z_theta: float, theta: float) -> float:
    """Compass residual, wrapped to (-pi, pi]."""
    return wrap_angle(z_theta - theta)


@njit(cache=True, error_model="numpy")
def compass_to_heading(compass_deg: float, declination_deg: float) -> float:
    """Magnetic compass degrees (clockwise from north) to filter heading (rad, CCW from east).

    True bearing = magnetic + declination (east positive); the filter heading is
    90 degrees minus the true bearing.
    """
    true_deg = compass_deg + declination_deg
    return wrap_angle(math.radians(90.0 - true_deg))


@njit(cache=True, error_model="numpy")
def reset_position(x: np.ndarray, P: np.ndarray, zx: float, zy: float, var: float) -> None:
    """A relocalisation in place (the car's ``PoseEstimator`` and the study engine): the
    position restarts at (zx, zy) with ``var`` on each axis, uncorrelated with every other
    state; the heading and the car's error states keep their means and variances (the
    engine's kept cos and sin of the heading too)."""
    x[0], x[1] = zx, zy
    for j in range(P.shape[0]):
        P[0, j] = P[j, 0] = P[1, j] = P[j, 1] = 0.0
    P[0, 0] = P[1, 1] = var


heading_to_compass = njit(cache=True, error_model="numpy")(angles.heading_to_compass)
"""Filter heading (rad) to magnetic compass degrees in [0, 360) (``guidance.core.angles``,
compiled)."""


@njit(cache=True, error_model="numpy")
def two_sigma_deg_to_var(two_sigma_deg: float) -> float:
    """Variance (rad^2) of a sensor specified by its 2-sigma error in degrees."""
    s = math.radians(two_sigma_deg) / 2.0
    return s * s


@njit(cache=True, error_model="numpy")
def ellipse_axes(pxx: float, pxy: float, pyy: float, k2: float) -> tuple[float, float, float]:
    """Semi-axes (major, minor) and orientation (rad from x) of {d^2 <= k2}.

    For the 2-sigma ellipse use ``k2 = CHI2_2D_2SIGMA`` (=4): the semi-axes are
    2 * sqrt(eigenvalues of the x-y covariance).
    """
    l1, l2 = eigenvalues_2x2(pxx, pxy, pyy)
    angle = 0.5 * math.atan2(2.0 * pxy, pxx - pyy)
    return math.sqrt(k2 * l1), math.sqrt(k2 * l2), angle


@njit(cache=True, error_model="numpy")
def eigenvalues_2x2(pxx: float, pxy: float, pyy: float) -> tuple[float, float]:
    """Eigenvalues (largest first, clipped at 0) of a symmetric 2x2 covariance."""
    tr = 0.5 * (pxx + pyy)
    diff = 0.5 * (pxx - pyy)
    rad = math.sqrt(diff * diff + pxy * pxy)
    return max(tr + rad, 0.0), max(tr - rad, 0.0)


@njit(cache=True, error_model="numpy")
def major_axis_m(P: np.ndarray) -> float:
    """Full length of the major axis of the 2-sigma position ellipse (SPEC 2)."""
    l1, _ = eigenvalues_2x2(P[0, 0], P[0, 1], P[1, 1])
    return 2.0 * math.sqrt(CHI2_2D_2SIGMA * l1)
