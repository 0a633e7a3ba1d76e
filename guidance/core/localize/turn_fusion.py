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
bias and scale states, ``e`` the gyro's white noise over the step, variance ``angle_var``),
and by the wheels ``W(x) + w`` (the corrected wheel difference over the effective track:
the scale, left/right and turn-scale states; ``w`` the wheels' walk and the street-to-street
camber, exactly the heading noise the wheel model adds). So ``0 = G(x) + e - W(x) - w``: a
measurement of zero whose noise is ``w``, on the state augmented by ``e`` for the step. The
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


def turn_row(F_wheels: np.ndarray, angle_rad: float, span_s: float, x: np.ndarray) -> np.ndarray:
    """The Jacobian of ``G(x) + e - W(x)`` over the state augmented by ``e`` (last): the
    wheels' turn Jacobian is row ``STATE_THETA`` of the wheel step's ``F`` (identity on the
    heading itself, which neither turn depends on)."""
    n = x.shape[0]
    H = np.zeros(n + 1)
    H[:n] = -F_wheels[model.STATE_THETA, :n]
    H[model.STATE_THETA] = 0.0
    bias, scale = float(x[STATE_GYRO_BIAS]), float(x[STATE_GYRO_SCALE])
    H[STATE_GYRO_BIAS] += -span_s * (1.0 + scale)
    H[STATE_GYRO_SCALE] += angle_rad - bias * span_s
    H[n] = 1.0
    return H


def fuse_turn(
    x: np.ndarray,
    P: np.ndarray,
    F_wheels: np.ndarray,
    var_wheel_turn: float,
    wheel_turn: float,
    turned: tuple[float, float, float],
    gate_chi2: float,
) -> tuple[float, float, np.ndarray, float] | None:
    """Update ``x`` and ``P`` in place with one step's wheel turn (module doc). Returns the
    gyro noise's posterior mean and variance, its covariance with the state and the d^2; or
    None (nothing changed) when the gate refuses the step."""
    angle, span, angle_var = turned
    n = x.shape[0]
    bias, scale = float(x[STATE_GYRO_BIAS]), float(x[STATE_GYRO_SCALE])
    y = wheel_turn - gyro_turn(angle, span, bias, scale)  # z = 0, h = G + e - W
    H = turn_row(F_wheels, angle, span, x)
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
    wheels: tuple[np.ndarray, np.ndarray, float],
    raw: tuple[float, float, float],
    turned: tuple[float, float, float],
    var_wheels_m2: float,
) -> tuple[float, np.ndarray, np.ndarray, str | None]:
    """An odometry step turned by the gyro: with ``cfg.with_wheels`` its wheel turn first
    measures the turn (``fuse_turn``; ``x`` and ``P`` updated in place), then the heading
    change, state Jacobian and process noise (``gyro.gyro_step``). ``wheels``: the wheel
    step's Jacobian, process noise and turn; ``raw``: the raw left and right increments and
    the corrected distance. Also returns what to count (``USED``, ``GATED``) or None."""
    raw_l, raw_r, d = raw
    F_w, Q_w, wheel_turn = wheels
    if not cfg.with_wheels or d == 0.0:
        return (*gyro_step(x, raw_l, raw_r, d, turned, var_wheels_m2), None)
    fused = fuse_turn(x, P, F_w, float(Q_w[model.STATE_THETA, model.STATE_THETA]), wheel_turn,
                      turned, cfg.gate_chi2)  # fmt: skip
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
