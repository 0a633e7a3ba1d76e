"""Declination from the WMM (pygeomag); compass readings to filter heading (guidance.core.model)."""

from __future__ import annotations

import datetime as dt
import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from guidance.app.magnetic import declination_deg, wmm_model_for
from guidance.core.localize.compass_cal import compass_heading_to_theta
from guidance.core.messages import CompassHeading
from guidance.core.model import heading_to_compass, wrap_angle
from guidance.errors import UserError


def test_wmm2025_is_used_for_current_dates() -> None:
    assert wmm_model_for(dt.date(2025, 6, 1)) == "WMM-2025"
    assert wmm_model_for(dt.date(2029, 12, 31)) == "WMM-2025"
    assert wmm_model_for(dt.date(2020, 2, 3)) == "WMM-2020"  # the RAV4 log's day
    assert wmm_model_for(2018.6) == "WMM-2015v2"


def test_ithaca_ny_2025() -> None:
    """Cornell (the paper's field site), 42.444 N 76.502 W: about 11.6 degrees west in 2025.

    -11.617 at 2025.0 and -11.598 at mid-2025, computed with pygeomag 1.1.0 / WMM-2025.
    """
    assert declination_deg(42.4440, -76.5019, dt.date(2025, 1, 1)) == pytest.approx(
        -11.617, abs=0.005
    )
    assert declination_deg(42.4440, -76.5019, dt.date(2025, 7, 1)) == pytest.approx(
        -11.598, abs=0.005
    )


def test_pygeomag_published_example() -> None:
    """pygeomag's documented WMM-2025 example: the Space Needle, Seattle, 2025.25 -> 15.0656."""
    assert declination_deg(47.6205, -122.3493, 2025.25) == pytest.approx(15.0656, abs=1e-4)


def test_altitude_is_metres() -> None:
    low = declination_deg(42.444, -76.502, 2025.5, alt_m=0.0)
    high = declination_deg(42.444, -76.502, 2025.5, alt_m=10_000.0)
    assert low != high and abs(low - high) < 0.5


def test_bad_inputs_are_user_errors() -> None:
    with pytest.raises(UserError, match="latitude"):
        declination_deg(95.0, 0.0, 2025.0)
    with pytest.raises(UserError, match="longitude"):
        declination_deg(0.0, 200.0, 2025.0)
    with pytest.raises(UserError, match="outside the World Magnetic Models"):
        declination_deg(0.0, 0.0, 2035.0)


def test_magnetic_north_in_ithaca_points_west_of_true_north() -> None:
    decl = declination_deg(42.4440, -76.5019, dt.date(2025, 1, 1))
    theta = compass_heading_to_theta(CompassHeading(0.0, 0.0), decl)
    # Magnetic north is 11.6 degrees west of true north: CCW from east, 90 + 11.6 degrees.
    assert math.degrees(theta) == pytest.approx(90.0 - decl, abs=1e-9)


def test_true_headings_skip_the_declination() -> None:
    theta = compass_heading_to_theta(CompassHeading(0.0, 90.0, is_true=True), -11.6)
    assert theta == pytest.approx(0.0, abs=1e-12)  # true east is the filter's x axis


def test_mounting_offset_is_added_clockwise() -> None:
    a = compass_heading_to_theta(CompassHeading(0.0, 80.0), 3.0, mounting_offset_deg=10.0)
    b = compass_heading_to_theta(CompassHeading(0.0, 90.0), 3.0)
    assert a == pytest.approx(b)


@settings(max_examples=300, deadline=None)
@given(
    reading=st.floats(min_value=0.0, max_value=359.99),
    decl=st.floats(min_value=-30.0, max_value=30.0),
    offset=st.floats(min_value=-180.0, max_value=180.0),
)
def test_round_trip_through_guidance_model(reading: float, decl: float, offset: float) -> None:
    theta = compass_heading_to_theta(CompassHeading(0.0, reading), decl, offset)
    assert -math.pi < theta <= math.pi
    back = heading_to_compass(theta, decl)
    diff = wrap_angle(math.radians(back - (reading + offset)))
    assert abs(diff) < 1e-9


def test_declination_round_trip_at_a_real_place() -> None:
    decl = declination_deg(42.4440, -76.5019, dt.date(2025, 6, 1))
    for reading in (0.0, 45.0, 181.5, 359.0):
        theta = compass_heading_to_theta(CompassHeading(0.0, reading), decl)
        assert heading_to_compass(theta, decl) == pytest.approx(reading, abs=1e-9)
