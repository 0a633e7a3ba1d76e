"""The one 2-sigma ellipse drawing (guidance.tools.plotting), on matplotlib's Agg backend."""

from __future__ import annotations

import math

import matplotlib
import pytest

from guidance.tools.plotting import covariance_patch, ellipse_patch

matplotlib.use("Agg")


def test_the_patch_spans_the_full_axes_at_the_heading_s_angle() -> None:
    p = ellipse_patch(10.0, 20.0, 30.0, 5.0, math.pi / 2, color="red", label="x")
    assert p.center == (10.0, 20.0)
    assert (p.width, p.height, p.angle) == (60.0, 10.0, pytest.approx(90.0))
    assert not p.get_fill() and p.get_label() == "x"


def test_a_covariance_gives_its_2_sigma_axes() -> None:
    # sigma_x 10 m, sigma_y 5 m: 2-sigma semi-axes sqrt(chi2_2(86.5 %) = 4) * sigma = 20 and 10
    p = covariance_patch(0.0, 0.0, [[100.0, 0.0], [0.0, 25.0]])
    assert (p.width, p.height) == (pytest.approx(40.0), pytest.approx(20.0))
    assert p.angle == pytest.approx(0.0, abs=1e-9)
