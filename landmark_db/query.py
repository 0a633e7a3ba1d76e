"""Candidate queries: the landmarks the camera could be seeing (SPEC section 2; ``gate``)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from guidance.core.model import CHI2_2D_2SIGMA
from landmark_db.gate import gate_box, in_gate, mahalanobis_sq


@dataclass(frozen=True, slots=True)
class Candidate:
    """A landmark that passed the gate, with its distance (m) to the 2-sigma ellipse."""

    id: int
    x_m: float
    y_m: float
    distance_m: float


class BoxIndex(Protocol):
    """What a query needs of the store (``LandmarkDb.in_box``, its R*Tree): a protocol, so
    this module does not import the store that imports it (no import circle)."""

    def in_box(
        self, min_x: float, max_x: float, min_y: float, max_y: float
    ) -> tuple[np.ndarray, np.ndarray]: ...


def query_gate(
    db: BoxIndex,
    mean_xy: Sequence[float],
    cov_xy: Sequence[Sequence[float]],
    range_m: float,
    k2: float = CHI2_2D_2SIGMA,
    limit: int | None = None,
) -> list[Candidate]:
    """Landmarks within ``range_m`` of the ``k2`` ellipse, nearest first (``landmark_db.gate``);
    those inside the ellipse by Mahalanobis distance from the mean.

    R*Tree box first, then the exact distance-to-ellipse test on what the box returned.
    """
    ids, xy = db.in_box(*gate_box(mean_xy, cov_xy, k2, range_m))
    if len(ids) == 0:
        return []
    mask, dist = in_gate(xy, mean_xy, cov_xy, k2, range_m)
    keep = np.flatnonzero(mask)
    # Nearest to the ellipse first; inside it (distance 0), most likely first (Mahalanobis).
    d2 = mahalanobis_sq(xy[keep], mean_xy, cov_xy)
    keep = keep[np.lexsort((ids[keep], d2, dist[keep]))]
    if limit is not None:
        keep = keep[:limit]
    return [Candidate(int(ids[i]), float(xy[i, 0]), float(xy[i, 1]), float(dist[i])) for i in keep]


def query_radius(db: BoxIndex, x_m: float, y_m: float, radius_m: float) -> list[Candidate]:
    """Landmarks within ``radius_m`` of a point, nearest first (distance is to the point)."""
    return query_gate(db, (x_m, y_m), ((0.0, 0.0), (0.0, 0.0)), radius_m)
