"""WGS-84 <-> local east-north metres around an origin: the one place pymap3d is called
(HOUSE_STYLE: wrap a third-party library once).

The local frame is east-north-up with its origin at ``Origin``'s latitude/longitude (height
``alt_m``); x is east, y is north, in metres. The car's config (``[start]``), the output
encoders (latitude/longitude in state messages), the landmark database and the simulator all
use this ``Origin``.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

LatLon = tuple[float, float]
"""(latitude, longitude) in degrees, WGS-84."""


@dataclass(frozen=True, slots=True)
class Origin:
    """The geodetic origin of a local frame (degrees, metres)."""

    lat_deg: float
    lon_deg: float
    alt_m: float = 0.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.lat_deg) and -90.0 <= self.lat_deg <= 90.0):
            raise ValueError(f"origin latitude {self.lat_deg!r} is not in [-90, 90]")
        if not (math.isfinite(self.lon_deg) and -180.0 <= self.lon_deg <= 180.0):
            raise ValueError(f"origin longitude {self.lon_deg!r} is not in [-180, 180]")

    @classmethod
    def of(cls, lat_lon: LatLon) -> Origin:
        return cls(float(lat_lon[0]), float(lat_lon[1]))

    @classmethod
    def checked(cls, lat_lon: LatLon) -> Origin:
        """``of`` for a value from a config: ``UserError`` (one line) when out of range."""
        from guidance.errors import UserError

        try:
            return cls.of(lat_lon)
        except ValueError as exc:
            raise UserError(str(exc)) from None

    def to_local(self, lat_deg: float, lon_deg: float) -> tuple[float, float]:
        """Latitude/longitude (degrees) -> local (x east, y north) metres."""
        return _to_local(float(lat_deg), float(lon_deg), self.lat_deg, self.lon_deg, self.alt_m)

    def to_geodetic(self, x_m: float, y_m: float) -> LatLon:
        """Local (x east, y north) metres -> latitude/longitude (degrees)."""
        return _to_geodetic(float(x_m), float(y_m), self.lat_deg, self.lon_deg, self.alt_m)


@functools.lru_cache(maxsize=256)
def _to_local(lat: float, lon: float, lat0: float, lon0: float, alt: float) -> tuple[float, float]:
    import pymap3d

    e, n, _u = pymap3d.geodetic2enu(lat, lon, alt, lat0, lon0, alt)
    return float(e), float(n)


@functools.lru_cache(maxsize=256)
def _to_geodetic(x: float, y: float, lat0: float, lon0: float, alt: float) -> LatLon:
    """pymap3d's ENU -> WGS-84 (about 0.13 ms). Cached: the goal and the target stay the same
    from one state message to the next, and telemetry and the recorder each build the same one."""
    import pymap3d

    lat, lon, _h = pymap3d.enu2geodetic(x, y, 0.0, lat0, lon0, alt)
    return float(lat), float(lon)
