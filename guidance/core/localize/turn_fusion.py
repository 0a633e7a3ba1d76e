"""Wheels and gyro together (``[vehicle] yaw_source = "both"``, issue 38): each a measurement
of the same turn, weighed by the filter.

The choice: the **gyro propagates** the heading (as with ``yaw_source = "gyro"``: its white
noise per step is two orders of magnitude below the wheels' over the same step, 0.002 deg
against 0.05 deg at 50 Hz and 10 m/s, and it turns the heading while the wheels slip or read
below their lowest speed) and **the wheels' turn of the same step is a measurement** of it.
The alternative, the gyro as a measurement on a wheel-propagated turn rate, would need a
turn-rate state with a process model for the driver's steering, a prior nobody can write down
for a car; here nothing is added but the step's own noise.

The true turn ``delta`` of one step is, by the gyro, ``G(x) + e`` (``gyro.gyro_turn``: its
bias and scale states, ``e`` the gyro's white noise over the step, variance ``angle_var``).
The wheels read their raw difference over the track, ``z = h(x, delta) + w``
(``wheel_turn_model``: the scale, left/right and turn-scale states; ``w`` the wheels' walk
and the street-to-street camber, exactly the heading noise the wheel model adds): a
measurement of the state augmented by ``e`` for the step, whose Jacobian is taken at the
gyro's turn (the wheels' reading is the measurement, never the point of linearisation). The
update (Joseph form) learns the bias against the left/right difference (one turns the heading
with time, the other with distance, so stops and changes of speed tell them apart), the gyro's
scale against the effective track (visible in every turn; their common part needs a compass
or landmarks), and moves ``e``; the heading then turns by ``G(x+) + e+`` and ``e``'s posterior
variance and its correlation with the state go into the process noise
(``Q += F c g^T + g c^T F^T + var_e g g^T``), so that nothing is counted twice.

A step whose d^2 exceeds ``GyroConfig.gate_chi2`` (1 dof, P = 0.999) is not a turn the two
agree on (a wheel spinning or locked, a kerb): the gyro alone turns it (counted,
``wheel_turn_gate``).
"""

from __future__ import annotations

import math

import numpy as np

from guidance.core import model
from guidance.core.localize.gyro import (
    STATE_GYRO_BIAS,
    STATE_GYRO_SCALE,
    GyroConfig,
    gyro_step,
    gyro_turn,
)

USED = "wheel_turn"
"""Counted (accepted) for each step whose wheel turn updated the filter."""
GATED = "wheel_turn_gate"
"""Counted (rejected) for each step whose wheel turn was refused by the gate."""


def wheel_turn_model(
    x: np.ndarray, delta: float, d_raw_m: float, track_m: float
) -> tuple[float, np.ndarray]:
    """The raw wheel turn ``(raw right - raw left) / track`` the wheels read for a true turn
    ``delta`` and a raw mean distance ``d_raw_m``, and its Jacobian over the state and
    ``delta`` (last). From the car model's wheels (``model.corrected_wheels``,
    ``model.effective_track``): ``delta = ((1 + k) D + kd S / 2)(1 + kt) / track`` with ``D``
    the raw difference and ``S = 2 d_raw`` the raw sum, so
    ``D / track = (delta / (1 + kt) - kd d_raw / track) / (1 + k)``. The Jacobian is taken at
    the gyro's turn, never at the wheels' own reading: a scale's Jacobian that carried the
    reading's noise would correlate with the innovation and walk the scales off (errors in
    variables)."""
    n = x.shape[0]
    k, kd, kt = float(x[model.STATE_SCALE]), float(x[model.STATE_DIFF]), float(x[model.STATE_TURN])
    a = 1.0 / ((1.0 + kt) * (1.0 + k))
    h = (delta / (1.0 + kt) - kd * d_raw_m / track_m) / (1.0 + k)
    J = np.zeros(n + 1)
    J[model.STATE_SCALE] = -h / (1.0 + k)
    J[model.STATE_DIFF] = -d_raw_m / (track_m * (1.0 + k))
    J[model.STATE_TURN] = -delta * a / (1.0 + kt)
    J[n] = a  # d h / d delta
    return h, J


