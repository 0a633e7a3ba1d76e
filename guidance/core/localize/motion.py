"""The filter's motion model (filterpy's ``predict``): one odometry increment in, the state
transition ``F``, its process noise ``Q`` and the control ``u = (distance, heading change)``
out, which the estimator hands to ``predict`` (whose ``predict_x`` moves the state along the
chord: ``measurements.ekf_class``).

For the paper's three states the wheels' increments with their noise (``guidance.core.model``,
shared with the study engine); for the car model's seven also the scale, difference and turn
states and the compass bias's growth with time and turns; for a gyro car's nine the gyro's
turn (``gyro.gyro_step``; ``yaw_source = "both"``: the wheels' turn measures it first,
``turn_fusion``, which updates the x and P it is handed: the estimator's own). And the
second-order heading term the linearised predict leaves out (``lever_sq``,
``widen_along_lever``). The estimator is the only caller: it alone moves x and P.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from guidance.core import model
from guidance.core.localize import turn_fusion
from guidance.core.localize.estimator_config import EstimatorConfig

BIAS_TURN_STEP_RAD = math.radians(10.0)
"""The bias grows with heading changes counted in steps of this size, so that the wiggles of a
straight drive (which cancel) do not add up as if they were turns."""


@dataclass(frozen=True, slots=True)
class Transition:
    """One odometry step's predict: ``F``, ``Q`` and ``u`` for filterpy, and what it counted."""

    F: np.ndarray
    Q: np.ndarray
    u: np.ndarray
    """(distance along the chord, heading change)."""
    turn_rad: float
    """The heading change not yet counted toward the compass bias's growth, after the step."""
    counted: str | None = None
    """``turn_fusion.USED`` or ``GATED``: the wheels' turn measured the gyro's, or was gated."""


def transition(
    cfg: EstimatorConfig,
    x: np.ndarray,
    P: np.ndarray,
    wheels: tuple[float, float, float],
    turned: tuple[float, float, float] | None,
    turn_rad: float,
) -> Transition:
    """The predict of one odometry step from state ``x`` (covariance ``P``): ``wheels`` the
    raw left and right increments (m) and the time since the last step (s), ``turned`` the
    gyro's gathered angle (``gyro.before_step``; None: the wheels turn), ``turn_rad`` the
    heading change not yet counted toward the compass bias's growth."""
    raw_l, raw_r, dt = wheels
    dl, dr = raw_l, raw_r
    car = x.shape[0] > model.N_STATE
    track = cfg.track_m
    if car:
        dl, dr = model.corrected_wheels(dl, dr, float(x[model.STATE_SCALE]),
                                        float(x[model.STATE_DIFF]))  # fmt: skip
        track = model.effective_track(track, float(x[model.STATE_TURN]))
    d, dth = model.odometry_increment(dl, dr, track)
    F, G, Q = np.empty((3, 3)), np.empty((3, 2)), np.empty((3, 3))
    model.motion_jacobians(float(x[2]), dl, dr, track, F, G)
    var_l = model.wheel_noise_var(dl, cfg.wheel_quantum_m, cfg.wheel_slip_frac)
    var_r = model.wheel_noise_var(dr, cfg.wheel_quantum_m, cfg.wheel_slip_frac)
    if cfg.wheel_walk_var_m2_per_m > 0.0:
        var_l += model.wheel_walk_var(dl, cfg.wheel_walk_var_m2_per_m)
        var_r += model.wheel_walk_var(dr, cfg.wheel_walk_var_m2_per_m)
    model.process_noise(G, var_l, var_r, Q)
    if not car:
        return Transition(F, Q, np.array([d, dth]), turn_rad)
    n = x.shape[0]
    Fc, Qc = np.eye(n), np.zeros((n, n))
    Fc[:3, :3] = F
    model.scale_jacobian(G, raw_l, raw_r, Fc)
    model.turn_jacobian(dl, dr, cfg.track_m, Fc)
    Qc[:3, :3] = Q
    Qc[model.STATE_DIFF, model.STATE_DIFF] = cfg.diff_walk_var_per_m * abs(d)
    Qc[model.STATE_THETA, model.STATE_THETA] += model.camber_heading_var(
        d, cfg.camber_diff_sigma, cfg.camber_length_m, cfg.track_m
    )
    counted = None
    if turned is not None and cfg.gyro is not None:  # the gyro turns ("both": measured)
        dth, Fc, Qc, counted = turn_fusion.gyro_turn_step(
            cfg.gyro, x, P, (cfg.track_m, float(Qc[2, 2])), (raw_l, raw_r, d), turned,
            var_l + var_r)  # fmt: skip
    walk = cfg.compass_bias_walk_deg2_per_s * dt
    turn_rad += dth
    turn = 0.0
    if abs(turn_rad) >= BIAS_TURN_STEP_RAD:  # a heading change, not a wiggle
        turn = cfg.compass_bias_turn_deg2_per_rad * abs(turn_rad)
        turn_rad = 0.0
    Qc[model.STATE_BIAS, model.STATE_BIAS] = math.radians(1.0) ** 2 * (walk + turn)
    return Transition(Fc, Qc, np.array([d, dth]), turn_rad, counted)


def lever_sq(P: np.ndarray) -> float:
    """``|P_xy,theta|^2``: the squared position lever of a heading error (before a predict)."""
    return float(P[0, 2]) ** 2 + float(P[1, 2]) ** 2


def widen_along_lever(P: np.ndarray, before: float, factor: float) -> None:
    """The second-order term of a heading error, which a linearised filter leaves out, in
    place after a predict: a position lever ``r`` turned by an error ``delta`` also moves
    ``-r delta^2 / 2`` along itself, ``|r| sigma^2 = |P_xy,theta|``. Its second moment about
    the (uncorrected) estimate is ``3/4 |P_xy,theta|^2`` (``E[delta^4] = 3 sigma^4``):
    ``factor`` times the growth of ``|P_xy,theta|^2`` since ``before`` (``lever_sq``) is added
    along the lever (``EstimatorConfig.heading_second_order``; docs/estimation.md)."""
    cx, cy = float(P[0, 2]), float(P[1, 2])
    c1 = cx * cx + cy * cy
    if c1 > before:  # along the lever (cy, -cx): perpendicular to dp/dtheta
        g = factor * (c1 - before) / c1
        P[0, 0] += g * cy * cy
        P[1, 1] += g * cx * cx
        P[0, 1] -= g * cx * cy
        P[1, 0] -= g * cx * cy
