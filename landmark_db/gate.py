"""Candidate gate (SPEC section 2): the 2-sigma ellipse enlarged by the camera's sighting range.

The estimate is ``mean`` with x-y covariance ``P``. The gate ellipse is
``E = {p : (p - mean)^T P^-1 (p - mean) <= k2}`` with ``k2 = guidance.core.model.CHI2_2D_2SIGMA``
(= 4, the "2-sigma" ellipse: for 2 degrees of freedom it holds the true position with
probability 1 - exp(-k2 / 2) = 0.865). A landmark is a candidate when the camera could
see it from some point of ``E``: its Euclidean distance to ``E`` is at most the sighting
range ``r``. That region is the Minkowski sum of ``E`` and a disc of radius ``r``; we test it
exactly:

1. the R*Tree returns the landmarks in its bounding box, the ellipse's box
   (half-widths ``sqrt(k2 * Pxx)``, ``sqrt(k2 * Pyy)``) grown by ``r`` on every side;
2. each of those is kept if it lies inside ``E`` or within ``r`` of its boundary. The
   distance from a point to an ellipse solves D. Eberly's root equation ("Distance from a
   point to an ellipse, an ellipsoid, or a hyperellipsoid", Geometric Tools, 2013) by a
   monotone Newton iteration, only for points that a cheap lower bound does not reject.

A cheaper, common shortcut (inflating P by ``r^2 / k2``) is *not* used: its semi-axes
``sqrt(a^2 + r^2)`` fall short of the true reach ``a + r``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from guidance.core.model import CHI2_2D_2SIGMA, mahalanobis_sq_2d
from guidance.core.model import ellipse_axes as model_ellipse_axes

GATE_PROBABILITY_2SIGMA = 1.0 - math.exp(-CHI2_2D_2SIGMA / 2.0)
"""P(chi-square, 2 dof <= 4) = 0.8647: the probability mass inside the 2-sigma ellipse."""

_MIN_SEMI_AXIS_M = 1e-6
_NEWTON_STEPS = 60


def ellipse_axes(cov_xy: Sequence[Sequence[float]], k2: float) -> tuple[float, float, float]:
    """Semi-axes (major, minor, metres) and orientation (rad from x) of ``d^T P^-1 d <= k2``:
    the estimator's own ``guidance.core.model.ellipse_axes`` (one definition of the math)."""
    a, b, angle = model_ellipse_axes(
        float(cov_xy[0][0]), float(cov_xy[0][1]), float(cov_xy[1][1]), float(k2)
    )
    return float(a), float(b), float(angle)


def gate_box(
    mean_xy: Sequence[float], cov_xy: Sequence[Sequence[float]], k2: float, range_m: float
) -> tuple[float, float, float, float]:
    """(min_x, max_x, min_y, max_y) of the ellipse's bounding box grown by ``range_m``."""
    hx = math.sqrt(max(k2 * float(cov_xy[0][0]), 0.0)) + range_m
    hy = math.sqrt(max(k2 * float(cov_xy[1][1]), 0.0)) + range_m
    mx, my = float(mean_xy[0]), float(mean_xy[1])
    return mx - hx, mx + hx, my - hy, my + hy


def _frame(
    points_xy: np.ndarray,
    mean_xy: Sequence[float],
    cov_xy: Sequence[Sequence[float]],
    k2: float,
) -> tuple[np.ndarray, np.ndarray, float, float]:
    """Points in the ellipse's axes, first quadrant (the problem is symmetric): u, v, e0, e1."""
    pts = np.asarray(points_xy, dtype=np.float64).reshape(-1, 2)
    a, b, ang = ellipse_axes(cov_xy, k2)
    e0 = max(a, _MIN_SEMI_AXIS_M)
    e1 = max(b, _MIN_SEMI_AXIS_M)
    c, s = math.cos(ang), math.sin(ang)
    dx = pts[:, 0] - float(mean_xy[0])
    dy = pts[:, 1] - float(mean_xy[1])
    return np.abs(c * dx + s * dy), np.abs(-s * dx + c * dy), e0, e1


