"""Compass deviation calibration: card, robust fit, coverage, odometry reference, a real drive."""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from guidance.core.localize.compass_cal import (
    MIN_READINGS,
    CompassCalibration,
    calibrate_from_drive,
    fit_deviation,
    heading_coverage,
    reference_headings_from_odometry,
)

REALDRIVES = Path(__file__).resolve().parents[5] / "shared" / "data" / "realdrives"
"""tests/guidance/core/<this> -> parents: core, guidance, tests, main, work: /work/shared/..."""

CARD = CompassCalibration(a_deg=40.0, b_deg=8.0, c_deg=-5.0, d_deg=3.0, e_deg=2.0)
TRACK = 1.62


def _wrap180(a: np.ndarray | float) -> np.ndarray:
    return np.mod(np.asarray(a) + 180.0, 360.0) - 180.0


def _readings_for(card: CompassCalibration, magnetic_deg: np.ndarray) -> np.ndarray:
    """What a compass with this card reads: solve reading + deviation(reading) = magnetic."""
    r = np.array(magnetic_deg, dtype=float)
    for _ in range(60):  # a contraction: |d deviation / d reading| < 1 for any usable card
        r = magnetic_deg - np.array([card.deviation_deg(x) for x in r])
    return np.mod(r, 360.0)


def _coefficients(cal: CompassCalibration) -> np.ndarray:
    return np.array(list(cal.as_dict().values()))


