"""Shared pieces of the ``landmark-db`` commands: query areas and landmark rows."""

from __future__ import annotations

import argparse
import math
import sys
import unicodedata

import numpy as np

from guidance.errors import UserError, number
from landmark_db.recognise import RecogniserConfig
from landmark_db.store import LandmarkDb

_REC = RecogniserConfig()


def safe(text: object) -> str:
    """Text from a file made safe for a terminal: control and format characters (escape
    sequences, line breaks, bidi overrides) shown as Python escapes, never sent raw."""
    return "".join(
        ch.encode("unicode_escape").decode("ascii") if unicodedata.category(ch)[0] == "C" else ch
        for ch in str(text)
    )


def out(text: str = "") -> None:
    """One line of a command's output on stdout (flushed: ``match`` streams its records)."""
    sys.stdout.write(text + "\n")
    sys.stdout.flush()


def err(text: str) -> None:
    """One line on stderr."""
    sys.stderr.write(text + "\n")


HEADER = (
    f"{'id':>6}  {'name':<24} {'lat':>11} {'lon':>11} {'x_m':>10} {'y_m':>10} {'facing':>6}"
    f" {'photos':>6}"
)


def print_landmark_row(
    lm_id: int, db: LandmarkDb, extra: str = "", photos: int | None = None
) -> None:
    lm = db.get(lm_id)
    if lm is None:
        return
    n = len(db.photos(lm_id)) if photos is None else photos
    facing = "-" if lm.facing_deg is None else f"{lm.facing_deg:.0f}"
    out(
        f"{lm.id:>6}  {safe(lm.name):<24.24} {lm.lat_deg:11.6f} {lm.lon_deg:11.6f}"
        f" {lm.x_m:10.1f} {lm.y_m:10.1f} {facing:>6} {n:>6} {extra}"
    )


def ellipse_cov(semi_major_m: float, semi_minor_m: float, angle_deg: float) -> np.ndarray:
    """Covariance whose 2-sigma ellipse has these semi-axes, major axis ``angle_deg`` from x."""
    a = math.radians(angle_deg)
    rot = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
    d = np.diag([(semi_major_m / 2.0) ** 2, (semi_minor_m / 2.0) ** 2])
    return np.asarray(rot @ d @ rot.T)


def position(db: LandmarkDb, args: argparse.Namespace) -> tuple[float, float]:
    if args.latlon:
        return db.origin.to_local(*args.latlon)
    if args.at:
        return float(args.at[0]), float(args.at[1])
    raise UserError("give a position: --at X Y or --latlon LAT LON")


def area(
    db: LandmarkDb, args: argparse.Namespace
) -> tuple[tuple[float, float], list[list[float]], float]:
    """(mean, covariance, range) of a query from --at/--latlon with --radius/--cov/--ellipse."""
    mean = position(db, args)
    if args.cov:
        pxx, pxy, pyy = args.cov
        cov = np.array([[pxx, pxy], [pxy, pyy]], dtype=np.float64)
        if not (pxx >= 0 and pyy >= 0 and pxx * pyy - pxy * pxy >= 0):
            raise UserError("--cov must be a positive semi-definite covariance")
        return mean, cov.tolist(), args.range
    if args.ellipse:
        major, minor, angle = args.ellipse
        if not (major >= minor >= 0):
            raise UserError("--ellipse needs SEMI_MAJOR >= SEMI_MINOR >= 0")
        return mean, ellipse_cov(major, minor, angle).tolist(), args.range
    return mean, [[0.0, 0.0], [0.0, 0.0]], args.radius


def area_args(p: argparse.ArgumentParser, radius_default: float | None = None) -> None:
    p.add_argument("--at", nargs=2, type=number, metavar=("X", "Y"), help="local metres")
    p.add_argument("--latlon", nargs=2, type=number, metavar=("LAT", "LON"))
    g = p.add_mutually_exclusive_group()
    g.add_argument(
        "--radius",
        type=number,
        default=_REC.sighting_range_m if radius_default is None else radius_default,
        help="metres (a circle)",
    )
    g.add_argument(
        "--cov",
        nargs=3,
        type=number,
        metavar=("PXX", "PXY", "PYY"),
        help="x-y covariance (m^2); gate = its 2-sigma ellipse plus --range",
    )
    g.add_argument(
        "--ellipse",
        nargs=3,
        type=number,
        metavar=("A", "B", "ANGLE_DEG"),
        help="2-sigma ellipse semi-axes (m) and major-axis angle from east (deg)",
    )
    p.add_argument(
        "--range",
        type=number,
        default=_REC.sighting_range_m,
        help="camera sighting range added to the ellipse (m, default %(default)s)",
    )
    p.add_argument("--limit", type=int, default=None, help="at most this many candidates")
