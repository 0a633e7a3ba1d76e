"""The closed-form bars (hal_sim/bars.py) against a Monte Carlo of the model they solve: cars
whose whitened error is a persistent draw plus independent samples."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from hal_sim import bars


@pytest.mark.parametrize("rho", [0.3, 0.6, 0.85, 1.0])
def test_the_fraction_below_half_matches_a_monte_carlo_of_persistent_and_white_errors(
    rho: float,
) -> None:
    rng = np.random.default_rng(11)
    cars, samples = 40_000, 201
    z = rng.standard_normal((cars, 1, 2))
    w = rng.standard_normal((cars, samples, 2))
    e = math.sqrt(rho) * z + math.sqrt(1.0 - rho) * w
    inside = np.mean(np.sum(e * e, axis=2) <= 4.0, axis=1)
    measured = float(np.mean(inside < 0.5))
    expected = bars.below_half_fraction(rho)
    se = math.sqrt(expected * (1 - expected) / cars)
    # the closed form is the many-sample limit: 201 samples leave a small finite-sample spread
    assert measured == pytest.approx(expected, abs=4 * se + 0.004)


def test_the_limits_are_zero_and_e_to_the_minus_two() -> None:
    assert bars.below_half_fraction(1.0) == pytest.approx(math.exp(-2.0))
    assert bars.below_half_fraction(0.0) == 0.0
    fractions = [bars.below_half_fraction(r) for r in np.linspace(0.0, 1.0, 21)]
    assert all(b >= a for a, b in itertools.pairwise(fractions))
    with pytest.raises(ValueError):
        bars.below_half_fraction(1.2)


def test_the_bars_catch_an_overconfident_and_a_conservative_filter() -> None:
    lo, hi = bars.nees_band(1000)
    assert lo < 2.0 < hi
    assert bars.matched_bars(1000, 2.0, 0.08).ok
    assert not bars.matched_bars(1000, 2.6, 0.08).ok  # overconfident
    assert not bars.matched_bars(1000, 1.4, 0.03).ok  # conservative: NEES below the band
    assert not bars.matched_bars(1000, 2.0, 0.20).ok  # more tail cars than any mix allows
    assert bars.heavier_bars(1000, 0.92, 0.05, 0.08, 1000).ok
    assert not bars.heavier_bars(1000, 0.75, 0.05, 0.08, 1000).ok
    assert not bars.heavier_bars(1000, 0.92, 0.12, 0.08, 1000).ok


def test_a_matched_linearised_filter_is_honest_while_the_heading_is_tight_wide_once_not() -> None:
    """The car model's filter matched exactly to cars whose left/right difference turns their
    heading: honest at a few degrees of heading spread, conservative (mean NEES under the
    100-car band, more than 90 % inside) at the 76 degrees the difference's prior reaches over
    a 20-minute drive; the saturation is across the road, the second-order term along it."""
    from guidance.core.localize.car_model import CAR_MODEL

    order, scale = CAR_MODEL["heading_second_order"], CAR_MODEL["scale_sigma"]
    tight = bars.linearised_heading(5.0, order, scale, cars=8000)
    assert tight.mean_nees == pytest.approx(2.0, abs=0.1)
    assert tight.inside == pytest.approx(1 - math.exp(-2.0), abs=0.01)
    assert tight.across_ratio == pytest.approx(1.0, abs=0.03)
    wide = bars.linearised_heading(76.0, order, scale, cars=8000)
    assert wide.mean_nees < bars.nees_band(100)[0] and wide.inside > 0.9
    # across: a sine saturates, E[sin^2] = (1 - e^(-2 S^2)) / 2 against the linear S^2
    assert wide.across_ratio < 0.6
    # a filter without the second-order term would be overconfident along the road instead
    bare = bars.linearised_heading(76.0, 0.0, scale, cars=8000)
    assert bare.along_ratio > 10.0


def test_the_inside_interval_is_over_cars_and_covers_a_known_population() -> None:
    """Cars whose inside fractions are drawn around 93 %: the interval over 60 of them covers
    the population's mean in about 95 % of draws, and it is printed with the verdict."""
    rng = np.random.default_rng(5)
    truth = float(np.mean(np.clip(rng.normal(0.93, 0.08, 1_000_000), 0.0, 1.0)))
    covered = 0
    for _ in range(200):
        per_car = np.clip(rng.normal(0.93, 0.08, 60), 0.0, 1.0)
        lo, hi = bars.inside_interval(per_car, seed=int(rng.integers(1 << 30)))
        covered += lo <= truth <= hi
    assert 0.89 <= covered / 200 <= 0.99
    verdict = bars.heavier_bars(60, 0.953, 0.017, 0.067, 60, per_car_inside=[0.9, 1.0] * 30)
    assert not verdict.ok and "interval over cars" in verdict.lines[0]