def _circle_odometry(
    radius_m: float, speed_mps: float, turns: float, left: bool, dt: float = 0.02
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Wheel increments for a circle of the given radius (centre line), from the geometry."""
    n = round(turns * 2 * math.pi * radius_m / speed_mps / dt)
    t = 1000.0 + dt * np.arange(n + 1)
    d = np.full(n + 1, speed_mps * dt)
    inner, outer = d * (radius_m - TRACK / 2) / radius_m, d * (radius_m + TRACK / 2) / radius_m
    return (t, inner, outer) if left else (t, outer, inner)


def test_two_circles_recover_the_card_and_count_the_spikes() -> None:
    rng = np.random.default_rng(7)
    magnetic = np.linspace(0.0, 720.0, 720, endpoint=False) + 17.0
    readings = _readings_for(CARD, magnetic) + rng.normal(0.0, 1.0, magnetic.size)
    spikes = rng.choice(magnetic.size, 8, replace=False)
    readings[spikes] += 60.0  # a passing bus, a steel gate
    res = fit_deviation(readings, np.mod(magnetic, 360.0))
    assert res.terms == "offset + 2 harmonics"
    assert res.note == ""
    np.testing.assert_allclose(_coefficients(res.calibration), _coefficients(CARD), atol=1.0)
    assert res.n_outliers == 8
    assert res.n_used == 712
    assert res.residual_rms_deg == pytest.approx(1.0, abs=0.15)
    assert res.coverage_deg > 350.0
    # Without the robust weights the spikes bend the curve.
    plain = fit_deviation(readings, np.mod(magnetic, 360.0), robust=False)
    assert plain.n_outliers == 0
    err = np.abs(_coefficients(plain.calibration) - _coefficients(CARD)).max()
    assert err > np.abs(_coefficients(res.calibration) - _coefficients(CARD)).max()


def test_apply_inverts_a_hard_and_soft_iron_compass() -> None:
    """A physical compass (not the card's own form): the card corrects it to its residual."""
    soft = np.array([[1.06, 0.05], [0.05, 0.93]])
    hard = np.array([0.12, -0.08])  # of the earth's horizontal field

    def compass(magnetic_deg: np.ndarray) -> np.ndarray:
        m = np.radians(magnetic_deg)
        f = soft @ np.vstack((np.cos(m), -np.sin(m))) + hard[:, None]  # forward, right
        return np.mod(np.degrees(np.arctan2(-f[1], f[0])) - 52.0, 360.0)  # mounted 52 deg off

    magnetic = np.linspace(0.0, 720.0, 400, endpoint=False)
    res = fit_deviation(compass(magnetic), np.mod(magnetic, 360.0))
    assert res.terms == "offset + 2 harmonics"
    assert res.residual_max_deg < 1.0  # the 5-term card is a close fit of this compass
    fresh = np.arange(0.5, 360.0, 1.0)
    corrected = np.array([res.calibration.apply(r) for r in compass(fresh)])
    assert np.abs(_wrap180(corrected - fresh)).max() <= res.residual_max_deg + 0.05


def test_straight_drive_fits_the_offset_only_and_says_why() -> None:
    rng = np.random.default_rng(1)
    readings = 100.0 + rng.normal(0.0, 1.0, 300)
    res = fit_deviation(readings, np.full(300, 130.0))
    assert res.terms == "offset only"
    assert res.calibration.a_deg == pytest.approx(30.0, abs=0.3)
    assert res.calibration.b_deg == res.calibration.d_deg == 0.0
    assert res.coverage_deg < 10.0
    assert "readings cover" in res.note
    assert "drive two slow circles" in res.note


def test_wrap_around_at_north() -> None:
    rng = np.random.default_rng(2)
    readings = np.mod(359.0 + rng.normal(0.0, 1.0, 200), 360.0)  # 357..1, crossing 0
    assert readings.min() < 5.0 and readings.max() > 355.0
    res = fit_deviation(readings, np.full(200, 1.0))
    assert res.terms == "offset only"
    assert res.coverage_deg < 10.0  # not 350: the gap is the wide side of the circle
    assert res.calibration.a_deg == pytest.approx(2.0, abs=0.3)
    assert res.calibration.apply(359.0) == pytest.approx(1.0, abs=0.3)
    assert res.residual_rms_deg == pytest.approx(1.0, abs=0.2)


def test_offset_near_180_wraps() -> None:
    card = CompassCalibration(a_deg=179.0, b_deg=5.0)
    magnetic = np.linspace(0.0, 720.0, 360, endpoint=False)
    readings = _readings_for(card, magnetic)
    res = fit_deviation(readings, np.mod(magnetic, 360.0))
    assert abs(_wrap180(res.calibration.a_deg - 179.0)) < 0.01
    assert -180.0 <= res.calibration.a_deg <= 180.0
    assert res.calibration.b_deg == pytest.approx(5.0, abs=0.01)


def test_sparse_headings_are_not_coverage() -> None:
    """Four headings 90 degrees apart leave no gap over 120 degrees but fix no harmonics."""
    readings = np.repeat([0.0, 90.0, 180.0, 270.0], 10)
    assert heading_coverage(readings) == (270.0, 4)
    res = fit_deviation(readings, readings + 10.0)
    assert res.terms == "offset only"
    assert res.calibration.a_deg == pytest.approx(10.0)


def test_half_circle_is_offset_only_at_the_default() -> None:
    magnetic = np.linspace(0.0, 200.0, 200)
    res = fit_deviation(_readings_for(CARD, magnetic), magnetic)
    assert res.terms == "offset only"
    assert fit_deviation(magnetic, magnetic, min_coverage_deg=180.0).terms != "offset only"


def test_too_few_readings_and_bad_input() -> None:
    h = np.linspace(0.0, 350.0, MIN_READINGS - 1)
    with pytest.raises(ValueError, match=f"at least {MIN_READINGS}"):
        fit_deviation(h, h)
    h = np.linspace(0.0, 350.0, 40)
    with pytest.raises(ValueError, match="equal 1-D"):
        fit_deviation(h, h[:-1])
    with pytest.raises(ValueError, match="finite"):
        fit_deviation(np.where(h > 100, np.nan, h), h)


def test_an_unusable_fit_is_refused() -> None:
    readings = np.linspace(0.0, 360.0, 100, endpoint=False)
    magnetic = readings + 50.0 * np.sin(np.radians(readings))  # the car's field ~ the earth's
    with pytest.raises(ValueError, match="unusable: b_deg = 50") as caught:
        fit_deviation(readings, magnetic)
    # Issue 21: the refusal says what the user can do about it.
    text = str(caught.value)
    assert "What to do" in text and "away from steel" in text and "run uncalibrated" in text


def test_from_mapping_round_trip_and_validation() -> None:
    assert CompassCalibration.from_mapping(CARD.as_dict()) == CARD
    assert CompassCalibration.from_mapping({"a_deg": 40}) == CompassCalibration(a_deg=40.0)
    assert CompassCalibration.from_mapping({}).is_identity
    assert not CARD.is_identity
    bad: list[tuple[dict[str, object], str]] = [
        ({"a_deg": math.nan}, "finite"),
        ({"b_deg": math.inf}, "finite"),
        ({"a_deg": 180.5}, r"\[-180, 180\]"),
        ({"b_deg": 46.0}, "45"),
        ({"e_deg": -45.1}, "45"),
        ({"d_deg": 30.0}, "single-valued"),  # 2h slope 2 * 30 deg = 1.05 rad > 1
        ({"b_deg": 45.0, "c_deg": 45.0}, "single-valued"),  # 1h slope 1.11 rad
        ({"a_deg": True}, "number"),
        ({"a_deg": "40"}, "number"),
        ({"a_deg": 10**400}, "out of range"),
        ({"a_dg": 40.0}, "unknown"),
    ]
    for mapping, message in bad:
        with pytest.raises(ValueError, match=message):
            CompassCalibration.from_mapping(mapping)


@given(
    st.lists(st.floats(-45.0, 45.0), min_size=4, max_size=4),
    st.floats(-180.0, 180.0),
    st.floats(-1e4, 1e4),
)
def test_apply_is_a_heading(harmonics: list[float], a: float, reading: float) -> None:
    cal = CompassCalibration(a, *harmonics)
    out = cal.apply(reading)
    assert 0.0 <= out < 360.0
    assert cal.deviation_deg(reading + 360.0) == pytest.approx(cal.deviation_deg(reading), abs=1e-9)
    assert abs(_wrap180(out - reading - cal.deviation_deg(reading))) < 1e-9


@pytest.mark.parametrize("left", [True, False])
def test_odometry_reference_on_a_circle(left: bool) -> None:
    radius, speed = 12.0, 3.0
    t, dl, dr = _circle_odometry(radius, speed, turns=2.0, left=left)
    ref = reference_headings_from_odometry(
        t, dl, dr, track_m=TRACK, start_true_heading_deg=5.0, declination_deg=13.5
    )
    q = np.linspace(t[0], t[-1], 777)
    turned = np.degrees(speed * (q - t[0]) / radius) * (-1.0 if left else 1.0)
    expected = np.mod(5.0 - 13.5 + turned, 360.0)
    np.testing.assert_allclose(_wrap180(ref.magnetic_at(q) - expected), 0.0, atol=1e-6)
    assert ref.total_distance_m == pytest.approx(2 * 2 * math.pi * radius, rel=1e-3)
    assert np.allclose(ref.speed_at(q), speed)
    assert np.isnan(ref.magnetic_at([t[0] - 1.0, t[-1] + 1.0])).all()
    assert not ref.moving([t[0] - 1.0]).any()


def test_odometry_reference_rejects_bad_input() -> None:
    t = np.arange(5.0)
    z = np.zeros(5)
    kw = {"start_true_heading_deg": 0.0, "declination_deg": 0.0}
    with pytest.raises(ValueError, match="increase"):
        reference_headings_from_odometry(t[::-1], z, z, track_m=TRACK, **kw)
    with pytest.raises(ValueError, match="positive"):
        reference_headings_from_odometry(t, z, z, track_m=0.0, **kw)
    with pytest.raises(ValueError, match="equal"):
        reference_headings_from_odometry(t, z[:3], z, track_m=TRACK, **kw)


def _stop(
    t: np.ndarray, dl: np.ndarray, dr: np.ndarray, seconds: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Prepend a standstill of the given length to a drive."""
    dt = t[1] - t[0]
    n = int(seconds / dt)
    t0 = t[0] - dt * np.arange(n, 0, -1)
    return (
        np.concatenate((t0, t)),
        np.concatenate((np.zeros(n), dl)),
        np.concatenate((np.zeros(n), dr)),
    )


def test_calibration_drive_end_to_end_drops_the_standstill() -> None:
    rng = np.random.default_rng(3)
    radius, speed = 10.0, 2.5
    t, dl, dr = _stop(*_circle_odometry(radius, speed, turns=2.0, left=False), seconds=20.0)
    ref = reference_headings_from_odometry(
        t, dl, dr, track_m=TRACK, start_true_heading_deg=90.0, declination_deg=-3.0
    )
    tr = np.arange(t[0], t[-1], 0.1) + 0.013  # a 10 Hz compass on its own clock
    readings = _readings_for(CARD, ref.magnetic_at(tr)) + rng.normal(0.0, 0.7, tr.size)
    res = calibrate_from_drive(tr, readings, ref)
    assert res.terms == "offset + 2 harmonics"
    np.testing.assert_allclose(_coefficients(res.calibration), _coefficients(CARD), atol=1.0)
    assert "200 readings taken standing" in res.note  # 20 s at 10 Hz
    assert "warning" not in res.note
    with pytest.raises(ValueError, match="while the car moved"):
        calibrate_from_drive(tr, readings, ref, min_speed_mps=3.0)


def test_long_calibration_drive_warns_about_drift() -> None:
    t, dl, dr = _circle_odometry(100.0, 8.0, turns=2.0, left=True, dt=0.05)  # 1257 m
    ref = reference_headings_from_odometry(
        t, dl, dr, track_m=TRACK, start_true_heading_deg=0.0, declination_deg=0.0
    )
    tr = np.arange(t[0], t[-1], 0.5)
    res = calibrate_from_drive(tr, _readings_for(CARD, ref.magnetic_at(tr)), ref)
    assert re.search(r"warning: 125\d m driven", res.note)
    assert "drifts with distance" in res.note


def _read_real_drive() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Compass reading times and headings, and the magnetic truth heading at those times."""
    nmea = REALDRIVES / "comma2k19_ex1_hdg_inferred.nmea"
    truth = REALDRIVES / "comma2k19_ex1_truth.csv"
    if not (nmea.is_file() and truth.is_file()):
        pytest.skip(f"real drive files not present in {REALDRIVES} (optional real-data check)")
    rows = [line.split() for line in nmea.read_text().splitlines() if "$HCHDG" in line]
    t = np.array([float(r[0]) for r in rows])
    h = np.array([float(r[1].split(",")[1]) for r in rows])
    tru = np.genfromtxt(truth, delimiter=",", names=True)
    true_unwrapped = np.degrees(np.unwrap(np.radians(tru["heading_deg"])))
    inside = (t >= tru["t"][0]) & (t <= tru["t"][-1])
    magnetic = np.mod(np.interp(t[inside], tru["t"], true_unwrapped) - 13.50, 360.0)
    return t[inside], h[inside], magnetic


@pytest.mark.shared_data
def test_real_straight_drive_gives_the_offset_only() -> None:
    """comma2k19 ex1: 60 s north on a straight road; the compass reads about 40 degrees low."""
    _, readings, magnetic = _read_real_drive()
    assert readings.size > 500
    res = fit_deviation(readings, magnetic)
    d = np.radians(magnetic - readings)
    direct = math.degrees(math.atan2(np.sin(d).mean(), np.cos(d).mean()))
    assert 35.0 < direct < 45.0  # reads 310 while heading 348.5 magnetic (2 true - 13.5)
    assert res.terms == "offset only"
    assert "drive two slow circles" in res.note
    assert res.calibration.a_deg == pytest.approx(direct, abs=3.0)
    assert res.coverage_deg < 20.0
    assert res.residual_rms_deg < 5.0
