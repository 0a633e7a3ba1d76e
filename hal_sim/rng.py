"""The world step's random numbers: xoroshiro128+ on two 64-bit words, and the inverse normal.

numba's ``np.random`` (a Mersenne Twister whose state is looked up in thread-local storage at
every call, and a normal by the polar method: two uniforms, a logarithm and a square root)
cost a study step about 36 ns for its two slip uniforms and 0.6 compass normals. Here the
state is two words the compiled trial loop keeps in registers (``hal_sim.engine``), or that
``world.world_step`` reads from and writes back to the route vector (the reference engine
and the in-car simulation call it step by step), so every caller draws the same numbers:

* ``next64``: one step of xoroshiro128+ (Blackman and Vigna, 2018; period 2^128 - 1); its
  53 high bits make a double (its weak lowest bits are dropped);
* ``uniform``: [0, 1) from 53 bits, as numpy's and numba's ``random()``;
* ``normal``: the standard normal by the inverse of its distribution function at a uniform
  in (0, 1) (Acklam's rational approximation, relative error below 1.2e-9 everywhere; one
  division in the central 95 %, a logarithm and a square root in the tails).
* ``seed_state``: the two words from one 62-bit number, by splitmix64 (the seeding its
  authors recommend), never both zero.

The rest of a trial's draws (the city, the landmarks, the goals, detections) stay numba's:
``np.random.seed`` still fixes the whole trial, through the words drawn in ``world.init_truth``.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

_TWO_M53 = 1.0 / 9007199254740992.0  # 2^-53
_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_MIX1 = np.uint64(0xBF58476D1CE4E5B9)
_MIX2 = np.uint64(0x94D049BB133111EB)

# Acklam's inverse normal: central region (|p - 1/2| <= 1/2 - P_LOW) and tails.
_A1, _A2, _A3 = -3.969683028665376e01, 2.209460984245205e02, -2.759285104469687e02
_A4, _A5, _A6 = 1.383577518672690e02, -3.066479806614716e01, 2.506628277459239e00
_B1, _B2, _B3 = -5.447609879822406e01, 1.615858368580409e02, -1.556989798598866e02
_B4, _B5 = 6.680131188771972e01, -1.328068155288572e01
_C1, _C2, _C3 = -7.784894002430293e-03, -3.223964580411365e-01, -2.400758277161838e00
_C4, _C5, _C6 = -2.549732539343734e00, 4.374664141464968e00, 2.938163982698783e00
_D1, _D2, _D3 = 7.784695709041462e-03, 3.224671290700398e-01, 2.445134137142996e00
_D4 = 3.754408661907416e00
P_LOW = 0.02425


@njit(cache=True, error_model="numpy", inline="always")
def _rotl(x: np.uint64, k: int) -> np.uint64:
    return (x << np.uint64(k)) | (x >> np.uint64(64 - k))


@njit(cache=True, error_model="numpy", inline="always")
def next64(s0: np.uint64, s1: np.uint64) -> tuple[np.uint64, np.uint64, np.uint64]:
    """(output, new s0, new s1): one step of xoroshiro128+ (rotations 24, 16, 37)."""
    out = s0 + s1
    s1 = s1 ^ s0
    s0 = _rotl(s0, 24) ^ s1 ^ (s1 << np.uint64(16))
    s1 = _rotl(s1, 37)
    return out, s0, s1


@njit(cache=True, error_model="numpy", inline="always")
def uniform(s0: np.uint64, s1: np.uint64) -> tuple[float, np.uint64, np.uint64]:
    """(a uniform in [0, 1) on the 2^-53 grid, new s0, new s1)."""
    r, s0, s1 = next64(s0, s1)
    return float(r >> np.uint64(11)) * _TWO_M53, s0, s1


@njit(cache=True, error_model="numpy")
def _normal_tail(p: float) -> float:
    """``inverse_normal`` in the tails (p < P_LOW or p > 1 - P_LOW): a call, as it is rare."""
    if p < P_LOW:
        q = math.sqrt(-2.0 * math.log(p))
        return (((((_C1 * q + _C2) * q + _C3) * q + _C4) * q + _C5) * q + _C6) / (
            (((_D1 * q + _D2) * q + _D3) * q + _D4) * q + 1.0
        )
    q = math.sqrt(-2.0 * math.log(1.0 - p))
    return -(((((_C1 * q + _C2) * q + _C3) * q + _C4) * q + _C5) * q + _C6) / (
        (((_D1 * q + _D2) * q + _D3) * q + _D4) * q + 1.0
    )


@njit(cache=True, error_model="numpy", inline="always")
def inverse_normal(p: float) -> float:
    """The standard normal quantile at p in (0, 1) (Acklam; relative error < 1.2e-9). The
    central region inline (in the trial loop: no call), the tails by ``_normal_tail``."""
    if p < P_LOW or p > 1.0 - P_LOW:
        return _normal_tail(p)
    q = p - 0.5
    r = q * q
    return (
        (((((_A1 * r + _A2) * r + _A3) * r + _A4) * r + _A5) * r + _A6)
        * q
        / (((((_B1 * r + _B2) * r + _B3) * r + _B4) * r + _B5) * r + 1.0)
    )


@njit(cache=True, error_model="numpy", inline="always")
def normal(s0: np.uint64, s1: np.uint64) -> tuple[float, np.uint64, np.uint64]:
    """(a standard normal, new s0, new s1): the quantile at the midpoint of a 2^-53 cell, so
    never at 0 or 1 (|z| at most 8.3)."""
    r, s0, s1 = next64(s0, s1)
    return inverse_normal((float(r >> np.uint64(11)) + 0.5) * _TWO_M53), s0, s1


@njit(cache=True, error_model="numpy")
def _splitmix(z: np.uint64) -> tuple[np.uint64, np.uint64]:
    """(output, next z): one step of splitmix64."""
    z = z + _GOLDEN
    x = z
    x = (x ^ (x >> np.uint64(30))) * _MIX1
    x = (x ^ (x >> np.uint64(27))) * _MIX2
    return x ^ (x >> np.uint64(31)), z


@njit(cache=True, error_model="numpy")
def seed_state(seed: int) -> tuple[np.uint64, np.uint64]:
    """The generator's two words from a non-negative seed (splitmix64), never both zero."""
    s0, z = _splitmix(np.uint64(seed))
    s1, z = _splitmix(z)
    if s0 == np.uint64(0) and s1 == np.uint64(0):
        s1 = np.uint64(1)
    return s0, s1


@njit(cache=True, error_model="numpy", inline="always")
def to_word(s: np.uint64) -> np.int64:
    """A state word as the int64 with its bits (the route vector holds it)."""
    return np.int64(s)


@njit(cache=True, error_model="numpy", inline="always")
def from_word(w: np.int64) -> np.uint64:
    """A state word back from its int64 (``to_word``'s inverse)."""
    return np.uint64(w)
