"""The two angle conventions every output needs, in plain Python: the one definition.

``guidance.core.model`` compiles these same functions with numba for the filter and the study
engine (``model.wrap_angle = njit(angles.wrap_angle)``); the output encoders call them as they
are, so importing the encoders does not load the compiler."""

from __future__ import annotations

import math


def wrap_angle(a: float) -> float:
    """Wrap an angle to (-pi, pi]."""
    if -math.pi < a <= math.pi:  # the common case, without a division
        return a
    w = (a + math.pi) % (2.0 * math.pi)
    if w == 0.0:
        w = 2.0 * math.pi
    return w - math.pi


def heading_to_compass(theta: float, declination_deg: float) -> float:
    """Filter heading (rad, counter-clockwise from east) to magnetic compass degrees in
    [0, 360)."""
    deg = 90.0 - math.degrees(theta) - declination_deg
    deg = deg % 360.0
    if deg >= 360.0:  # -1e-17 % 360.0 rounds to 360.0
        deg = 0.0
    return deg
