"""Pipeline edge cases: an odometry dropout, and advice without a heading."""

from __future__ import annotations

import math

import pytest

from guidance.core.localize.estimator import REANCHOR_AFTER, EstimatorConfig
from guidance.core.messages import HeadingFix, WheelOdometry
from guidance.core.odometry_gap import GAP_ACCEL_MPS2
from guidance.core.pipeline import Pipeline, PipelineConfig
from guidance.core.plan.navigator import NavigatorConfig


def _pipeline() -> Pipeline:
    cfg = PipelineConfig(
        estimator=EstimatorConfig(compass_two_sigma_deg=20.0),
        navigator=NavigatorConfig(),
        start_xy_m=(0.0, 0.0),
        start_heading_rad=0.0,
        expected_rates_hz={"odometry": 20.0},
        stop_at_arrival=False,
    )
    return Pipeline(cfg)


def test_a_5_s_dropout_at_11_mps_is_dead_reckoned_along_the_road_not_widened_as_a_circle() -> None:
    """Issue 20, item 4: the heading and the speed are known through a CAN dropout, only the
    distance is not. The estimate moves on at the last speed along its heading, widened along
    the road by what the car could have gained or lost (1/2 a t^2 as 2-sigma), across it only
    by the heading's own uncertainty."""
    p = _pipeline()
    t, step = 0.0, 11.0 * 0.05
    for _ in range(200):  # 10 s at 11 m/s east, 20 Hz
        t += 0.05
        p.feed(WheelOdometry(t, step, step))
    x_before = float(p.localizer.estimator.x[0])
    before = p.localizer.estimator.P[:2, :2].copy()
    for k in range(30):  # the compass goes on through the gap (6 Hz, heading east)
        p.feed(HeadingFix(t + (k + 1) / 6.0, 0.0))
    p.feed(WheelOdometry(t + 5.0, step, step))  # the first increment after 5 s of silence
    p.feed(WheelOdometry(t + 5.05, step, step))  # confirms the new time base
    assert p.counts["odometry_gaps"] == 1
    moved = float(p.localizer.estimator.x[0]) - x_before
    assert moved == pytest.approx(11.0 * 5.05 + step, abs=1.5)  # the 55 m it could not measure
    along = 2.0 * math.sqrt(p.localizer.estimator.P[0, 0] - before[0, 0])
    across = 2.0 * math.sqrt(max(0.0, p.localizer.estimator.P[1, 1] - before[1, 1]))
    assert along == pytest.approx(0.5 * GAP_ACCEL_MPS2 * 5.05**2, rel=0.1)  # 38 m, not 92 m
    assert across < 0.3 * along
    assert p.localizer.estimator.major_axis_m < 100.0  # not lost
    assert math.isclose(p.estimate.speed_mps, 11.0, rel_tol=0.01)  # the speed before the gap


def test_without_a_compass_a_dropout_widens_across_too_but_the_car_is_not_lost() -> None:
    """No compass: the car may have turned a corner in the gap (the heading's random walk at
    a town corner's yaw rate), so the spread grows across as well; still not lost."""
    p = _pipeline()
    t, step = 0.0, 11.0 * 0.05
    for _ in range(200):
        t += 0.05
        p.feed(WheelOdometry(t, step, step))
    p.feed(WheelOdometry(t + 5.0, step, step))
    p.feed(WheelOdometry(t + 5.05, step, step))
    assert p.counts["odometry_gaps"] == 1
    assert p.localizer.estimator.major_axis_m < 100.0


def test_no_turn_advice_until_the_heading_is_known() -> None:
    """No compass reading yet and no start heading: say so once, advise nothing."""
    from dataclasses import replace

    from guidance.core.messages import CompassHeading, IntersectionScene

    p = Pipeline(replace(_pipeline().config, start_heading_rad=None, goal_xy_m=(0.0, 1000.0),
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
    assert glitched.counts["time_glitch_dropped"] == 1 and glitched.counts["odometry_gaps"] == 0
    g, c = glitched.estimate, clean.estimate
    assert g.ellipse.major_axis_m == pytest.approx(c.ellipse.major_axis_m)
    assert glitched.localizer.estimator.x[0] == pytest.approx(clean.localizer.estimator.x[0])


def test_a_clock_stepped_back_half_a_second_keeps_the_estimate_moving() -> None:
    """A wall-clock step of -0.5 s between two increments (issue 14, item 1)."""
    p = _pipeline()
    t, step = 0.0, 11.0 * 0.05
    for k in range(200):
        t += 0.05
        if k == 100:
            t -= 0.5
        assert p.feed(WheelOdometry(t, step, step)).accepted
    assert p.localizer.estimator.x[0] == pytest.approx(200 * step, rel=1e-6)
    assert p.statuses(t)["odometry"].valid


def test_inputs_the_estimator_cannot_place_in_time_make_the_input_invalid() -> None:
    p = _pipeline()
    for k in range(1, 40):
        p.feed(WheelOdometry(0.05 * k, 0.5, 0.5))
    p.localizer.estimator.process(WheelOdometry(100.0, 0.1, 0.1))  # the estimate's time: ahead
    out = p.feed(WheelOdometry(2.05, 0.5, 0.5))
    assert out.reason == "out_of_order"
    st = p.statuses(2.05)["odometry"]
    assert not st.valid and "time" in st.detail
    for k in range(REANCHOR_AFTER):
        p.feed(WheelOdometry(2.1 + 0.05 * k, 0.5, 0.5))
    assert p.statuses(3.0)["odometry"].valid  # the estimate followed the inputs' time
