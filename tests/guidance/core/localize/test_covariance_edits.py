"""The filter's covariance edits (``localize.covariance_edits``): pure, each on a copy."""

from __future__ import annotations

import math

import numpy as np
import pytest

from guidance.core import model
from guidance.core.localize import covariance_edits as edits
from guidance.core.localize.car_model import car_model
from guidance.core.localize.estimator import EstimatorConfig

CAR = car_model(EstimatorConfig(), calibrated=False)


def _correlated(n: int) -> np.ndarray:
    """A valid covariance with every state correlated with every other."""
    a = np.random.default_rng(4).normal(size=(n, n))
    return a @ a.T + n * np.eye(n)


def test_adopted_values_are_set_alone_and_the_rest_is_kept() -> None:
    x, P = np.arange(7.0), _correlated(7)
    x2, P2 = edits.adopted(x, P, [(model.STATE_SCALE, 0.01, 0.002)])
    s = model.STATE_SCALE
    assert x2[s] == 0.01 and P2[s, s] == pytest.approx(0.002**2)
    assert np.count_nonzero(P2[s]) == 1 and np.count_nonzero(P2[:, s]) == 1
    keep = [i for i in range(7) if i != s]
    assert np.array_equal(P2[np.ix_(keep, keep)], P[np.ix_(keep, keep)])
    assert np.array_equal(x, np.arange(7.0))  # the inputs untouched


def test_a_heading_from_the_compass_carries_the_bias_uncertainty() -> None:
    """The compass reads heading + bias: the heading is the reading less the bias, with the
    bias's variance added, anti-correlated with it (their sum is what the compass knows)."""
    x, P = np.zeros(7), edits.prior(CAR)
    b = model.STATE_BIAS
    x[b] = 0.3
    theta, P2 = edits.heading_from_compass(x, P, 1.0, 0.01)
    assert theta == pytest.approx(0.7)
    h = np.zeros(7)
    h[2] = h[b] = 1.0  # the compass's measurement row
    assert h @ P2 @ h == pytest.approx(0.01)
    assert P2[2, 2] == pytest.approx(0.01 + P[b, b]) and P2[0, 2] == 0.0
    np.linalg.cholesky(P2 + 1e-12 * np.eye(7))  # still a covariance


def test_the_lost_reset_is_never_tighter_than_the_last_finite_covariance() -> None:
    before = _correlated(7) * 1e6
    lost = edits.lost(CAR, before)
    assert np.all(np.diag(lost) >= np.diag(before))
    assert lost[2, 2] >= math.pi**2 and lost[0, 0] >= CAR.lost_major_axis_m**2
    assert edits.lost(CAR, before * np.nan)[0, 0] == CAR.lost_major_axis_m**2


def test_a_pose_covariance_is_embedded_with_the_error_states_at_their_priors() -> None:
    pose = np.diag([4.0, 9.0, 0.04])
    P = edits.of_pose(CAR, pose)
    assert np.array_equal(P[:3, :3], pose)
    assert np.array_equal(np.diag(P)[3:], np.diag(edits.prior(CAR))[3:])
    whole = _correlated(7)
    assert np.array_equal(edits.of_pose(CAR, whole), whole)
    assert np.array_equal(edits.position_widened(pose, 20.0), pose + np.diag([100.0, 100.0, 0]))
