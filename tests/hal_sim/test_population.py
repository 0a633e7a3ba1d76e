"""Issue 21: the estimator's honesty over a population of simulated cars (hal_sim/population.py),
each with its own persistent errors, heavier-tailed than the filter's priors, driven through the
car's real pipeline with the car model as an uncalibrated car is configured."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import chi2

from guidance.core.model import CHI2_2D_2SIGMA
from hal_sim.car_errors import draw_car
from hal_sim.population import CarResult, drive_car, persistent_limit, population


@pytest.mark.parametrize(("compass", "cars"), [(False, 200), (True, 100)])
def test_an_uncalibrated_population_is_honest(compass: bool, cars: int) -> None:
    rng = np.random.default_rng(20261201)  # not the benchmark's draws
    results = [drive_car(5000 + i, draw_car(rng), compass=compass) for i in range(cars)]
    fig = population(results)
    assert 0.80 <= fig.inside <= 0.95, fig.summary()  # honest: 86.5 %
    # The bar is 5 %; measured 4.5 % (odometry only, 94.4 % inside) and 3.0 % (compass,
    # 100 cars) on these draws with the street-to-street change bounded (4.5 % and 6.0 % with the
    # left/right walk; 7.0 % and 5.0 % before the turn scale state; 8-10.5 %
    # and 4-5 % before the second-order heading term): the cars left are in
    # the tail of the left/right difference (2-4 sigma of its prior), overconfident across the
    # road. With the priors before issue 21 (1 % scale, a 1 m start): 71 % inside and 24.5 %
    # of cars below 50 %.
    assert fig.cars_below_half <= 0.10, fig.summary()
    assert fig.median_axis_ratio <= 4.0, fig.summary()
    assert 0.5 <= fig.along_nees <= 1.6 and 0.5 <= fig.across_nees <= 1.6, fig.summary()
    assert all(r.driven_m >= 1500.0 for r in results)


def test_a_perfectly_matched_filter_has_few_cars_below_half_inside() -> None:
    """The yardstick for "cars below 50 % inside": cars whose wheel errors are drawn from the
    filter's own Gaussian priors. Their errors are persistent, so a car whose draw lies beyond
    about 2 sigma is outside for most of its drive: 5.5 % of them are below 50 % (91.1 %
    inside, mean NEES 1.61; 89.8 % with the left/right walk). Without the second-order heading
    term (``heading_second_order = 0``) the same cars were 11.5 % below 50 % with a mean NEES of
    2.10: the linearised ellipse, thin along the road, missed the along-road part of a heading
    error."""
    from hal_sim.car_errors import draw_matched_car

    rng = np.random.default_rng(20261203)
    fig = population([drive_car(8000 + i, draw_matched_car(rng), compass=False)
                      for i in range(200)])  # fmt: skip
    assert 0.84 <= fig.inside <= 0.92, fig.summary()
    assert 0.7 <= fig.mean_nees / 2.0 <= 1.15, fig.summary()
    assert fig.cars_below_half <= 0.08, fig.summary()


def test_a_car_with_the_filters_own_errors_is_inside_most_of_the_time() -> None:
    """The population's machinery: a car whose errors are exactly the prior's typical ones."""
    from dataclasses import replace

    car = replace(draw_car(np.random.default_rng(1)), scale=0.01, diff=0.0001, hard_iron_ratio=0.0)
    res = drive_car(7, car, compass=False)
    assert res.inside >= 0.8 and len(res.nees) > 100
    assert res.final_error_m > 0.0


def test_a_second_drive_from_learned_parameters_has_a_smaller_ellipse_and_is_still_honest() -> None:
    """Issue 21, item 3: each car learns on a drive with landmark fixes; its next drive (another
    route, no landmarks, a day later) starts from what it learned, widened for the day."""
    from guidance.core.localize.car_model import car_model
    from guidance.core.localize.estimator import EstimatorConfig
    from hal_sim.population import learn_then_drive

    cfg = car_model(EstimatorConfig(compass_two_sigma_deg=None), calibrated=False)
    rng = np.random.default_rng(424242)
    runs = [learn_then_drive(6000 + i, draw_car(rng)) for i in range(40)]
    taught = 0
    for r in runs:
        assert r.first.learned is not None
        taught += r.first.learned.scale_sigma < 0.5 * cfg.scale_sigma  # the scale was learned
    # most routes pass landmarks; with the turn scale a state, the fixes' information is
    # shared with it (a heading error before a corner is an along-road error after it): 27 of
    # these 40 cars halve their scale's sigma, 31 without the state
    assert taught >= 24
    with_learned = population([r.from_learned for r in runs])
    assert with_learned.inside >= 0.80, with_learned.summary()
    axis_learned = np.median([r.from_learned.final_major_axis_m for r in runs])
    axis_priors = np.median([r.from_priors.final_major_axis_m for r in runs])
    # the left/right difference learned is kept (no walk, docs/estimation.md): 214 m against
    # 406 m on these cars (0.53; with the walk the gain was about a tenth)
    assert axis_learned < 0.75 * axis_priors, (axis_learned, axis_priors)


def _persistent_cars(rng: np.random.Generator, n: int, var_scale: float) -> list[CarResult]:
    """Cars whose error is one 2-D Gaussian draw held for the whole drive, against a filter
    whose covariance is ``1 / var_scale`` times the true one."""
    cars = []
    for _ in range(n):
        r = CarResult(draw_car(rng), compass=False)
        r.nees = [float(rng.normal() ** 2 + rng.normal() ** 2) * var_scale] * 50
        r.along2 = r.across2 = r.axis_ratio = [1.0]
        cars.append(r)
    return cars


def test_the_nees_band_counts_cars_and_catches_a_conservative_filter() -> None:
    """The mean NEES band is the chi-square band of N cars' persistent draws (2 dof each), not
    of their correlated samples: an honest filter's mean lies inside it in about 95 % of
    populations, a filter whose ellipse is a quarter too wide in variance lies below it."""
    rng = np.random.default_rng(5)
    honest = [population(_persistent_cars(rng, 400, 1.0)) for _ in range(40)]
    lo, hi = honest[0].nees_band
    assert 1.75 < lo < 1.85 and 2.15 < hi < 2.25  # chi2(800) / 400
    assert sum(lo <= f.mean_nees <= hi for f in honest) >= 34  # 95 % of 40, with some slack
    wide = population(_persistent_cars(rng, 400, 0.75))
    assert wide.mean_nees < wide.nees_band[0]
    # The cars below 50 % of a persistent honest population: those outside the 2-sigma
    # ellipse, 13.5 % (chi-square, 2 dof, beyond 4), within its Wilson interval.
    f = honest[0]
    ci = f.below_half_interval
    assert ci is not None and ci[0] <= f.cars_below_half <= ci[1]
    assert ci[0] <= 0.135 <= ci[1], (f.cars_below_half, ci)


def test_a_left_right_difference_that_walks_changes_the_cars_heading_error() -> None:
    """``CarErrors.diff_walk_var_per_m`` (benchmarks/estimator_population.py --diff-walk): the
    car's left/right difference wanders along the road; 0 keeps it constant (the default)."""
    from dataclasses import replace

    car = replace(draw_car(np.random.default_rng(2)), diff=0.0, scale=0.0)
    still = drive_car(11, car, compass=False)
    walking = drive_car(11, replace(car, diff_walk_var_per_m=1e-8), compass=False)
    assert walking.final_error_m > 2.0 * still.final_error_m, (still.final_error_m,
                                                                walking.final_error_m)  # fmt: skip


