"""The wheel-speed scale from a drive of known length (``guidance calibrate --distance-m``).

The car model's scale state ``k`` says true distance = measured x (1 + k)
(``guidance.core.model.STATE_SCALE``). Drive a stretch whose length is known (between two
landmarks, or a measured straight), and ``k = known / wheel - 1``. Its uncertainty has two
parts, both first order:

* the known distance's own: ``sigma_known / wheel`` (a map measures 1 km to about 1-2 m; a
  surveyed straight to centimetres);
* the wheel noise: each wheel's random walk ``q |d|`` (``EstimatorConfig.
  wheel_walk_var_m2_per_m``), so the centre distance ``(l + r) / 2`` has variance ``q D / 2``
  and ``k`` the term ``(known / wheel^2)^2 q D / 2``.

A fit whose scale lies outside the physical bound of a learned scale
(``guidance.core.localize.state_limits.MAX_ABS_SCALE``), or from less than ``MIN_DISTANCE_M`` of
driving, is refused (``ValueError``, one line saying what to check): it is a wrong distance,
a wrong stretch of the log, or a wrong CAN profile, never a tyre.

Pure code: no I/O, no clock.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Final

from guidance.core.localize.state_limits import MAX_ABS_SCALE

MIN_DISTANCE_M: Final = 100.0
"""Shortest stretch accepted: a scale of 1 % is 1 m over 100 m, about what a map pin is worth."""
MAX_TURN_DEG: Final = 20.0
"""Largest heading span of the odometry between two known points. Their straight-line
distance is the path's only on a straight road (a 20-degree arc is 0.5 % longer than its
chord); the wheels' own left/right difference turns a straight drive by up to ~15 degrees a
kilometre (comma2k19: 14 degrees), so the span allows for that and no more."""


@dataclass(frozen=True, slots=True)
class ScaleFit:
    """The learned wheel scale and what it came from."""

    scale: float
    scale_sigma: float
    wheel_m: float
    """Centre (mean of left and right) wheel distance over the stretch, as measured."""
    known_m: float
    known_sigma_m: float
    wheel_sigma_m: float
    """1-sigma of the wheel distance from the wheel noise alone."""
    turn_deg: float
    """Span of the odometry's own heading over the stretch (max - min)."""


@dataclass(frozen=True, slots=True)
class Stretch:
    """Wheel distance and heading span of a window of odometry increments."""

    wheel_m: float
    turn_deg: float
    t_from_s: float
    t_to_s: float


def stretch(
    t_s: Sequence[float],
    d_left_m: Sequence[float],
    d_right_m: Sequence[float],
    track_m: float,
    t_from_s: float | None = None,
    t_to_s: float | None = None,
) -> Stretch:
    """The increments between ``t_from_s`` and ``t_to_s`` (default: the whole log). An
    increment at ``t_s[i]`` covers ``(t_s[i-1], t_s[i]]``; one cut by a bound counts by the
    fraction inside it."""
    if len(t_s) < 2:
        raise ValueError("fewer than two odometry increments")
    lo = t_s[0] if t_from_s is None else t_from_s
    hi = t_s[-1] if t_to_s is None else t_to_s
    if not hi > lo:
        raise ValueError(f"the stretch is empty (from {lo:.2f} s to {hi:.2f} s)")
    wheel = heading = 0.0
    h_min = h_max = 0.0
    for i in range(1, len(t_s)):
        a, b = t_s[i - 1], t_s[i]
        if b <= lo or a >= hi or b <= a:
            continue
        frac = (min(b, hi) - max(a, lo)) / (b - a)
        wheel += frac * 0.5 * (d_left_m[i] + d_right_m[i])
        heading += frac * (d_right_m[i] - d_left_m[i]) / track_m
        h_min, h_max = min(h_min, heading), max(h_max, heading)
    return Stretch(wheel, math.degrees(h_max - h_min), lo, hi)


def scale_from_distance(
    wheel_m: float, known_m: float, known_sigma_m: float, walk_var_m2_per_m: float,
    turn_deg: float = 0.0,
) -> ScaleFit:  # fmt: skip
    """``k = known / wheel - 1`` with its 1-sigma (module docstring); ``ValueError`` with one
    line when the result cannot be a tyre."""
    if not (math.isfinite(known_m) and known_m > 0.0):
        raise ValueError(f"the known distance must be a positive number of metres, not {known_m}")
    if not (math.isfinite(known_sigma_m) and known_sigma_m >= 0.0):
        raise ValueError(f"the distance's uncertainty must be >= 0 m, not {known_sigma_m}")
    if not wheel_m >= MIN_DISTANCE_M:
        raise ValueError(
            f"the wheels measured {wheel_m:.1f} m over the stretch: at least "
            f"{MIN_DISTANCE_M:.0f} m are needed (check --from-t/--to-t and the CAN profile)"
        )
    scale = known_m / wheel_m - 1.0
    if abs(scale) > MAX_ABS_SCALE:
        raise ValueError(
            f"wheel scale {100 * scale:+.1f} % ({wheel_m:.1f} m measured by the wheels against "
            f"{known_m:.1f} m known) is outside +-{100 * MAX_ABS_SCALE:.0f} %: a tyre cannot do "
            "that; check the distance, the stretch of the log (--from-t/--to-t) and the CAN "
            "profile"
        )
    wheel_sigma = math.sqrt(max(0.0, walk_var_m2_per_m) * wheel_m / 2.0)
    sigma = math.hypot(known_sigma_m / wheel_m, known_m / wheel_m**2 * wheel_sigma)
    return ScaleFit(scale, sigma, wheel_m, known_m, known_sigma_m, wheel_sigma, turn_deg)


def fuse(old: float, old_sigma: float, new: float, new_sigma: float) -> tuple[float, float, bool]:
    """Inverse-variance combination of an earlier estimate and a new measurement; when they
    disagree by more than 3 sigma (new tyres, another pressure) the new one replaces the old
    (the last value is False then)."""
    if abs(new - old) > 3.0 * math.hypot(old_sigma, new_sigma) or old_sigma <= 0.0:
        return new, new_sigma, False
    if new_sigma <= 0.0:
        return new, new_sigma, True
    w_old, w_new = 1.0 / old_sigma**2, 1.0 / new_sigma**2
    return (w_old * old + w_new * new) / (w_old + w_new), math.sqrt(1.0 / (w_old + w_new)), True
