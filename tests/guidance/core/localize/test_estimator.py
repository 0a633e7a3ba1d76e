"""Estimator tests: consistency (NEES), growth, updates, gates, conversions."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import chi2

from guidance.core import model
from guidance.core.localize.car_model import car_model
from guidance.core.localize.estimator import REANCHOR_AFTER, EstimatorConfig, PoseEstimator
from guidance.core.messages import HeadingFix, LandmarkFix, WheelOdometry

TRACK = 1.72


def _drive(
    rng: np.random.Generator,
    cfg: EstimatorConfig,
    turn_rate_rad_per_m: float,
    steps: int = 600,
    step_m: float = 1.0,
) -> np.ndarray:
    """Seeded drive: truth from the wheel model with noise drawn as the sensors make it.

    Returns the NEES of every step.
    """
    x0 = np.array([0.0, 0.0, 0.3])
    est = PoseEstimator(cfg, *x0)
    truth = x0 + rng.multivariate_normal(np.zeros(3), est.P)
    nees = np.empty(steps)
    compass_var = (
        None
        if cfg.compass_two_sigma_deg is None
        else model.two_sigma_deg_to_var(cfg.compass_two_sigma_deg)
    )
    for k in range(steps):
        t = 0.1 * (k + 1)
        # True wheel distances for a path with the given curvature (switching sign every 150 m).
        sign = 1.0 if (k * step_m) // 150 % 2 == 0 else -1.0
        dth = sign * turn_rate_rad_per_m * step_m
        dl_true = step_m - 0.5 * TRACK * dth
        dr_true = step_m + 0.5 * TRACK * dth
        d, dtheta = model.odometry_increment(dl_true, dr_true, TRACK)
        truth[:] = model.motion_predict(truth[0], truth[1], truth[2], d, dtheta)
        # Measured wheel distances: slip (proportional) and quantisation noise.
        meas = []
        for dw in (dl_true, dr_true):
            sd = math.sqrt(model.wheel_noise_var(dw, cfg.wheel_quantum_m, cfg.wheel_slip_frac))
            meas.append(dw + rng.normal(0.0, sd))
        est.process(WheelOdometry(t, meas[0], meas[1]))
        if compass_var is not None and k % 2 == 0:
            z = model.wrap_angle(truth[2] + rng.normal(0.0, math.sqrt(compass_var)))
            est.process(HeadingFix(t, z))
        e = truth - est.x
        e[2] = model.wrap_angle(e[2])
        nees[k] = float(e @ np.linalg.solve(est.P, e))
    return nees


@pytest.mark.parametrize(
    ("compass", "steps"),
    # Without a compass the drive stops at 150 m (major axis ~40 m): closer to "lost" the
    # heading error makes the position distribution banana-shaped and no EKF stays consistent.
    [(None, 150), (20.0, 600)],
)
@pytest.mark.parametrize("turn", [0.0, 0.004])
def test_nees_within_95pct_bounds_in_90pct_of_steps(
    compass: float | None, steps: int, turn: float
) -> None:
    cfg = EstimatorConfig(compass_two_sigma_deg=compass)
    lo, hi = chi2.ppf([0.025, 0.975], df=3)
    inside = []
    mean_nees = []
    for run in range(50):
        rng = np.random.default_rng(1000 + run)
        nees = _drive(rng, cfg, turn, steps=steps)
        inside.append(np.mean((nees >= lo) & (nees <= hi)))
        mean_nees.append(nees.mean())
    frac = float(np.mean(inside))
    assert frac >= 0.90, f"NEES inside [{lo:.2f}, {hi:.2f}] in only {frac:.1%} of steps"
    # and on average the filter is neither optimistic nor very pessimistic
    assert 2.0 < float(np.mean(mean_nees)) < 4.0


def test_major_axis_grows_much_faster_without_compass() -> None:
    def grow(compass: float | None) -> float:
        est = PoseEstimator(EstimatorConfig(compass_two_sigma_deg=compass))
        for k in range(2000):
            est.process(WheelOdometry(0.1 * k, 1.0, 1.0))
            if compass is not None:
                est.process(HeadingFix(0.1 * k, 0.0))
        return est.major_axis_m

    without, with_compass = grow(None), grow(20.0)
    assert without > 10 * with_compass
    assert PoseEstimator(EstimatorConfig(compass_two_sigma_deg=None)).lost is False


def test_landmark_update_shrinks_ellipse() -> None:
    est = PoseEstimator(EstimatorConfig(compass_two_sigma_deg=None))
    for k in range(400):
        est.process(WheelOdometry(0.1 * k, 1.0, 1.0))
    before = est.ellipse()
    r = est.process(LandmarkFix(41.0, 7, 400.0, 0.0, 5.0))
    after = est.ellipse()
    assert r.accepted
    assert after.major_axis_m < before.major_axis_m
    assert after.semi_minor_m <= before.semi_minor_m
    assert after.major_axis_m <= 4 * 5.0 + 1e-9


def test_compass_outlier_of_180_degrees_is_rejected_and_counted() -> None:
    est = PoseEstimator(EstimatorConfig(compass_two_sigma_deg=20.0), heading_rad=0.5)
    for k in range(50):
        est.process(WheelOdometry(0.1 * k, 1.0, 1.0))
        est.process(HeadingFix(0.1 * k, 0.5))
    x_before = est.x
    r = est.process(HeadingFix(10.0, model.wrap_angle(0.5 + math.pi)))
    assert not r.accepted and r.reason == "compass_gate"
    assert r.mahalanobis_sq is not None and r.mahalanobis_sq > est.config.compass_gate_chi2
    assert est.rejections["compass_gate"] == 1
    np.testing.assert_array_equal(est.x, x_before)


def test_landmark_far_outside_ellipse_is_rejected() -> None:
    est = PoseEstimator()
    r = est.process(LandmarkFix(1.0, 1, 500.0, 500.0, 5.0))
    assert not r.accepted and r.reason == "landmark_gate"


def test_out_of_order_inputs_are_rejected_and_counted() -> None:
    est = PoseEstimator()
    assert est.process(WheelOdometry(5.0, 1.0, 1.0)).accepted
    r = est.process(WheelOdometry(3.0, 1.0, 1.0))  # older than the reorder window (1 s)
    assert not r.accepted and r.reason == "out_of_order"
    assert est.rejections["out_of_order"] == 1
    assert est.x[0] == pytest.approx(1.0)


def test_a_late_input_inside_the_reorder_window_is_applied_and_time_never_goes_back() -> None:
    """Sources race (a compass line stamped later than an odometry increment delivered after
    it): the distance must not be lost (issue 14, item 12)."""
    est = PoseEstimator()
    assert est.process(WheelOdometry(2.0, 1.0, 1.0)).accepted
    assert est.process(HeadingFix(2.3, 0.0)).accepted
    r = est.process(WheelOdometry(2.1, 1.0, 1.0))  # delivered late, 0.2 s older
    assert r.accepted and est.x[0] == pytest.approx(2.0)
    assert est.last_t_s == 2.3 and est.accepted["late_in_window"] == 1


def test_a_clock_stepped_back_is_followed_after_a_few_inputs_never_frozen() -> None:
    """Inputs from a clock that stepped back by an hour (or an estimate stamped in the future
    by a glitch): rejected at first, then the estimate follows their time base."""
    est = PoseEstimator()
    assert est.process(WheelOdometry(3600.0, 1.0, 1.0)).accepted  # the glitch
    results = [est.process(WheelOdometry(1.0 + 0.05 * k, 0.5, 0.5)) for k in range(30)]
    rejected = [r for r in results if not r.accepted]
    assert 0 < len(rejected) < REANCHOR_AFTER
    assert est.rejections["time_reanchored"] == 1
    assert est.x[0] == pytest.approx(1.0 + 0.5 * (30 - len(rejected)))  # moving again


def test_non_finite_inputs_never_corrupt_the_estimate() -> None:
    est = PoseEstimator()
    est.process(WheelOdometry(1.0, 1.0, 1.0))
    for bad in (math.nan, math.inf):
        assert not est.process(WheelOdometry(2.0, bad, 1.0)).accepted
        assert not est.process(HeadingFix(2.0, bad)).accepted
        assert not est.process(LandmarkFix(2.0, 1, bad, 0.0, 5.0)).accepted
    assert not est.process(WheelOdometry(math.nan, 1.0, 1.0)).accepted
    assert np.all(np.isfinite(est.x)) and np.all(np.isfinite(est.P))


def test_non_finite_state_resets_with_health_flag() -> None:
    est = PoseEstimator()
    est.process(WheelOdometry(1.0, 1.0, 1.0))
    # A covariance that overflows on the next predict.
    est.set_pose(1.0, 0.0, 0.0, np.diag([1.0, 1e308, 1e308]))
    r = est.process(WheelOdometry(2.0, 1.0, 1.0))
    assert not r.accepted and r.reason == "non_finite_state_reset"
    assert est.resets == 1 and not est.healthy
    assert np.all(np.isfinite(est.x)) and np.all(np.isfinite(est.P))
    assert est.lost


def test_ellipse_geometry() -> None:
    est = PoseEstimator()
    est.set_pose(0.0, 0.0, 0.0, np.diag([100.0, 25.0, 0.01]))
    e = est.ellipse()
    assert e.semi_major_m == pytest.approx(20.0)
    assert e.semi_minor_m == pytest.approx(10.0)
    assert e.major_axis_m == pytest.approx(40.0)
    assert e.orientation_rad == pytest.approx(0.0)
    est.set_pose(0.0, 0.0, 0.0, np.diag([700.0, 1.0, 0.01]))
    assert est.lost  # 2 * 2 * sqrt(700) = 105.8 m > 100 m


def _zone_drive(detect: bool, seed: int) -> tuple[PoseEstimator, list[bool], float]:
    """Straight east 1.5 km; compass 2-sigma 20 deg at 6 Hz; 35 deg bias from 500 to 800 m."""
    rng = np.random.default_rng(seed)
    est = PoseEstimator(EstimatorConfig(compass_two_sigma_deg=20.0, interference_detection=detect))
    flags: list[bool] = []
    worst = 0.0
    sigma = math.radians(10.0)
    for i in range(1, 1400):
        t = 0.1 * i
        est.process(WheelOdometry(t, 1.1, 1.1))
        if i % 2 == 0:
            in_zone = 500 <= 1.1 * i <= 800
            bias = math.radians(35.0) if in_zone else 0.0
            est.process(HeadingFix(t, bias + rng.normal(0.0, sigma)))
            flags.append(est.interference)
        worst = max(worst, abs(float(est.x[2])))
    return est, flags, worst


def test_magnetic_interference_is_detected_and_compass_trusted_again_after() -> None:
    for seed in range(5):
        est, flags, worst = _zone_drive(True, seed)
        zone = flags[230:360]  # readings well inside the zone
        assert np.mean(zone) > 0.8
        assert not any(flags[-100:])  # trusted again after the zone
        assert np.mean(flags[:220]) < 0.05  # rare false alarms before it
        assert est.rejections["magnetic_interference"] > 50
        _, _, worst_off = _zone_drive(False, seed)
        # Without detection the bias drags the heading; with it the error stays small.
        assert worst < math.radians(12.0) < worst_off


def test_interference_detector_never_trips_on_a_clean_compass() -> None:
    rng = np.random.default_rng(3)
    est = PoseEstimator(EstimatorConfig(compass_two_sigma_deg=30.0))
    heading = 0.0
    for i in range(1, 20000):
        t = 0.1 * i
        turn = 0.02 if (i // 300) % 2 else -0.02
        heading = model.wrap_angle(heading + turn)
        est.process(WheelOdometry(t, 1.1 - 0.86 * turn, 1.1 + 0.86 * turn))
        if i % 2 == 0:
            est.process(HeadingFix(t, model.wrap_angle(heading + rng.normal(0, math.radians(15)))))
    assert est.rejections["magnetic_interference"] < 0.01 * est.accepted["HeadingFix"]


def test_an_absurd_landmark_sigma_is_rejected_not_squared_into_overflow() -> None:
    """A damaged landmark row (sigma 1e200, a coordinate 1e39) must not reach the math
    (issue 14, item 4)."""
    est = PoseEstimator()
    est.process(WheelOdometry(1.0, 1.0, 1.0))
    before = est.P.copy()
    for fix in (
        LandmarkFix(2.0, 1, 1.0, 0.0, 1e200),
        LandmarkFix(2.0, 1, 1.0, 0.0, 1e-9),
        LandmarkFix(2.0, 1, 1e39, 0.0, 5.0),
    ):
        r = est.process(fix)
        assert not r.accepted and r.reason == "implausible_landmark"
    assert np.array_equal(est.P, before) and est.healthy


def test_the_estimator_owns_its_covariance_changes() -> None:
    """Issue 25, change 5: what the pipeline used to write into P (a forgotten heading, a
    restart's widening, a checkpoint's time order) are the estimator's own methods."""
    est = PoseEstimator(EstimatorConfig(), x_m=3.0, y_m=4.0, heading_rad=0.5)
    est.process(WheelOdometry(1.0, 1.0, 1.1))
    x0 = est.x.copy()
    est.forget_heading()
    P = est.P
    assert P[2, 2] == pytest.approx(math.pi**2) and P[0, 2] == P[1, 2] == 0.0
    assert est.x[2] == 0.0 and est.x[0] == x0[0] and est.x[1] == x0[1]
    before = est.P.copy()
    est.inflate_position(20.0)  # 2-sigma 20 m: 100 m^2 on each axis
    assert est.P[0, 0] - before[0, 0] == pytest.approx(100.0)
    assert est.P[1, 1] - before[1, 1] == pytest.approx(100.0)
    for bad in (math.nan, math.inf, -5.0, 0.0):
        est.inflate_position(bad)
    assert est.P[0, 0] - before[0, 0] == pytest.approx(100.0)
    other = PoseEstimator(EstimatorConfig())
    other.restore(est.x, est.P, 1.0)
    assert np.array_equal(other.x, est.x) and np.array_equal(other.P, est.P)
    assert not other.process(WheelOdometry(-5.0, 1.0, 1.0)).accepted  # the time order survived


