"""Issue 21, item 5: Fig. 3's question for a population of real cars (hal_sim/car_range.py):
the distance driven before "lost", uncalibrated and calibrated, through the car's real pipeline."""

from __future__ import annotations

import numpy as np

from hal_sim.car_range import CONDITIONS, median_axis_curve, range_study


def test_calibrated_cars_go_farther_than_uncalibrated_ones() -> None:
    # Not the benchmark's draws. 24 cars, not 6: the claim is about a population, and six
    # of them can hold one car that drove 0.85 km uncalibrated and 0.63 km calibrated (world
    # seed 20010, since the world's random stream changed in issue 26); over 24, calibrated
    # odometry-only cars go 0.042 +- 0.023 km farther, paired, 75 % of them.
    figs = {f.label: f for f in range_study(24, 20261202, 20_000.0)}
    assert list(figs) == [c[0] for c in CONDITIONS]
    for sensors in ("odometry only", "compass"):
        unc, cal = (f for label, f in figs.items() if label.startswith(sensors))
        assert cal.mean_km > unc.mean_km, (unc.row(), cal.row())
        # the same cars on the same routes: most of them get farther once calibrated
        farther = np.mean(np.asarray(cal.lost_km) > np.asarray(unc.lost_km))
        assert farther >= 0.5, (unc.lost_km, cal.lost_km)
    for f in figs.values():
        assert all(r.lost_at_m is not None for r in f.results)  # nobody reaches 20 km
        assert all(0.0 < e < 100.0 for e in f.true_error_at_lost_m)
        # the curve crosses the lost line where the cars are lost
        d = np.array([0.1, 0.5 * min(f.lost_km)])
        assert np.all(median_axis_curve(f.results, d) < 100.0)