def test_the_persistent_limit_matches_its_closed_form_and_a_heavier_tail_is_no_easier() -> None:
    """Gaussian persistent draws: e^-2 of the cars outside a matched 2-sigma ellipse; 5 % only
    with chi2_2(0.95) / 4 of the variance, and a mean NEES of 2 over that (below any band for
    more than a few cars). A t4 tail at the same variance: still more than 10 % outside."""
    g = persistent_limit(np.random.default_rng(3), 400_000)
    assert g.outside_matched == pytest.approx(math.exp(-2.0), abs=0.003)
    k = chi2.ppf(0.95, 2) / CHI2_2D_2SIGMA
    assert g.inflation_for == pytest.approx(k, rel=0.02)
    assert g.nees_then == pytest.approx(2.0 / k, rel=0.02)
    t4 = persistent_limit(np.random.default_rng(4), 400_000, df=4.0)
    assert 0.10 < t4.outside_matched < 0.125
    assert t4.nees_then < g.nees_then


def test_a_compass_brings_the_estimate_nearer_the_truth_and_a_strong_hard_iron_stays_honest() -> (
    None
):
    """The estimate against the truth, not only the ellipse: each car drives 3 km of one route
    twice, with its uncalibrated compass and without. Measured on 300 other cars
    (``benchmarks/estimator_population.py --compass --vs-odometry --distance 3000``): the
    compass halves the median final error and is nearer the truth for most cars. Cars whose
    hard-iron field is 0.6-0.9 of the earth's (``--hard-iron 0.6,0.9``) have a deviation curve
    no bias walk follows: the compass helps them less, and the filter must stay honest."""
    rng = np.random.default_rng(20261204)
    cars = [draw_car(rng) for _ in range(24)]
    with_compass = [drive_car(9000 + i, c, compass=True, distance_m=3000.0)
                    for i, c in enumerate(cars)]  # fmt: skip
    without = [drive_car(9000 + i, c, compass=False, distance_m=3000.0)
               for i, c in enumerate(cars)]  # fmt: skip
    a = np.array([r.final_error_m for r in with_compass])
    b = np.array([r.final_error_m for r in without])
    assert np.median(a / b) <= 0.8, (np.median(a), np.median(b))
    assert np.mean(a < b) >= 0.6, np.mean(a < b)
    assert population(with_compass).inside >= 0.80
    strong = [drive_car(9500 + i, draw_car(rng, hard_iron=(0.6, 0.9)), compass=True,
                        distance_m=3000.0) for i in range(16)]  # fmt: skip
    assert all(r.errors.hard_iron_ratio >= 0.6 for r in strong)
    fig = population(strong)
    assert fig.inside >= 0.80, fig.summary()