def test_the_car_model_adds_the_second_order_heading_term_along_the_lever() -> None:
    """A heading error delta turns the position lever r (|r| sigma^2 = |P_xy,theta|) and also
    moves the position -r delta^2 / 2 along it, which a linearised filter leaves out; the car
    model adds its second moment, 3/4 |P_xy,theta|^2, along the lever (docs/estimation.md).
    Checked against a Monte Carlo of the heading error on a straight drive north."""
    from dataclasses import replace

    from guidance.core.localize.car_model import car_model

    # the heading error all from the start (10 degrees), none from the wheels on the way
    base = car_model(
        EstimatorConfig(compass_two_sigma_deg=None, track_m=TRACK, initial_heading_sigma_deg=10.0),
        calibrated=False, diff_sigma=1e-9, diff_walk_var_per_m=0.0, wheel_walk_var_m2_per_m=1e-12,
    )  # fmt: skip
    cfgs = {"paper-like": replace(base, heading_second_order=0.0), "car": base}
    ests = {k: PoseEstimator(c, 0.0, 0.0, math.pi / 2) for k, c in cfgs.items()}
    for k in range(1000):
        for est in ests.values():
            est.process(WheelOdometry(0.1 * (k + 1), 1.0, 1.0))
    lin, car = ests["paper-like"].P, ests["car"].P
    c = car[0:2, 2]
    assert car[0:2, 2] == pytest.approx(lin[0:2, 2])  # the linear part is the same
    added = car[:2, :2] - lin[:2, :2]
    # driving north: the lever is north (along the road), dp/dtheta east (across it)
    assert added[1, 1] == pytest.approx(0.75 * float(c @ c), rel=0.02)
    assert abs(added[0, 0]) < 1e-6 * added[1, 1] and abs(added[0, 1]) < 1e-6 * added[1, 1]
    # the truth: 1 km north turned by a heading error of N(0, sigma): the along-road miss
    sigma = math.sqrt(float(car[2, 2]))
    delta = np.random.default_rng(5).normal(0.0, sigma, 200_000)
    miss = 1000.0 * (np.cos(delta) - 1.0)  # about the estimate, which is not corrected
    along = float(np.mean(miss**2))
    assert added[1, 1] == pytest.approx(along, rel=0.15)


