"""The filter's motion model (``localize.motion``): one odometry step's F, Q and control."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from guidance.core import model
from guidance.core.localize import motion
from guidance.core.localize.car_model import car_model
from guidance.core.localize.covariance_edits import prior
from guidance.core.localize.estimator import EstimatorConfig


def test_the_car_model_with_no_error_is_the_paper_model_on_the_pose() -> None:
    """Scale, difference and turn states at zero: the pose block of F and Q is the paper
    filter's for the same wheel noise (the error states only add columns and rows)."""
    car = car_model(EstimatorConfig(), calibrated=True, camber_diff_sigma=0.0)
    paper = replace(car, scale_sigma=0.0, diff_sigma=0.0, turn_scale_sigma=0.0,
                    compass_bias_sigma_deg=0.0)  # fmt: skip
    assert car.n_state == model.N_STATE_CAR and paper.n_state == model.N_STATE
    x7, x3 = np.zeros(7), np.zeros(3)
    x7[2] = x3[2] = 0.4
    a = motion.transition(car, x7, prior(car), (1.0, 1.05, 0.1), None, 0.0)
    b = motion.transition(paper, x3, prior(paper), (1.0, 1.05, 0.1), None, 0.0)
    assert np.array_equal(a.F[:3, :3], b.F) and np.array_equal(a.Q[:3, :3], b.Q)
    assert np.array_equal(a.u, b.u)
    assert a.F[0, model.STATE_SCALE] != 0.0  # the scale moves the position


def test_the_compass_bias_grows_with_turns_counted_in_ten_degree_steps() -> None:
    """The bias's variance grows with time and with heading changes, counted once they add up
    to ``BIAS_TURN_STEP_RAD``: a straight drive's wiggles (which cancel) add nothing."""
    cfg = car_model(EstimatorConfig(), calibrated=True)
    x, P = np.zeros(7), prior(cfg)
    b = model.STATE_BIAS
    walk = math.radians(1.0) ** 2 * cfg.compass_bias_walk_deg2_per_s * 0.1
    wiggle = motion.transition(cfg, x, P, (1.0, 1.01, 0.1), None, 0.0)
    assert wiggle.Q[b, b] == pytest.approx(walk) and 0.0 < wiggle.turn_rad < 0.01
    back = motion.transition(cfg, x, P, (1.01, 1.0, 0.1), None, wiggle.turn_rad)
    assert back.Q[b, b] == pytest.approx(walk) and abs(back.turn_rad) < 1e-12  # cancelled
    near = motion.BIAS_TURN_STEP_RAD - 0.001
    turn = motion.transition(cfg, x, P, (1.0, 1.01, 0.1), None, near)
    total = near + float(turn.u[1])
    assert total >= motion.BIAS_TURN_STEP_RAD and turn.turn_rad == 0.0
    extra = math.radians(1.0) ** 2 * cfg.compass_bias_turn_deg2_per_rad * total
    assert turn.Q[b, b] == pytest.approx(walk + extra)


def test_the_second_order_term_widens_along_the_lever_only() -> None:
    """``widen_along_lever``: ``factor`` times the growth of ``|P_xy,theta|^2`` goes on the
    trace, along the lever, none along dp/dtheta; nothing when the lever did not grow."""
    P = np.diag([4.0, 9.0, 0.01])
    P[0, 2] = P[2, 0] = 0.05
    P[1, 2] = P[2, 1] = 0.12
    before = motion.lever_sq(P) - 0.004
    Q = P.copy()
    motion.widen_along_lever(Q, before, 0.75)
    c = P[:2, 2]
    assert np.trace(Q) - np.trace(P) == pytest.approx(0.75 * 0.004)
    assert c @ (Q - P)[:2, :2] @ c == pytest.approx(0.0, abs=1e-15)
    R = P.copy()
    motion.widen_along_lever(R, motion.lever_sq(P) + 1.0, 0.75)
    assert np.array_equal(R, P)
