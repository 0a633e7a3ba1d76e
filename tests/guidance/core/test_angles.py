"""The plain angle functions (``guidance.core.angles``) and their numba compilation
(``guidance.core.model``) are one definition: the same results, bit for bit."""

from __future__ import annotations

import math

from hypothesis import given, settings
from hypothesis import strategies as st

from guidance.core import angles, model

ANGLES = st.floats(-1e6, 1e6, allow_nan=False) | st.sampled_from(
    [math.pi, -math.pi, 2 * math.pi, -1e-17, 0.0, 3 * math.pi, -3 * math.pi]
)


@settings(max_examples=300, deadline=None)
@given(ANGLES)
def test_wrap_angle_compiled_and_plain_agree(a: float) -> None:
    w = angles.wrap_angle(a)
    assert w == model.wrap_angle(a)
    assert -math.pi < w <= math.pi


@settings(max_examples=300, deadline=None)
@given(ANGLES, st.floats(-30.0, 30.0))
def test_heading_to_compass_compiled_and_plain_agree(theta: float, decl: float) -> None:
    c = angles.heading_to_compass(theta, decl)
    assert c == model.heading_to_compass(theta, decl)
    assert 0.0 <= c < 360.0
