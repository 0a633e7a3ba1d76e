"""Pipeline edge cases: an odometry dropout, and advice without a heading."""

from __future__ import annotations

import math

import pytest

from guidance.core.estimator import REANCHOR_AFTER, EstimatorConfig
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


def test_a_frame_stamped_an_hour_ahead_neither_widens_nor_freezes_the_estimate() -> None:
    """An adapter glitch stamps one increment an hour ahead (issue 14, item 2): it is held
    until the next one shows the time base did not move, then dropped; the estimate is the
    same as without the glitch and keeps moving."""
    step = 11.0 * 0.05
    runs = []
    for glitch in (False, True):
        p = _pipeline()
        t = 0.0
        for k in range(140):
            t += 0.05
            if glitch and k == 100:
                out = p.feed(WheelOdometry(t + 3600.0, step, step))
                assert not out.accepted and out.reason == "held_after_gap"
            assert p.feed(WheelOdometry(t, step, step)).accepted
        runs.append(p)
    clean, glitched = runs
    assert glitched.counts["time_glitch_dropped"] == 1 and glitched.counts["gap_inflations"] == 0
    assert glitched.estimator.major_axis_m == pytest.approx(clean.estimator.major_axis_m)
    assert glitched.estimator.x[0] == pytest.approx(clean.estimator.x[0])


def test_a_clock_stepped_back_half_a_second_keeps_the_estimate_moving() -> None:
    """A wall-clock step of -0.5 s between two increments (issue 14, item 1)."""
    p = _pipeline()
    t, step = 0.0, 11.0 * 0.05
    for k in range(200):
        t += 0.05
        if k == 100:
            t -= 0.5
        assert p.feed(WheelOdometry(t, step, step)).accepted
    assert p.estimator.x[0] == pytest.approx(200 * step, rel=1e-6)
    assert p.statuses(t)["odometry"].valid


def test_inputs_the_estimator_cannot_place_in_time_make_the_input_invalid() -> None:
    p = _pipeline()
    for k in range(1, 40):
        p.feed(WheelOdometry(0.05 * k, 0.5, 0.5))
    p.estimator.process(WheelOdometry(100.0, 0.1, 0.1))  # the estimate's time is now ahead
    out = p.feed(WheelOdometry(2.05, 0.5, 0.5))
    assert out.reason == "out_of_order"
    st = p.statuses(2.05)["odometry"]
    assert not st.valid and "time" in st.detail
    for k in range(REANCHOR_AFTER):
        p.feed(WheelOdometry(2.1 + 0.05 * k, 0.5, 0.5))
    assert p.statuses(3.0)["odometry"].valid  # the estimate followed the inputs' time
