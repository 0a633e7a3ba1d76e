"""Geodetic <-> local east-north conversion around a database origin (SPEC section 7).

Wraps pymap3d in one place. The local frame is east-north-up with its origin at the
database's origin latitude/longitude (height 0); x is east, y is north, in metres.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import pymap3d


@dataclass(frozen=True, slots=True)
class Origin:
    """The geodetic origin of a database's local frame (degrees, metres)."""

    lat_deg: float
    lon_deg: float
    alt_m: float = 0.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.lat_deg) and -90.0 <= self.lat_deg <= 90.0):
            raise ValueError(f"origin latitude {self.lat_deg!r} is not in [-90, 90]")
        if not (math.isfinite(self.lon_deg) and -180.0 <= self.lon_deg <= 180.0):
            raise ValueError(f"origin longitude {self.lon_deg!r} is not in [-180, 180]")

    def to_local(self, lat_deg: float, lon_deg: float) -> tuple[float, float]:
        """Latitude/longitude (degrees) -> local (x east, y north) metres."""
        e, n, _u = pymap3d.geodetic2enu(
            lat_deg, lon_deg, self.alt_m, self.lat_deg, self.lon_deg, self.alt_m
        )
        return float(e), float(n)

    def to_geodetic(self, x_m: float, y_m: float) -> tuple[float, float]:
        """Local (x east, y north) metres -> latitude/longitude (degrees)."""
        lat, lon, _h = pymap3d.enu2geodetic(x_m, y_m, 0.0, self.lat_deg, self.lon_deg, self.alt_m)
        return float(lat), float(lon)