def test_a_left_right_difference_that_changes_from_street_to_street_is_drawn_and_driven() -> None:
    """``car_errors.with_camber`` (benchmarks/estimator_population.py --camber): each car's own
    Gauss-Markov process, its sigma within ``CAMBER_SIGMA`` (rms near the 0.016 % of the
    physical range's middle) and its length 150-400 m, from a stream of its own (the car's other
    draws unchanged); driven, it turns the heading of a car whose constant difference is 0."""
    from dataclasses import replace

    from hal_sim.car_errors import CAMBER_SIGMA, with_camber

    rng = np.random.default_rng(4)
    cars = [with_camber(draw_car(np.random.default_rng(2)), rng) for _ in range(2000)]
    sig = np.array([c.camber_sigma for c in cars])
    assert CAMBER_SIGMA[0] <= sig.min() and sig.max() <= CAMBER_SIGMA[1]
    assert math.sqrt(float(np.mean(sig**2))) == pytest.approx(1.56e-4, rel=0.05)
    assert all(150.0 <= c.camber_length_m <= 400.0 for c in cars)
    assert replace(cars[0], camber_sigma=0.0, camber_length_m=250.0) == draw_car(
        np.random.default_rng(2)
    )
    car = replace(draw_car(np.random.default_rng(2)), diff=0.0, scale=0.0)
    still = drive_car(11, car, compass=False)
    changing = drive_car(11, replace(car, camber_sigma=3e-3, camber_length_m=300.0), compass=False)
    assert changing.final_error_m > 2.0 * still.final_error_m, (still.final_error_m,
                                                                changing.final_error_m)  # fmt: skip
