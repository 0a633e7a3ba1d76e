"""A car's own odometry as a speed and yaw-rate CSV, for ``guidance replay`` (issue 38).

Some data sets give a car's odometry as its CAN speed and its stability control's yaw rate
rather than as CAN frames (the shared smartLoc Berlin drive:
``t,speed_mps,yaw_rate_rad_s``, Unix seconds, counter-clockwise positive). Each row closes
the interval since the previous one: the distance is the trapezoid of the two speeds (as the
wheel decoder integrates wheel speeds), given to both wheels, and the yaw rate is a
``YawRate`` reading, sent before the distance of the same time so the step that uses it has
it. For a car whose ``yaw_source`` is "wheels" the yaw rate is split into a left/right wheel
difference over the track instead (``v -/+ yaw_rate x track / 2``, what the shared drive's
re-encoded CAN log does), so the two models can be compared on the same file.

Read through ``guidance.files`` (kind ``odometry_csv``) and the truth CSV's column parser
(``guidance.tools.evaluate.columns_from``): bounded lines, strict numbers, one error naming
file and line. Rows out of time order, a speed beyond ``MAX_SPEED_MPS`` or a yaw rate beyond
``MAX_YAW_RATE_RAD_S`` are refused with the line, never fed.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from pathlib import Path

from guidance import files
from guidance.core.messages import WheelOdometry, YawRate
from guidance.errors import UserError

COLUMNS = ("t", "speed_mps")
YAW_COLUMN = "yaw_rate_rad_s"
MAX_SPEED_MPS = 100.0
"""360 km/h: a faster row is a unit mistake (km/h read as m/s is still below it at 100 m/s,
but the distance then disagrees with the truth by 3.6 times, which evaluate shows)."""
MAX_YAW_RATE_RAD_S = 5.0
"""About 290 deg/s, beyond the measuring range of ESC yaw-rate sensors (100-300 deg/s): a
larger value is deg/s read as rad/s or a damaged row."""
MAX_GAP_S = 2.0
"""Rows further apart than this close no interval (the log paused): the next row starts
over."""


def is_odometry_csv(path: Path) -> bool:
    """A speed and yaw-rate CSV is named ``*.csv``; everything else is a CAN log."""
    return path.suffix.lower() == ".csv"


def read_odometry_csv(path: Path) -> dict[str, list[float]]:
    """The columns ``t``, ``speed_mps`` and (if there) ``yaw_rate_rad_s``; UserError naming
    the file and line on anything else."""
    from guidance.tools.evaluate import columns_from

    with files.opened(path, "odometry_csv") as raw:
        cols, lines = columns_from(raw, path, "odometry", COLUMNS, (YAW_COLUMN,))
    t, v = cols["t"], cols["speed_mps"]
    w = cols.get(YAW_COLUMN)
    for i in range(len(t)):
        if i and t[i] <= t[i - 1]:
            raise UserError(f"{path}: line {lines[i]}: time {t[i]} is not after {t[i - 1]}")
        if abs(v[i]) > MAX_SPEED_MPS:
            raise UserError(f"{path}: line {lines[i]}: speed {v[i]} m/s is beyond +-100 m/s")
        if w is not None and abs(w[i]) > MAX_YAW_RATE_RAD_S:
            raise UserError(
                f"{path}: line {lines[i]}: yaw rate {w[i]} rad/s is beyond +-5 rad/s "
                "(is it in deg/s?)"
            )
    out = {"t": t.tolist(), "speed_mps": v.tolist()}
    if w is not None:
        out[YAW_COLUMN] = w.tolist()
    return out


def odometry_inputs(path: Path, *, gyro: bool, track_m: float) -> Iterator[WheelOdometry | YawRate]:
    """The file's rows as the estimator's inputs (module doc): with ``gyro`` a ``YawRate``
    then the distance of each row; without, the yaw rate as a wheel difference over
    ``track_m``. A file without the yaw-rate column drives straight (said by the caller)."""
    if not (math.isfinite(track_m) and track_m > 0.0):
        raise UserError(f"track width {track_m} m must be a finite number > 0")
    cols = read_odometry_csv(path)
    t, v = cols["t"], cols["speed_mps"]
    w = cols.get(YAW_COLUMN, [0.0] * len(t))
    for i in range(len(t)):
        if gyro and YAW_COLUMN in cols:
            yield YawRate(t[i], w[i])
        if i == 0 or t[i] - t[i - 1] > MAX_GAP_S:
            continue
        dt = t[i] - t[i - 1]
        d = 0.5 * (v[i - 1] + v[i]) * dt
        if gyro:
            yield WheelOdometry(t[i], d, d)
            continue
        half = 0.25 * (w[i - 1] + w[i]) * dt * track_m  # the mean yaw rate x track / 2
        yield WheelOdometry(t[i], d - half, d + half)


def first_time(path: Path) -> float:
    """The first row's time (the log's time base, for the declination and learned files)."""
    t = read_odometry_csv(path)["t"]
    return float(t[0])
