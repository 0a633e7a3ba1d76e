"""Landmarks in the car: the ``[landmarks]`` table, the database opened read-only, and the
real recogniser (the same one the simulator runs), built off the event loop.

``[landmarks] database = "landmarks.sqlite"`` (relative to the config file) turns on landmark
updates in ``guidance run``: every landmark of the database becomes a navigator landmark (its
name is what the driver hears), and camera frames are matched against the ones the current
estimate gates in. Today's ``[[landmarks]]`` array (positions only, no photos) still works.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from guidance.app.ports import Recogniser
from guidance.core.geo import Origin
from guidance.core.plan.navigator import Landmark
from guidance.errors import UserError

RECOGNISER = "landmark_db.recognise:Recogniser"
RECOGNISER_CONFIG = "landmark_db.recognise:RecogniserConfig"
OPEN_DB = "landmark_db.store:open_db"


@dataclass(frozen=True, slots=True)
class LandmarkSettings:
    """The ``[landmarks]`` table."""

    database: str
    """Path of the landmark database (``landmark-db``), read-only in the car."""
    sighting_range_m: float = 20.0
    """The camera recognises a landmark photo from at most this far."""
    confirm_frames: int = 2
    """Consecutive frames that must verify the same landmark before a fix."""
    max_candidates: int = 5
    """At most this many gated landmarks are compared per frame (the time budget)."""


def parse_landmarks_table(table: Mapping[str, Any], base_dir: Path | None) -> LandmarkSettings:
    """Validate ``[landmarks]``: a database path (relative to the config) and matcher settings."""
    known = {"database", "sighting_range_m", "confirm_frames", "max_candidates"}
    unknown = sorted(set(table) - known)
    if unknown:
        raise UserError(f"[landmarks] unknown key(s): {', '.join(unknown)}")
    db = table.get("database")
    if not isinstance(db, str) or not db:
        raise UserError("[landmarks] database must be the path of a landmark database")
    path = Path(db)
    if not path.is_absolute() and base_dir is not None:
        path = base_dir / path
    rng = table.get("sighting_range_m", 20.0)
    if isinstance(rng, bool) or not isinstance(rng, int | float) or not 1.0 <= rng <= 500.0:
        raise UserError(f"[landmarks] sighting_range_m must be 1-500 m, not {rng!r}")
    ints = {}
    for key, default, hi in (("confirm_frames", 2, 20), ("max_candidates", 5, 50)):
        v = table.get(key, default)
        if isinstance(v, bool) or not isinstance(v, int) or not 1 <= v <= hi:
            raise UserError(f"[landmarks] {key} must be an integer 1-{hi}, not {v!r}")
        ints[key] = v
    return LandmarkSettings(str(path), float(rng), ints["confirm_frames"], ints["max_candidates"])


def _import(path: str) -> Any:
    from guidance.app.backends import import_backend

    return import_backend(path)


def _open_read_only(settings: LandmarkSettings) -> Any:
    """The database opened as the car opens it; a missing or damaged file is one line."""
    if not Path(settings.database).is_file():
        raise UserError(f"[landmarks] database {settings.database}: no such file")
    try:
        return _import(OPEN_DB)(settings.database, readonly=True)
    except Exception as exc:  # the store reports damage as one line (LandmarkDbError)
        raise UserError(f"[landmarks] database {settings.database}: {exc}") from None


def check_database(settings: LandmarkSettings) -> int:
    """Open the database read-only as the car will (``--check``); returns its landmark count."""
    db = _open_read_only(settings)
    try:
        return sum(1 for _ in db.landmarks())
    finally:
        db.close()


def open_landmarks(
    settings: LandmarkSettings, origin_lat_lon: tuple[float, float] | None
) -> tuple[Recogniser, tuple[Landmark, ...]]:
    """The recogniser on the database and its landmarks in the car's local frame.

    Slow (features are loaded, the matcher built): call it off the event loop. Positions come
    from each landmark's latitude/longitude around the car's ``[start]`` when it has one, else
    from the database's own local metres (the car's start must then be the database's origin).
    """
    db = _open_read_only(settings)
    config = _import(RECOGNISER_CONFIG)(
        sighting_range_m=settings.sighting_range_m,
        confirm_frames=settings.confirm_frames,
        max_candidates=settings.max_candidates,
    )
    recogniser: Recogniser = _import(RECOGNISER)(db, config)
    out = []
    for lm in db.landmarks():
        x, y = float(lm.x_m), float(lm.y_m)
        if origin_lat_lon is not None:
            x, y = Origin.of(origin_lat_lon).to_local(float(lm.lat_deg), float(lm.lon_deg))
        if math.isfinite(x) and math.isfinite(y):
            out.append(Landmark(int(lm.id), x, y, str(lm.name)))
    return recogniser, tuple(out)


def landmark_warnings(cfg: Any) -> list[str]:
    """What ``--check`` says about landmarks: a camera whose frames can never produce a fix,
    a database nothing will ever match against; a damaged database is an error."""
    out = []
    if cfg.landmark_db is not None:
        n = check_database(cfg.landmark_db)
        if cfg.camera is None:
            out.append(
                f"[landmarks] database {cfg.landmark_db.database} ({n} landmarks) but no "
                "[camera] enabled: no landmark will ever be sighted"
            )
    elif cfg.camera is not None:
        out.append(
            "[camera] is enabled but there is no [landmarks] database: its frames can never "
            "produce a landmark fix"
        )
    if cfg.landmark_db is not None and cfg.camera is not None:
        from guidance.core.messages import reset_sigma_m

        across = 4.0 * reset_sigma_m(cfg.landmark_db.sighting_range_m, 0.0)
        lost = cfg.pipeline.estimator.lost_major_axis_m
        if across >= lost:  # the places' own survey sigma comes on top
            out.append(
                f"[landmarks] sighting_range_m = {cfg.landmark_db.sighting_range_m:g}: a place "
                f"found while lost leaves the position {across:.0f} m across, over [estimator] "
                f"lost_major_axis_m = {lost:g}, so a lost car can never find itself again; "
                f"keep it below {lost / 4.0:g} m less the places' survey sigma"
            )
    return out