def fuse_turn(
    x: np.ndarray,
    P: np.ndarray,
    raw: tuple[float, float, float],
    var_wheel_turn: float,
    turned: tuple[float, float, float],
    gate_chi2: float,
) -> tuple[float, float, np.ndarray, float] | None:
    """Update ``x`` and ``P`` in place with one step's wheel turn (module doc; ``raw``: the
    raw left and right increments and the track). Returns the gyro noise's posterior mean and
    variance, its covariance with the state and the d^2; or None (nothing changed) when the
    gate refuses the step."""
    raw_l, raw_r, track = raw
    angle, span, angle_var = turned
    n = x.shape[0]
    bias, scale = float(x[STATE_GYRO_BIAS]), float(x[STATE_GYRO_SCALE])
    delta = gyro_turn(angle, span, bias, scale)  # the turn by the gyro, its noise e = 0
    h, J = wheel_turn_model(x, delta, 0.5 * (raw_l + raw_r), track)
    H = J.copy()  # delta = G(x) + e: through the gyro's bias and scale, and e itself
    H[STATE_GYRO_BIAS] += J[n] * -span * (1.0 + scale)
    H[STATE_GYRO_SCALE] += J[n] * (angle - bias * span)
    y = (raw_r - raw_l) / track - h
    Pa = np.zeros((n + 1, n + 1))
    Pa[:n, :n] = P
    Pa[n, n] = angle_var * (1.0 + scale) ** 2
    PH = Pa @ H
    S = float(H @ PH) + var_wheel_turn
    d2 = y * y / S
    if not d2 <= gate_chi2:  # NaN too
        return None
    K = PH / S
    xa = np.zeros(n + 1)
    xa[:n] = x
    xa += K * y
    A = np.eye(n + 1) - np.outer(K, H)
    Pa = A @ Pa @ A.T + var_wheel_turn * np.outer(K, K)
    x[:] = xa[:n]
    x[model.STATE_THETA] = model.wrap_angle(float(x[model.STATE_THETA]))
    P[:, :] = Pa[:n, :n]
    return float(xa[n]), float(Pa[n, n]), Pa[:n, n].copy(), d2


def gyro_turn_step(
    cfg: GyroConfig,
    x: np.ndarray,
    P: np.ndarray,
    wheels: tuple[float, float],
    raw: tuple[float, float, float],
    turned: tuple[float, float, float],
    var_wheels_m2: float,
) -> tuple[float, np.ndarray, np.ndarray, str | None]:
    """An odometry step turned by the gyro: with ``cfg.with_wheels`` its wheel turn first
    measures the turn (``fuse_turn``; ``x`` and ``P`` updated in place), then the heading
    change, state Jacobian and process noise (``gyro.gyro_step``). ``wheels``: the configured
    track and the variance of the wheels' turn over the step (their walk and the camber, as
    the wheel model adds it); ``raw``: the raw left and right increments and the corrected
    distance. Also returns what to count (``USED``, ``GATED``) or None."""
    raw_l, raw_r, d = raw
    track, var_wheel_turn = wheels
    if not cfg.with_wheels or d == 0.0:
        return (*gyro_step(x, raw_l, raw_r, d, turned, var_wheels_m2), None)
    fused = fuse_turn(x, P, (raw_l, raw_r, track), var_wheel_turn, turned, cfg.gate_chi2)
    if fused is None:
        return (*gyro_step(x, raw_l, raw_r, d, turned, var_wheels_m2), GATED)
    e, var_e, c, _ = fused
    angle, span, _ = turned
    scale = float(x[STATE_GYRO_SCALE])
    dth, F, Q = gyro_step(x, raw_l, raw_r, d, (angle + e / (1.0 + scale), span, 0.0),
                          var_wheels_m2)  # fmt: skip
    mid = float(x[model.STATE_THETA]) + 0.5 * dth
    g = np.zeros(x.shape[0])
    g[0], g[1], g[2] = -0.5 * d * math.sin(mid), 0.5 * d * math.cos(mid), 1.0
    Fc = F @ c
    Q += np.outer(Fc, g) + np.outer(g, Fc) + var_e * np.outer(g, g)
    return dth, F, Q, USED