def test_the_camber_process_adds_its_heading_walk_and_nothing_when_off() -> None:
    """``camber_diff_sigma`` (a bounded alternative to the difference's walk): after a drive of
    D metres its heading variance is ``model.camber_heading_var(D)`` more than without it (the
    heading is the only state it feeds), and 0 leaves every state as it was."""
    from dataclasses import replace

    from guidance.core.localize.car_model import car_model

    base = car_model(
        EstimatorConfig(track_m=1.6, compass_two_sigma_deg=None), calibrated=False,
        camber_diff_sigma=0.0,
    )  # fmt: skip
    on = replace(base, camber_diff_sigma=2e-4, camber_length_m=300.0)
    cfgs = (base, on, replace(on, camber_diff_sigma=0.0))
    ests = [PoseEstimator(c, 0.0, 0.0, 0.3) for c in cfgs]
    for i in range(1, 801):  # 800 m, a gentle curve
        for e in ests:
            e.process(WheelOdometry(0.1 * i, 1.0, 1.002))
    p0, p1, p2 = (e.P for e in ests)
    extra = model.camber_heading_var(800.0 * 1.001, 2e-4, 300.0, 1.6)
    assert p1[2, 2] - p0[2, 2] == pytest.approx(extra, rel=1e-6)
    assert np.array_equal(p0, p2)


