"""Gyro cars in the population (issue 38, items 2 and 5): the bars of hal_sim/bars.py on cars
drawn from the filter's own priors and on heavier-tailed ones, from a parked start with stops
at intersections (benchmarks/honest_bars.py runs the same over more cars and 20 minutes)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hal_sim import bars
from hal_sim.car_errors import draw_car, draw_gyro, draw_matched_car, draw_matched_gyro, with_camber
from hal_sim.gyro_cars import GyroErrors, GyroSim
from hal_sim.population import GYRO_PROFILE, drive_car, population

CARS = 30


def _cars(matched: bool) -> list:
    # draw seed 1, the population figures' convention (benchmarks/honest_bars.py's first cars)
    rng, camber_rng, gyro_rng = (np.random.default_rng(s) for s in (1, [1, 8], [1, 9]))
    out = []
    for _ in range(CARS):
        if matched:
            car = draw_matched_gyro(with_camber(draw_matched_car(rng), camber_rng), gyro_rng)
        else:
            car = draw_gyro(draw_car(rng), gyro_rng)
        out.append(car)
    return out


@pytest.mark.parametrize("both", [False, True], ids=["gyro", "both"])
def test_gyro_cars_meet_the_bars_an_honest_filter_can_meet(both: bool) -> None:
    """Gyro cars, and the same cars whose filter weighs their wheels too (``both``)."""
    runs = {}
    for matched in (True, False):
        results = [drive_car(20_000 + i, car, compass=False, distance_m=1500.0, stops=True,
                             both=both)
                   for i, car in enumerate(_cars(matched))]  # fmt: skip
        assert all(r.errors.gyro is not None for r in results)
        assert min(r.duration_s for r in results) > 150.0  # stops and a parked start
        runs[matched] = population(results)
    m, h = runs[True], runs[False]
    assert bars.matched_bars(m.cars, m.mean_nees, m.cars_below_half).ok, m.summary()
    verdict = bars.heavier_bars(h.cars, h.inside, h.cars_below_half, m.cars_below_half, m.cars)
    assert verdict.ok, verdict.lines


def test_the_simulated_gyro_reads_its_bias_and_scale() -> None:
    """The sensor the population drives: a standing car's readings average to its bias, a
    turn reads the true rate over (1 + scale)."""
    rng = np.random.default_rng(2)
    sim = GyroSim(GyroErrors(0.2, 0.05, walk_deg2_per_s3=0.0), rng)
    standing = [sim.reading(0.0, 0.1) for _ in range(20_000)]
    assert abs(math.degrees(float(np.mean(standing))) - 0.2) < 0.005
    turning = [sim.reading(0.05, 0.1) for _ in range(20_000)]
    rate = float(np.mean(turning)) - math.radians(0.2)
    assert abs(rate - 0.5 / 1.05) < 0.002


def test_a_gyro_cars_filter_sees_its_yaw_rate_as_the_dbc_steps_it() -> None:
    """A gyro car's reading reaches its filter as its DBC's frame decoded (``car_inputs``): a
    sensor biased by 0.15 deg/s (no walk), standing at lights, teaches its bias to within the
    filter's sigma on the population's DBC (0.0002 rad/s steps), on GM's (0.0625 deg/s) and on
    the coarsest any profile sends, Toyota's 0.244 deg/s, whose zero is no step (the reading
    noise dithers it): the truth stays inside the ellipse on all three."""
    from dataclasses import replace

    car = replace(draw_car(np.random.default_rng(3)), gyro=GyroErrors(0.15, 0.0, 0.0))
    for profile in (GYRO_PROFILE, "gm_global_a", "toyota"):
        res = drive_car(20_000, car, compass=False, distance_m=1500.0, stops=True,
                        profile=profile)  # fmt: skip
        assert res.learned is not None, profile
        bias, sigma = res.learned.gyro_bias_deg_s, res.learned.gyro_bias_sigma_deg_s
        assert bias is not None and sigma is not None
        assert abs(bias - 0.15) < 3.0 * sigma < 0.1, profile
        assert res.inside == 1.0, profile
