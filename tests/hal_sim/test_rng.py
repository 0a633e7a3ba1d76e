"""The world step's generator (hal_sim.rng): uniforms and normals with the right statistics."""

from __future__ import annotations

import math
import statistics

import numpy as np
from numba import njit

from hal_sim import rng


@njit(cache=True)
def _draws(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    s0, s1 = rng.seed_state(seed)
    u = np.empty(n)
    z = np.empty(n)
    for i in range(n):
        u[i], s0, s1 = rng.uniform(s0, s1)
        z[i], s0, s1 = rng.normal(s0, s1)
    return u, z


def test_the_inverse_normal_is_within_1e9_of_the_quantile() -> None:
    nd = statistics.NormalDist()
    ps = np.concatenate(
        [
            np.linspace(1e-9, 1.0 - 1e-9, 4001),
            np.logspace(-15, -1, 100),
            1.0 - np.logspace(-15, -1, 100),
        ]
    )
    for p in ps:
        want = nd.inv_cdf(float(p))
        assert abs(rng.inverse_normal(float(p)) - want) <= 1.2e-9 * max(abs(want), 1e-3)


def test_uniforms_and_normals_have_their_moments() -> None:
    n = 400_000
    u, z = _draws(n, 12345)
    assert u.min() >= 0.0 and u.max() < 1.0
    se = 1.0 / math.sqrt(n)
    assert abs(u.mean() - 0.5) < 5 * se * math.sqrt(1 / 12)
    assert abs(u.var() - 1 / 12) < 5 * se * math.sqrt(1 / 180)
    assert abs(z.mean()) < 5 * se
    assert abs(z.var() - 1.0) < 5 * se * math.sqrt(2.0)
    assert abs((z**3).mean()) < 5 * se * math.sqrt(15.0)
    assert abs((z**4).mean() - 3.0) < 5 * se * math.sqrt(96.0)
    # the tails: P(|z| > 2.5) = 1.24 %, drawn through the logarithm branch
    tail = float((np.abs(z) > 2.5).mean())
    assert abs(tail - 0.012419) < 5 * math.sqrt(0.012419 / n)


def test_seeds_give_distinct_streams_and_state_words_round_trip() -> None:
    u1, _ = _draws(1000, 1)
    u2, _ = _draws(1000, 2)
    assert not np.array_equal(u1, u2)
    assert np.array_equal(u1, _draws(1000, 1)[0])
    s0, s1 = rng.seed_state(7)
    assert rng.from_word(rng.to_word(s0)) == s0 and rng.from_word(rng.to_word(s1)) == s1