def test_a_relocalised_fix_while_lost_resets_the_position_and_keeps_the_heading() -> None:
    """Issue 36: a whole-database find while lost, far outside the estimate's gate, restarts
    the position at the place with the fix's sigma (uncorrelated with every other state); the
    heading and its variance are kept. The same fix on a car that is not lost is gated as any
    other, so a wrong find cannot move a good estimate."""
    from guidance.core.messages import LandmarkFix as Fix
    from guidance.core.stages import RELOCALISED

    est = PoseEstimator(car_model(EstimatorConfig(), calibrated=False), 0.0, 0.0, 0.3)
    P = est.P
    P[0, 0] = P[1, 1] = 400.0**2  # lost: a 1.6 km ellipse
    P[0, 2] = P[2, 0] = 50.0
    est.set_state(est.x, P)
    assert est.lost
    heading, heading_var = est.heading_rad, est.P[2, 2]
    r = est.process(Fix(1.0, 4, 3000.0, -2000.0, 20.0, relocalised=True))
    assert r.accepted and r.reason == RELOCALISED
    x, P = est.x, est.P
    assert (x[0], x[1]) == (3000.0, -2000.0) and not est.lost
    assert P[0, 0] == P[1, 1] == 400.0 and P[0, 1] == 0.0
    assert np.all(P[:2, 2:] == 0.0) and np.all(P[2:, :2] == 0.0)
    assert est.heading_rad == heading and P[2, 2] == heading_var
    # not lost now: the same far find is refused by the gate, an ordinary fix
    far = est.process(Fix(2.0, 5, 9000.0, 9000.0, 20.0, relocalised=True))
    assert not far.accepted and far.reason == "landmark_gate"
    near = est.process(Fix(3.0, 4, 3005.0, -2003.0, 20.0, relocalised=True))
    assert near.accepted and near.reason is None  # inside the gate: an update
