"""Pipeline edge cases: an odometry dropout, and advice without a heading."""

from __future__ import annotations

import math

from guidance.core.estimator import EstimatorConfig
from guidance.core.messages import WheelOdometry
from guidance.core.navigator import NavigatorConfig
from guidance.core.pipeline import GAP_ACCEL_MPS2, Pipeline, PipelineConfig, gap_spread_m


def _pipeline() -> Pipeline:
    cfg = PipelineConfig(
        estimator=EstimatorConfig(compass_two_sigma_deg=None),
        navigator=NavigatorConfig(),
        start_xy_m=(0.0, 0.0),
        goal_xy_m=(1e6, 0.0),
        start_heading_rad=0.0,
        expected_rates_hz={"odometry": 20.0},
        stop_at_arrival=False,
    )
    return Pipeline(cfg)


def test_a_5_s_dropout_at_11_mps_widens_by_the_distance_it_could_not_measure() -> None:
    p = _pipeline()
    t, step = 0.0, 11.0 * 0.05
    for _ in range(200):  # 10 s at 11 m/s, 20 Hz
        t += 0.05
        p.feed(WheelOdometry(t, step, step))
    before = p.estimator.P[:2, :2].copy()
    p.feed(WheelOdometry(t + 5.0, step, step))  # the first increment after 5 s of silence
    assert p.counts["gap_inflations"] == 1
    added = p.estimator.P[0, 0] - before[0, 0]
    spread = 2.0 * math.sqrt(added)  # the 2-sigma distance the widening stands for
    unmeasured = 11.0 * 5.0  # about 55 m went unmeasured
    assert spread >= unmeasured
    assert math.isclose(spread, unmeasured + 0.5 * GAP_ACCEL_MPS2 * 25.0, rel_tol=0.02)
    assert math.isclose(p.speed_mps, 11.0, rel_tol=0.01)  # the speed before the gap is kept


def test_the_spread_is_the_last_speed_plus_what_could_be_gained() -> None:
    assert gap_spread_m(11.0, 5.0) == 55.0 + 37.5
    assert gap_spread_m(0.0, 2.0) == 0.5 * GAP_ACCEL_MPS2 * 4.0  # standing: could have set off


def test_no_turn_advice_until_the_heading_is_known() -> None:
    """No compass reading yet and no start heading: say so once, advise nothing."""
    from dataclasses import replace

    from guidance.core.messages import CompassHeading, IntersectionScene

    p = Pipeline(replace(_pipeline().config, start_heading_rad=None,
                         estimator=EstimatorConfig(compass_two_sigma_deg=20.0)))  # fmt: skip
    exits = (0.0, math.pi / 2, -math.pi / 2)
    said = []
    for k in range(3):
        out = p.feed(IntersectionScene(1.0 + k, exits))
        assert not out.accepted and out.reason == "heading_unknown" and not out.decisions
        said += [pr.text for pr in out.prompts if pr.kind != "sensor"]
    assert len(said) == 1 and said[0].startswith("Waiting for a heading")
    p.feed(CompassHeading(5.0, 90.0))  # the first reading gives the heading
    out = p.feed(IntersectionScene(6.0, exits))
    assert out.accepted and len(out.decisions) == 1
