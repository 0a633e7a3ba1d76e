"""Learned parameters (guidance/core/localize/learned.py): taken from the filter, widened with time,
applied to the next drive, refused when absurd."""

from __future__ import annotations

import math

import pytest

from guidance.core import model
from guidance.core.localize.car_model import car_model
from guidance.core.localize.estimator import EstimatorConfig, PoseEstimator
from guidance.core.localize.learned import SCHEMA, LearnedParams
from guidance.core.messages import WheelOdometry


def _car(compass: bool = True) -> PoseEstimator:
    cfg = car_model(EstimatorConfig(compass_two_sigma_deg=30.0 if compass else None),
                    calibrated=False)  # fmt: skip
    return PoseEstimator(cfg, 0.0, 0.0, 0.0)


def test_taken_from_the_filter_and_applied_to_the_next_one() -> None:
    est = _car()
    for k in range(100):
        est.process(WheelOdometry(0.1 * (k + 1), 1.0, 1.0))
    p = LearnedParams.from_estimator(est, "car1", 1000.0, 100.0)
    assert p is not None and p.scale_sigma == pytest.approx(0.02, rel=0.05)
    nxt = _car()
    learned = LearnedParams("car1", 0.0, 500.0, 0.012, 0.004, 0.0002, 0.0001, 35.0, 4.0)
    learned.apply(nxt)
    assert nxt.x[3] == pytest.approx(0.012) and math.sqrt(nxt.P[3, 3]) == pytest.approx(0.004)
    assert math.degrees(nxt.x[5]) == pytest.approx(35.0)
    assert nxt.P[0, 3] == 0.0 and nxt.P[3, 5] == 0.0
    assert (
        LearnedParams.from_estimator(PoseEstimator(EstimatorConfig(), 0, 0, 0), "x", 0, 0) is None
    )


def test_widened_with_the_time_since_and_never_wider_than_the_prior() -> None:
    cfg = _car().config
    p = LearnedParams("car1", 0.0, 500.0, 0.012, 0.004, 0.0002, 0.0001, 35.0, 4.0)
    same = p.widened(0.0, cfg)
    assert same.scale_sigma == pytest.approx(0.004) and same.compass_bias_sigma_deg == 4.0
    month = p.widened(30 * 86400.0, cfg)
    assert month.scale_sigma == pytest.approx(math.hypot(0.004, 0.001))
    assert month.compass_bias_sigma_deg == cfg.compass_bias_sigma_deg  # the car's field moved
    years = p.widened(3e9, cfg)
    assert years.scale_sigma == cfg.scale_sigma and years.diff_sigma == cfg.diff_sigma
    assert years.scale == p.scale  # the value stays; only how sure the car is of it changes


@pytest.mark.parametrize(
    ("key", "value", "why"),
    [
        ("schema", "guidance.learned/0", "schema"),
        ("scale", 0.5, "scale = 0.5 is outside"),
        ("scale", float("nan"), "scale must be a finite number"),
        ("scale_sigma", 0.0, "scale_sigma = 0.0 is outside"),
        ("diff", True, "diff must be a finite number"),
        ("vehicle_id", "", "vehicle_id"),
        ("compass_bias_deg", 400.0, "compass_bias_deg = 400"),
        ("turn_scale", 0.4, "turn_scale = 0.4 is outside"),
        ("turn_scale_sigma", -1.0, "turn_scale_sigma = -1.0 is outside"),
        ("extra", 1, "unknown fields: extra"),
    ],
)
def test_an_absurd_or_tampered_value_is_refused_by_name(key: str, value: object, why: str) -> None:
    good = LearnedParams(
        "car1", 0.0, 500.0, 0.012, 0.004, 0.0002, 0.0001, 35.0, 4.0, -0.01, 0.005
    ).to_dict()
    assert good["schema"] == SCHEMA
    assert LearnedParams.from_dict(good).scale == 0.012
    with pytest.raises(ValueError, match=why):
        LearnedParams.from_dict({**good, key: value})


def test_the_turn_scale_is_learned_kept_and_a_version_1_file_still_reads() -> None:
    """Version 2 keeps the turn scale (a state since version 2); a version-1 file, without
    it, is read as it was and the turn scale starts from its prior."""
    est = _car()
    for k in range(100):  # a left turn on the wheels: the turn scale's variance is its prior
        est.process(WheelOdometry(0.1 * (k + 1), 0.99, 1.01))
    p = LearnedParams.from_estimator(est, "car1", 1000.0, 100.0)
    assert p is not None and p.turn_scale_sigma == pytest.approx(0.02, rel=0.05)
    nxt = _car()
    LearnedParams.from_dict(p.to_dict() | {"turn_scale": -0.015, "turn_scale_sigma": 0.006}).apply(
        nxt
    )
    assert nxt.x[model.STATE_TURN] == pytest.approx(-0.015)
    assert math.sqrt(nxt.P[model.STATE_TURN, model.STATE_TURN]) == pytest.approx(0.006)
    assert p.widened(3e9, nxt.config).turn_scale_sigma == nxt.config.turn_scale_sigma
    v1 = {k: v for k, v in p.to_dict().items() if not k.startswith("turn_scale")}
    old = LearnedParams.from_dict(v1 | {"schema": "guidance.learned/1"})
    assert old.turn_scale is None
    fresh = _car()
    old.apply(fresh)
    assert math.sqrt(fresh.P[model.STATE_TURN, model.STATE_TURN]) == pytest.approx(0.02)
