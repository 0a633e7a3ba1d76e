"""Magnetic declination from the World Magnetic Model.

pygeomag (a port of NOAA's reference C code) ships the WMM coefficient files from WMM-2010 to
WMM-2025; the model whose 5-year life span holds the date is chosen, so old logs get the model
of their day and today's drives get WMM-2025 (valid 2025.0-2030.0, released 11/13/2024).

The reading -> filter heading conversion is
``guidance.core.localize.compass_cal.compass_heading_to_theta`` (the pipeline's); this module
gives it the declination of the place and date.
"""

from __future__ import annotations

import datetime as dt
import functools
import logging
import math

from pygeomag import GeoMag, decimal_year_from_date

from guidance.errors import UserError

log = logging.getLogger(__name__)

# Coefficient files shipped by pygeomag 1.1, by first year of validity.
_MODELS = {
    2010: "wmm/WMM_2010.COF",
    2015: "wmm/WMM_2015v2.COF",
    2020: "wmm/WMM_2020.COF",
    2025: "wmm/WMM_2025.COF",
}


@functools.cache
def _geomag(epoch: int) -> GeoMag:
    return GeoMag(coefficients_file=_MODELS[epoch])


def _decimal_year(when: dt.date | dt.datetime | float) -> float:
    if isinstance(when, dt.datetime | dt.date):
        return float(decimal_year_from_date(when))
    if isinstance(when, int | float) and math.isfinite(when):
        return float(when)
    raise UserError(f"date must be a date or a decimal year, not {when!r}")


def wmm_model_for(when: dt.date | dt.datetime | float) -> str:
    """Name of the WMM release used for a date (e.g. 'WMM-2025')."""
    return str(_geomag(_epoch(_decimal_year(when))).model)


def _epoch(year: float) -> int:
    epoch = 5 * int(year // 5)
    if epoch not in _MODELS:
        first, last = min(_MODELS), max(_MODELS) + 5
        raise UserError(
            f"date {year:.2f} is outside the World Magnetic Models available "
            f"({first}.0-{last}.0); update pygeomag for a newer WMM"
        )
    return epoch


def declination_deg(
    lat_deg: float, lon_deg: float, when: dt.date | dt.datetime | float, alt_m: float = 0.0
) -> float:
    """Magnetic declination (degrees, east positive) at a place and date from the WMM.

    ``alt_m`` is height above the WGS-84 ellipsoid in metres (pygeomag takes kilometres).
    Near the magnetic poles (horizontal field below 2000 nT) the value is unreliable; that is
    logged, since urban driving never gets there.
    """
    if not (math.isfinite(lat_deg) and -90.0 <= lat_deg <= 90.0):
        raise UserError(f"latitude must be within [-90, 90] degrees, not {lat_deg!r}")
    if not (math.isfinite(lon_deg) and -180.0 <= lon_deg <= 180.0):
        raise UserError(f"longitude must be within [-180, 180] degrees, not {lon_deg!r}")
    year = _decimal_year(when)
    result = _geomag(_epoch(year)).calculate(
        glat=lat_deg, glon=lon_deg, alt=alt_m / 1000.0, time=year, allow_date_outside_lifespan=True
    )
    if result.in_blackout_zone:
        log.warning("declination at %.3f, %.3f is unreliable (magnetic pole)", lat_deg, lon_deg)
    return float(result.d)
