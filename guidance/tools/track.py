"""The estimate as a CSV track, one row per odometry step (``guidance replay --track``).

Columns (``guidance evaluate`` reads them): ``t_s`` in the input logs' own time base,
``east_m``/``north_m`` local metres from the configured start, ``heading_deg`` clockwise from
true north, the position covariance (``var_east_m2``, ``cov_east_north_m2``, ``var_north_m2``)
and ``major_axis_m``, the full major axis of the 2-sigma ellipse (d^2 = 4).
"""

from __future__ import annotations

import csv
from pathlib import Path
from typing import TextIO

from guidance.core.angles import heading_to_compass
from guidance.core.messages import EstimateState
from guidance.errors import UserError

COLUMNS = (
    "t_s",
    "east_m",
    "north_m",
    "heading_deg",
    "var_east_m2",
    "cov_east_north_m2",
    "var_north_m2",
    "major_axis_m",
)


def compass_deg(heading_rad: float) -> float:
    """Filter heading (CCW from east, rad) as a true heading (clockwise from north, degrees)."""
    return float(heading_to_compass(heading_rad, 0.0))  # true: no declination


class TrackWriter:
    """Writes one row per estimate; ``close`` flushes."""

    def __init__(self, path: Path) -> None:
        try:
            self._file: TextIO = path.open("w", newline="", encoding="utf-8")
        except OSError as exc:
            raise UserError(f"--track {path}: {exc.strerror or exc}") from None
        self._csv = csv.writer(self._file)
        self._csv.writerow(COLUMNS)
        self.rows = 0

    def write(self, st: EstimateState) -> None:
        P = st.covariance
        self._csv.writerow(
            (
                f"{st.t_s:.6f}",
                f"{st.x_m:.4f}",
                f"{st.y_m:.4f}",
                f"{compass_deg(st.heading_rad):.4f}",
                f"{P[0][0]:.6g}",
                f"{P[0][1]:.6g}",
                f"{P[1][1]:.6g}",
                f"{st.ellipse.major_axis_m:.4f}",
            )
        )
        self.rows += 1

    def close(self) -> None:
        self._file.close()
