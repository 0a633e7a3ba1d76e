"""The filter's gates (``localize.gates``): what may update the estimate, and why not."""

from __future__ import annotations

import math

import numpy as np

from guidance.core.localize import gates
from guidance.core.localize.covariance_edits import prior
from guidance.core.localize.estimator import EstimatorConfig
from guidance.core.messages import LandmarkFix, WheelOdometry
from guidance.core.stages import LOST_HYSTERESIS, RELOCALISED


def _wide(major_axis_m: float) -> np.ndarray:
    """A pose covariance whose 2-sigma major axis is ``major_axis_m`` (along x)."""
    P = prior(EstimatorConfig())
    P[0, 0] = (major_axis_m / 4.0) ** 2  # full axis = 2 x 2 sigma
    return P


def test_a_relocalising_fix_resets_only_while_lost_past_the_hysteresis() -> None:
    cfg = EstimatorConfig()
    x = np.zeros(3)
    far = LandmarkFix(1.0, 7, 900.0, 0.0, 5.0, relocalised=True)
    edge = LOST_HYSTERESIS * cfg.lost_major_axis_m
    assert gates.landmark_verdict(cfg, x, _wide(edge * 1.01), far).reason == RELOCALISED
    assert gates.landmark_verdict(cfg, x, _wide(edge * 0.99), far).reason == "landmark_gate"
    plain = LandmarkFix(1.0, 7, 900.0, 0.0, 5.0)  # not a whole-database find: gated as ever
    assert gates.landmark_verdict(cfg, x, _wide(edge * 2.0), plain).reason == "landmark_gate"
    near = gates.landmark_verdict(cfg, x, _wide(edge * 0.99), LandmarkFix(1.0, 7, 1.0, 0.0, 5.0))
    assert near.reason is None and near.var == 25.0 and near.d2 is not None


def test_inputs_outside_their_bounds_are_refused_before_any_math() -> None:
    cfg = EstimatorConfig()
    x, P = np.zeros(3), prior(cfg)
    assert gates.odometry_refusal(cfg, WheelOdometry(1.0, math.nan, 0.0)) == "non_finite_input"
    big = cfg.max_wheel_step_m * 1.01
    assert gates.odometry_refusal(cfg, WheelOdometry(1.0, 0.0, big)) == "implausible_odometry"
    assert gates.odometry_refusal(cfg, WheelOdometry(1.0, 1.0, 1.0)) is None
    for sigma in (gates.MIN_LANDMARK_SIGMA_M / 2, gates.MAX_LANDMARK_SIGMA_M * 2):
        v = gates.landmark_verdict(cfg, x, P, LandmarkFix(1.0, 1, 0.0, 0.0, sigma))
        assert v.reason == "implausible_landmark" and v.d2 is None
    v = gates.landmark_verdict(cfg, x, P, LandmarkFix(1.0, 1, gates.MAX_COORDINATE_M * 2, 0, 1))
    assert v.reason == "implausible_landmark"
    judge = gates.Interference()
    nothing = EstimatorConfig(compass_two_sigma_deg=None)
    assert gates.heading_verdict(nothing, x, P, 0.0, judge).reason == "no_compass_configured"
    assert gates.heading_verdict(cfg, x, P, math.inf, judge).reason == "non_finite_input"
    assert judge.level == 1.0  # refused before the judge saw it


def test_the_interference_judge_turns_on_above_its_level_and_off_only_below_the_lower() -> None:
    cfg = EstimatorConfig()
    judge = gates.Interference()
    states = [judge.judge(16.0, cfg) for _ in range(12)]  # readings far off the estimate
    assert not states[0] and states[-1] and judge.level > cfg.interference_on_nis
    k = 0
    while judge.judge(1.0, cfg):  # readings as modelled again
        assert judge.level > cfg.interference_off_nis
        k += 1
    assert k > 0 and judge.level <= cfg.interference_off_nis
