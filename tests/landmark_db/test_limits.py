"""The landmark file's limits (``landmark_db.limits``) agree with what the estimator accepts
(``guidance.core.localize.gates``): landmark_db may not import the estimator, so the two
definitions are checked here."""

from __future__ import annotations

import numpy as np

from guidance.core.localize import gates
from landmark_db import limits
from landmark_db.recognise import RecogniserConfig, fix_sigma_m


def test_every_fix_a_valid_landmark_can_make_is_one_the_estimator_accepts() -> None:
    assert limits.MAX_COORDINATE_M <= gates.MAX_COORDINATE_M
    r = RecogniserConfig().sighting_range_m
    for sigma in np.linspace(limits.MIN_POSITION_SIGMA_M, limits.MAX_POSITION_SIGMA_M, 101):
        s = fix_sigma_m(r, float(sigma))
        assert gates.MIN_LANDMARK_SIGMA_M <= s <= gates.MAX_LANDMARK_SIGMA_M
    # the sighting ranges the docs promise (up to 1.7 km) keep the largest sigma inside too
    assert fix_sigma_m(1700.0, limits.MAX_POSITION_SIGMA_M) <= gates.MAX_LANDMARK_SIGMA_M


def test_the_position_limit_keeps_x_y_and_lat_lon_in_agreement() -> None:
    from guidance.core.geo import Origin

    for lat in (0.0, 48.85, 70.0):
        o = Origin(lat, 2.35)
        m = limits.MAX_COORDINATE_M
        for x, y in ((m, 0.0), (0.0, -m), (m, m), (-m, m)):
            ex, ey = o.to_local(*o.to_geodetic(x, y))
            assert limits.agreement_problem(ex - x, ey - y) is None, (lat, x, y)
