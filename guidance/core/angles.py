"""The two angle conventions every output needs, in plain Python: the one definition.

``guidance.core.model`` compiles these same functions with numba for the filter and the study
engine (``model.wrap_angle = njit(angles.wrap_angle)``); the output encoders call them as they
are, so importing the encoders does not load the compiler."""

from __future__ import annotations

import math

_TWO_PI = 2.0 * math.pi


def wrap_angle(a: float) -> float:
    """Wrap an angle to (-pi, pi]."""
    if -math.pi < a <= math.pi:  # the common case, without a division
        return a
    x = a + math.pi
    # x % 2 pi, without the library's remainder when a is less than a turn out (a heading
    # just past +-pi: every step of a car driving west) and with the same result: for
    # 2 pi < x < 4 pi the remainder is x - 2 pi, exactly (Sterbenz); for -2 pi < x < 0 it is
    # x, which % makes positive by adding 2 pi.
    if _TWO_PI < x < 2.0 * _TWO_PI:
        w = x - _TWO_PI
    elif -_TWO_PI < x < 0.0:
        w = x + _TWO_PI
    else:
        w = x % _TWO_PI
    if w == 0.0:
        w = _TWO_PI
    return w - math.pi


def heading_to_compass(theta: float, declination_deg: float) -> float:
    """Filter heading (rad, counter-clockwise from east) to magnetic compass degrees in
    [0, 360)."""
    deg = 90.0 - math.degrees(theta) - declination_deg
    deg = deg % 360.0
    if deg >= 360.0:  # -1e-17 % 360.0 rounds to 360.0
        deg = 0.0
    return deg
