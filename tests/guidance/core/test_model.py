"""The shared math (guidance.core.model): compass conventions, chi-square constants, and the
in-place Joseph updates checked against filterpy."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import chi2

from guidance.core import model
from guidance.core.localize.estimator import EstimatorConfig, PoseEstimator
from guidance.core.messages import HeadingFix, LandmarkFix, WheelOdometry


@pytest.mark.parametrize("deg", [0.0, 90.0, 180.0, 270.0, 359.9])
@pytest.mark.parametrize("decl", [-15.0, 0.0, 15.0])
def test_compass_degrees_round_trip(deg: float, decl: float) -> None:
    theta = model.compass_to_heading(deg, decl)
    assert -math.pi < theta <= math.pi
    back = model.heading_to_compass(theta, decl)
    assert abs(model.wrap_angle(math.radians(back - deg))) < 1e-9


def test_compass_convention() -> None:
    # magnetic north with +10 deg (east) declination is true bearing 10 deg: 80 deg CCW from east
    assert model.compass_to_heading(0.0, 10.0) == pytest.approx(math.radians(80.0))
    assert model.compass_to_heading(90.0, 0.0) == pytest.approx(0.0, abs=1e-12)
    assert model.compass_to_heading(180.0, 0.0) == pytest.approx(-math.pi / 2)


def test_chi2_constants_match_their_documented_probabilities() -> None:
    assert chi2.cdf(model.CHI2_2D_2SIGMA, 2) == pytest.approx(1 - math.exp(-2))  # 86.5 %
    assert chi2.cdf(model.CHI2_2D_P99, 2) == pytest.approx(0.99)
    assert chi2.cdf(model.CHI2_1D_P999, 1) == pytest.approx(0.999)


def test_model_updates_match_filterpy() -> None:
    """The engine's in-place updates (core.model) and filterpy's give the same covariance."""
    est = PoseEstimator(EstimatorConfig(compass_two_sigma_deg=20.0))
    for k in range(100):
        est.process(WheelOdometry(0.1 * k, 1.0, 1.01))
    x, P = est.x, est.P
    var = model.two_sigma_deg_to_var(20.0)
    y, S = model.heading_innovation(x, P, 0.2, var)
    model.heading_update(x, P, y, S, var)
    est.process(HeadingFix(10.0, 0.2))
    np.testing.assert_allclose(est.P, P, rtol=0, atol=1e-12)
    np.testing.assert_allclose(est.x, x, rtol=0, atol=1e-12)
    # and a landmark fix
    inn = model.position_innovation(x, P, 95.0, 25.0, 25.0)
    model.position_update(x, P, *inn, 25.0, np.empty((3, 3)))
    assert est.process(LandmarkFix(11.0, 1, 95.0, 25.0, 5.0)).accepted
    np.testing.assert_allclose(est.P, P, rtol=0, atol=1e-12)
    np.testing.assert_allclose(est.x, x, rtol=0, atol=1e-12)


def _car_pose_after(x: np.ndarray, dl: float, dr: float, track: float) -> np.ndarray:
    """The car model's predicted pose from raw wheel increments (as ``PoseEstimator``)."""
    cl, cr = model.corrected_wheels(dl, dr, x[model.STATE_SCALE], x[model.STATE_DIFF])
    d, dth = model.odometry_increment(cl, cr, model.effective_track(track, x[model.STATE_TURN]))
    return np.array(model.motion_predict(x[0], x[1], x[2], d, dth))


@pytest.mark.parametrize(("dl", "dr"), [(1.0, 1.0), (0.9, 1.2), (2.0, 1.1), (-0.4, 0.4)])
def test_the_car_models_jacobian_is_the_derivative_of_its_prediction(dl: float, dr: float) -> None:
    """Every column of the car model's state Jacobian (pose, wheel scale, left/right, turn
    scale) against a central difference of the prediction itself."""
    track = 1.6
    x = np.zeros(model.N_STATE_CAR)
    x[:3] = 10.0, -5.0, 0.7
    x[model.STATE_SCALE], x[model.STATE_DIFF], x[model.STATE_TURN] = 0.015, 4e-4, -0.03
    cl, cr = model.corrected_wheels(dl, dr, x[model.STATE_SCALE], x[model.STATE_DIFF])
    tr = model.effective_track(track, x[model.STATE_TURN])
    F3, G = np.empty((3, 3)), np.empty((3, 2))
    model.motion_jacobians(x[2], cl, cr, tr, F3, G)
    F = np.eye(model.N_STATE_CAR)
    F[:3, :3] = F3
    model.scale_jacobian(G, dl, dr, F)
    model.turn_jacobian(cl, cr, track, F)
    for j in range(model.N_STATE_CAR):
        h = 1e-6 if j < 3 else 1e-7
        xp, xm = x.copy(), x.copy()
        xp[j] += h
        xm[j] -= h
        num = (_car_pose_after(xp, dl, dr, track) - _car_pose_after(xm, dl, dr, track)) / (2 * h)
        assert F[:3, j] == pytest.approx(num, rel=1e-5, abs=1e-7), j


def test_the_camber_heading_walk_is_the_integrated_gauss_markov_difference() -> None:
    """``model.camber_heading_var``: a left/right difference that changes from street to
    street (stationary 1-sigma s, correlation length L) turns the heading by its integral over
    the distance over the track. A Monte Carlo of that process (exact Gauss-Markov steps)
    agrees with the integral's closed form, ``2 s^2 L^2 (d/L - 1 + e^(-d/L)) / track^2``; the
    walk is never narrower than it, and within 6 % of it over 20 L."""
    s, length, track = 2e-4, 250.0, 1.6
    rng = np.random.default_rng(5)
    n, step = 8000, 5.0
    a = math.exp(-step / length)
    g = s * rng.standard_normal(n)
    heading = np.zeros(n)
    checked = 0
    for i in range(1, int(20 * length / step) + 1):
        g_next = a * g + s * math.sqrt(1.0 - a * a) * rng.standard_normal(n)
        heading += 0.5 * (g + g_next) * step / track
        g = g_next
        d = i * step
        if d in (50.0, 250.0, 1000.0, 5000.0):
            u = d / length
            exact = 2.0 * s * s * length * length * (u - 1.0 + math.exp(-u)) / track**2
            assert float(np.var(heading)) == pytest.approx(exact, rel=0.08), d
            walk = model.camber_heading_var(d, s, length, track)
            assert walk >= exact, (d, walk, exact)
            checked += 1
    assert checked == 4
    assert walk == pytest.approx(exact, rel=0.06)
    assert model.camber_heading_var(-100.0, s, length, track) == model.camber_heading_var(
        100.0, s, length, track
    )
