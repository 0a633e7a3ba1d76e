"""The candidate gate: exact distance to the 2-sigma ellipse, R*Tree query against brute force."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.stats import chi2

from guidance.core.geo import Origin
from guidance.core.model import CHI2_2D_2SIGMA
from landmark_db.features import Features
from landmark_db.gate import GATE_PROBABILITY_2SIGMA, distance_to_ellipse, ellipse_axes
from landmark_db.store import create_db, query_gate


def _cov(sx: float, sy: float, rho: float) -> tuple[tuple[float, float], tuple[float, float]]:
    return ((sx * sx, rho * sx * sy), (rho * sx * sy, sy * sy))


def _brute_distance(p: np.ndarray, mean: np.ndarray, cov: tuple, k2: float) -> float:
    """Distance to the filled ellipse by dense sampling of its boundary."""
    P = np.array(cov)
    d = p - mean
    if d @ np.linalg.solve(P, d) <= k2:
        return 0.0
    a, b, ang = ellipse_axes(cov, k2)
    th = np.linspace(0.0, 2.0 * math.pi, 20001)
    ex = mean[0] + a * np.cos(th) * math.cos(ang) - b * np.sin(th) * math.sin(ang)
    ey = mean[1] + a * np.cos(th) * math.sin(ang) + b * np.sin(th) * math.cos(ang)
    return float(np.min(np.hypot(ex - p[0], ey - p[1])))


def test_gate_probability_is_the_chi_square_value() -> None:
    prob = GATE_PROBABILITY_2SIGMA
    assert prob == pytest.approx(chi2.cdf(CHI2_2D_2SIGMA, 2), abs=1e-12)
    assert prob == pytest.approx(0.8647, abs=1e-4)


@settings(max_examples=60, deadline=None)
@given(
    sx=st.floats(0.5, 200.0),
    sy=st.floats(0.5, 200.0),
    rho=st.floats(-0.95, 0.95),
    px=st.floats(-800.0, 800.0),
    py=st.floats(-800.0, 800.0),
)
def test_distance_to_ellipse_matches_brute_force(
    sx: float, sy: float, rho: float, px: float, py: float
) -> None:
    cov = _cov(sx, sy, rho)
    mean = np.array([10.0, -5.0])
    p = np.array([px, py])
    got = float(distance_to_ellipse(p[None, :], mean, cov, CHI2_2D_2SIGMA)[0])
    want = _brute_distance(p, mean, cov, CHI2_2D_2SIGMA)
    # sampling error of the brute force: chord sagitta of the densest sampling
    a, _, _ = ellipse_axes(cov, CHI2_2D_2SIGMA)
    assert got == pytest.approx(want, abs=1e-6 + a * 2e-3)


def test_range_reaches_a_plus_r_along_the_major_axis() -> None:
    """The gate is the Minkowski sum: inflating P by r^2/k2 would stop at sqrt(a^2 + r^2)."""
    cov = _cov(50.0, 5.0, 0.0)  # 2-sigma semi-axes 100 m and 10 m along x and y
    r = 20.0
    pts = np.array([[119.9, 0.0], [120.1, 0.0], [0.0, 29.9], [0.0, 30.1], [100.0, 10.0]])
    d = distance_to_ellipse(pts, (0.0, 0.0), cov, CHI2_2D_2SIGMA)
    assert list(d <= r) == [True, False, True, False, True]
    # sqrt(100^2 + 20^2) = 102 m: the inflated-covariance shortcut would miss 102-120 m.
    assert math.sqrt(100.0**2 + r**2) < 110.0 and d[0] <= r


def test_rtree_query_equals_brute_force(tmp_path: Path) -> None:
    rng = np.random.default_rng(4)
    db = create_db(tmp_path / "g.sqlite", Origin(0.0, 0.0))
    xy = rng.uniform(-2000.0, 2000.0, (3000, 2))
    f = Features(np.zeros((1, 6), np.float32), np.zeros((1, 32), np.uint8), 1, 1)
    db.add_many_precomputed([(f"l{i}", x, y) for i, (x, y) in enumerate(xy)], f, b"\x89PNG")
    ids_all = np.arange(1, len(xy) + 1)
    for _ in range(40):
        mean = rng.uniform(-1500.0, 1500.0, 2)
        cov = _cov(rng.uniform(1, 150), rng.uniform(1, 150), rng.uniform(-0.9, 0.9))
        r = rng.uniform(0.0, 50.0)
        got = query_gate(db, mean, cov, r)
        d = distance_to_ellipse(xy, mean, cov, CHI2_2D_2SIGMA)
        want = set(ids_all[d <= r].tolist())
        assert {c.id for c in got} == want
        dists = [c.distance_m for c in got]
        assert dists == sorted(dists)
        limited = query_gate(db, mean, cov, r, limit=5)
        assert [c.id for c in limited] == [c.id for c in got[:5]]
    db.close()


def test_inside_the_ellipse_the_most_likely_come_first(tmp_path: Path) -> None:
    """A lost estimate in a dense block: the 5 compared are the 5 nearest in Mahalanobis terms."""
    db = create_db(tmp_path / "m.sqlite", Origin(0.0, 0.0))
    f = Features(np.zeros((1, 6), np.float32), np.zeros((1, 32), np.uint8), 1, 1)
    # Along x the ellipse is wide (sigma 100 m), along y narrow (sigma 10 m).
    pts = [
        (150.0, 0.0),
        (0.0, 15.0),
        (100.0, 0.0),
        (0.0, 5.0),
        (50.0, 0.0),
        (0.0, 10.0),
        (10.0, 0.0),
        (0.0, 18.0),
    ]
    db.add_many_precomputed([(f"p{i}", x, y) for i, (x, y) in enumerate(pts)], f, b"x")
    got = query_gate(db, (0.0, 0.0), _cov(100.0, 10.0, 0.0), 0.0, limit=5)
    # d2: (10,0) 0.01, (50,0) 0.25, (0,5) 0.25, (100,0) 1, (0,10) 1, (0,15) 2.25, (150,0) 2.25
    assert [c.id for c in got] == [7, 4, 5, 3, 6]
    db.close()
