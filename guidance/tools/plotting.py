"""The one way a 2-sigma ellipse is drawn (matplotlib, loaded when a picture is made): the fleet
monitor's PNG snapshot (``guidance.tools.monitor``) and a simulated drive's picture
(``hal_sim.plots``) use it."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

from guidance.core import model


def ellipse_patch(
    x: float, y: float, semi_major_m: float, semi_minor_m: float, orientation_rad: float,
    **style: Any,
) -> Any:  # fmt: skip
    """An unfilled matplotlib ``Ellipse`` for a 2-sigma ellipse (semi-axes, major axis angle
    counter-clockwise from east, as ``EstimateState.ellipse`` and ``model.ellipse_axes`` give
    them); ``style``: matplotlib's (color, lw, alpha, label...)."""
    from matplotlib.patches import Ellipse

    return Ellipse(
        (x, y), 2 * semi_major_m, 2 * semi_minor_m, angle=math.degrees(orientation_rad),
        fill=False, **style,
    )  # fmt: skip


def covariance_patch(x: float, y: float, P: Sequence[Sequence[float]], **style: Any) -> Any:
    """The 2-sigma ellipse of a 2x2 position covariance (``model.ellipse_axes``)."""
    a, b, ang = model.ellipse_axes(P[0][0], P[0][1], P[1][1], model.CHI2_2D_2SIGMA)
    return ellipse_patch(x, y, a, b, ang, **style)
