"""A gyro car through the estimator (issue 38): honest over a population of sensors drawn from
the filter's own priors, the bias learned at standstill, a stale gyro handed back to the
wheels, the states kept in the learned file."""

from __future__ import annotations

import math

import numpy as np
import pytest

from guidance.core import model
from guidance.core.localize import gyro
from guidance.core.localize.car_model import car_model
from guidance.core.localize.estimator import EstimatorConfig, PoseEstimator
from guidance.core.localize.learned import LearnedParams
from guidance.core.messages import WheelOdometry, YawRate

DT = 0.1


def _gyro_estimator() -> PoseEstimator:
    cfg = car_model(EstimatorConfig(track_m=1.6, compass_two_sigma_deg=None), calibrated=False)
    from dataclasses import replace

    return PoseEstimator(replace(cfg, gyro=gyro.GyroConfig()), 0.0, 0.0, 0.0)


def _drive(
    est: PoseEstimator, rng: np.random.Generator, bias: float, scale: float, plan: list[tuple]
) -> tuple[float, float]:
    """Drive ``plan`` ((seconds, speed m/s, yaw rate rad/s), ...) with a sensor of ``bias``
    (rad/s) and ``scale``; returns the true heading and the true bias at the end."""
    cfg = gyro.GyroConfig()
    theta, t = 0.0, 0.0
    band = max(cfg.bandwidth_hz, 1.0 / DT)
    for seconds, speed, rate in plan:
        for _ in range(round(seconds / DT)):
            t += DT
            theta += rate * DT
            bias += rng.normal() * math.sqrt(cfg.walk_var_per_s * DT)
            noise = rng.normal() * math.sqrt(cfg.noise_var_per_s * band)
            reading = rate / (1 + scale) + bias + noise
            est.process(YawRate(t, reading))
            est.process(WheelOdometry(t, speed * DT, speed * DT))
    return theta, bias


TURN = math.radians(10.0)
PLAN = [(20.0, 0.0, 0.0), (30.0, 10.0, 0.0), (9.0, 5.0, TURN), (30.0, 10.0, 0.0),
        (25.0, 0.0, 0.0), (60.0, 10.0, 0.0), (9.0, 5.0, -TURN), (60.0, 10.0, 0.0)]  # fmt: skip
"""A start from standstill, turns, a stop at a light and a minute's drive after it."""


def test_a_population_of_gyros_from_the_priors_is_honest_in_heading_and_bias() -> None:
    """100 sensors drawn from the filter's own priors (bias 0.3 deg/s, scale 2 %, the walk and
    the noise): the mean normalised squared error of the final heading and of the learned
    bias lie within their chi-square bands (1 dof per car)."""
    rng = np.random.default_rng(8)
    cfg = gyro.GyroConfig()
    nh, nb = [], []
    for _ in range(100):
        bias = rng.normal() * math.sqrt(cfg.bias_var)
        scale = rng.normal() * cfg.scale_sigma
        est = _gyro_estimator()
        theta, bias_end = _drive(est, rng, bias, scale, PLAN)
        x, P = est.x, est.P
        nh.append(model.wrap_angle(theta - x[2]) ** 2 / P[2, 2])
        b = gyro.STATE_GYRO_BIAS
        nb.append((bias_end - x[b]) ** 2 / P[b, b])
        assert est.accepted["gyro_standstill"] > 300
    lo, hi = 0.70, 1.35  # chi2(100 dof) 95 % band over 100
    assert lo < float(np.mean(nh)) < hi
    assert lo < float(np.mean(nb)) < hi


def test_the_bias_is_learned_at_standstill_and_no_heading_is_integrated_there() -> None:
    rng = np.random.default_rng(3)
    est = _gyro_estimator()
    bias = math.radians(0.25)
    _drive(est, rng, bias, 0.0, [(60.0, 0.0, 0.0)])
    b = gyro.STATE_GYRO_BIAS
    assert abs(est.x[b] - bias) < 3 * math.sqrt(est.P[b, b])
    assert math.degrees(math.sqrt(est.P[b, b])) < 0.02
    assert abs(math.degrees(est.x[2])) < 0.1  # 60 s x 0.25 deg/s = 15 deg if integrated


def test_a_stale_gyro_hands_the_turn_back_to_the_wheels() -> None:
    est = _gyro_estimator()
    track = est.config.track_m
    for k in range(1, 51):  # no reading at all: the wheels' difference turns the car
        est.process(WheelOdometry(k * DT, 1.0 - 0.005 * track, 1.0 + 0.005 * track))
    assert est.accepted["gyro_stale_wheel_turn"] == 50
    assert est.x[2] == pytest.approx(50 * 0.01, rel=1e-6)
    assert est.process(YawRate(6.0, math.nan)).reason == "non_finite_input"
    assert est.process(YawRate(6.0, 10.0)).reason == "implausible_yaw_rate"
    assert est.process(YawRate(6.0, 0.1)).accepted
    assert est.process(YawRate(5.9, 0.1)).reason == "gyro_out_of_order"


def test_a_wheel_car_refuses_a_yaw_rate() -> None:
    cfg = car_model(EstimatorConfig(compass_two_sigma_deg=None), calibrated=False)
    est = PoseEstimator(cfg)
    assert est.n == model.N_STATE_CAR
    assert est.process(YawRate(1.0, 0.1)).reason == "no_gyro_configured"


def test_the_gyro_states_are_learned_and_kept() -> None:
    rng = np.random.default_rng(4)
    est = _gyro_estimator()
    _drive(est, rng, math.radians(-0.2), 0.01, [(30.0, 0.0, 0.0), (20.0, 10.0, 0.0)])
    p = LearnedParams.from_estimator(est, "car1", 1000.0, 200.0)
    assert p is not None and p.gyro_bias_deg_s == pytest.approx(-0.2, abs=0.03)
    back = LearnedParams.from_dict(p.to_dict())
    assert back == p
    nxt = _gyro_estimator()
    later = back.widened(1000.0 + 60.0, nxt.config)  # a minute later
    later.apply(nxt)
    b = gyro.STATE_GYRO_BIAS
    assert math.degrees(nxt.x[b]) == pytest.approx(-0.2, abs=0.03)
    assert math.degrees(math.sqrt(nxt.P[b, b])) < 0.1
    a_day = back.widened(1000.0 + 86400.0, nxt.config)  # restarted since: back to the prior
    assert a_day.gyro_bias_sigma_deg_s == pytest.approx(gyro.GyroConfig().bias_sigma_deg_s)
    bad = dict(p.to_dict(), gyro_bias_deg_s=40.0)
    with pytest.raises(ValueError, match="gyro_bias_deg_s"):
        LearnedParams.from_dict(bad)