def _outside_distance(u: float, v: float, e0: float, e1: float) -> float:
    """Distance from (u, v) >= 0, outside the ellipse with semi-axes e0 >= e1, to it.

    The closest point is (e0^2 u / (t + e0^2), e1^2 v / (t + e1^2)) for the root t > 0 of
    F(t) = (e0 u / (t + e0^2))^2 + (e1 v / (t + e1^2))^2 - 1. F is convex and decreasing,
    and t0 = max(e0 u - e0^2, e1 v - e1^2, 0) lies left of the root (each term is <= 1
    there), so Newton's method from t0 rises monotonically to the root.
    """
    e0s, e1s = e0 * e0, e1 * e1
    a0, a1 = e0 * u, e1 * v
    t = max(a0 - e0s, a1 - e1s, 0.0)
    for _ in range(_NEWTON_STEPS):
        r0 = a0 / (t + e0s)
        r1 = a1 / (t + e1s)
        f = r0 * r0 + r1 * r1 - 1.0
        if f <= 1e-15:
            break
        df = -2.0 * (r0 * r0 / (t + e0s) + r1 * r1 / (t + e1s))
        t -= f / df
    return math.hypot(u - e0s * u / (t + e0s), v - e1s * v / (t + e1s))


def distance_to_ellipse(
    points_xy: np.ndarray,
    mean_xy: Sequence[float],
    cov_xy: Sequence[Sequence[float]],
    k2: float,
) -> np.ndarray:
    """Euclidean distance (m) from each point (N x 2) to the filled ellipse; 0 inside."""
    u, v, e0, e1 = _frame(points_xy, mean_xy, cov_xy, k2)
    out = np.zeros(len(u))
    outside = (u / e0) ** 2 + (v / e1) ** 2 > 1.0
    for i in np.flatnonzero(outside):
        out[i] = _outside_distance(float(u[i]), float(v[i]), e0, e1)
    return out


def mahalanobis_sq(
    points_xy: np.ndarray, mean_xy: Sequence[float], cov_xy: Sequence[Sequence[float]]
) -> np.ndarray:
    """d^T P^-1 d for each point (N x 2); +inf where P is singular. Each is the estimator's
    ``guidance.core.model.mahalanobis_sq_2d`` (the gate checks a handful of candidates)."""
    pts = np.asarray(points_xy, dtype=np.float64).reshape(-1, 2)
    pxx, pxy, pyy = float(cov_xy[0][0]), float(cov_xy[0][1]), float(cov_xy[1][1])
    if not pxx * pyy - pxy * pxy > 0.0:
        return np.full(len(pts), math.inf)
    mx, my = float(mean_xy[0]), float(mean_xy[1])
    return np.array(
        [mahalanobis_sq_2d(x - mx, y - my, pxx, pxy, pyy) for x, y in pts], dtype=np.float64
    )


def in_gate(
    points_xy: np.ndarray,
    mean_xy: Sequence[float],
    cov_xy: Sequence[Sequence[float]],
    k2: float = CHI2_2D_2SIGMA,
    range_m: float = 0.0,
) -> tuple[np.ndarray, np.ndarray]:
    """(mask, distance_m): which points are within ``range_m`` of the k2-ellipse, and how far
    each is from the ellipse (0 inside; for points beyond the range, a lower bound)."""
    u, v, e0, e1 = _frame(points_xy, mean_xy, cov_xy, k2)
    # |p| - e0 is a lower bound of the distance: most of the R*Tree box fails it cheaply.
    dist = np.maximum(np.hypot(u, v) - e0, 0.0)
    inside = (u / e0) ** 2 + (v / e1) ** 2 <= 1.0
    dist[inside] = 0.0
    for i in np.flatnonzero(~inside & (dist <= range_m)):
        dist[i] = _outside_distance(float(u[i]), float(v[i]), e0, e1)
    return dist <= range_m, dist


def valid_covariance(cov_xy: Sequence[Sequence[float]]) -> bool:
    """Finite, symmetric enough, with non-negative eigenvalues."""
    try:
        pxx, pxy = float(cov_xy[0][0]), float(cov_xy[0][1])
        pyx, pyy = float(cov_xy[1][0]), float(cov_xy[1][1])
    except (TypeError, ValueError, IndexError):
        return False
    if not all(math.isfinite(v) for v in (pxx, pxy, pyx, pyy)):
        return False
    if abs(pxy - pyx) > 1e-6 * max(1.0, abs(pxx) + abs(pyy)):
        return False
    return pxx >= 0.0 and pyy >= 0.0 and pxx * pyy - pxy * pxy >= -1e-9 * (pxx * pyy + 1.0)
