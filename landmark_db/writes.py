"""Writing landmarks: the part of ``LandmarkDb`` that adds, updates and removes landmark rows
and their index boxes, every value within ``landmark_db.limits`` (the car's read-only open
refuses a file holding anything else), and ``batch`` (one transaction around many writes)."""

from __future__ import annotations

import hashlib
import unicodedata
from collections.abc import Iterator, Sequence
from contextlib import contextmanager

import numpy as np

from guidance.core.geo import Origin
from landmark_db import global_index
from landmark_db.features import Features
from landmark_db.limits import (
    MAX_NAME_CHARS,
    agreement_problem,
    position_problem,
    sigma_problem,
)
from landmark_db.photos import PhotoStore, _check_text, _finite, _utc_now
from landmark_db.schema import LandmarkDbError

DEFAULT_POSITION_SIGMA_M = 3.0
"""1-sigma of a surveyed landmark position when the source gives none (consumer GPS)."""


class LandmarkWriter(PhotoStore):
    """Mixin of ``LandmarkDb``: landmark rows. Uses ``origin`` and what ``PhotoStore`` uses."""

    origin: Origin

    def add(
        self,
        name: str,
        image: np.ndarray | bytes,
        *,
        lat_deg: float | None = None,
        lon_deg: float | None = None,
        x_m: float | None = None,
        y_m: float | None = None,
        facing_deg: float | None = None,
        position_sigma_m: float = DEFAULT_POSITION_SIGMA_M,
        source: str = "",
        image_format: str = ".png",
        conditions: str = "",
    ) -> int:
        """Add a landmark with its first photo (encoded bytes or an array); returns its id.

        Give either lat/lon or local x/y; the other pair is computed from the origin.
        Raises ``LandmarkDbError`` for a bad position or an undecodable image.
        """
        self._writable()
        _check_name(name)
        lat, lon, x, y = self._position(lat_deg, lon_deg, x_m, y_m)
        sigma = _sigma(position_sigma_m)
        facing = None if facing_deg is None else _finite("facing", facing_deg) % 360.0
        _check_text(conditions, source)
        data, pixels, fmt, feats = self._encoded(f"landmark {name!r}", image, image_format)
        with self._lock, self._tx():
            cur = self._conn.execute(
                "INSERT INTO landmarks (name, lat_deg, lon_deg, x_m, y_m, facing_deg,"
                " position_sigma_m, added_utc, source) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?)",
                (name, lat, lon, x, y, facing, sigma, _utc_now(), source),
            )
            lid = cur.lastrowid
            assert lid is not None
            self._insert_photo(lid, data, pixels, fmt, feats, facing, conditions, source)
            self._conn.execute(
                "INSERT INTO landmark_index VALUES (?, ?, ?, ?, ?)", (lid, x, x, y, y)
            )
        return int(lid)

    def _position(
        self, lat_deg: float | None, lon_deg: float | None, x_m: float | None, y_m: float | None
    ) -> tuple[float, float, float, float]:
        """(lat, lon, x, y) from either pair, within ``limits`` (the car's read-only open
        refuses a file holding anything else)."""
        if lat_deg is not None and lon_deg is not None:
            lat, lon = _finite("lat", lat_deg), _finite("lon", lon_deg)
            if not (-90.0 <= lat <= 90.0 and -180.0 <= lon <= 180.0):
                raise LandmarkDbError(f"lat/lon {lat}, {lon} out of range")
            x, y = self.origin.to_local(lat, lon)
        elif x_m is not None and y_m is not None:
            x, y = _finite("x", x_m), _finite("y", y_m)
            why = position_problem(x, y)
            if why is not None:  # before the conversion, which has no meaning that far
                raise LandmarkDbError(why)
            lat, lon = self.origin.to_geodetic(x, y)
        else:
            raise LandmarkDbError("give a position: lat and lon, or x and y")
        why = position_problem(x, y)
        if why is None:
            ex, ey = self.origin.to_local(lat, lon)
            why = agreement_problem(ex - x, ey - y)
        if why is not None:
            raise LandmarkDbError(why)
        return lat, lon, x, y

    def update(
        self,
        landmark_id: int,
        *,
        lat_deg: float | None = None,
        lon_deg: float | None = None,
        x_m: float | None = None,
        y_m: float | None = None,
        facing_deg: float | None = None,
        position_sigma_m: float = DEFAULT_POSITION_SIGMA_M,
        source: str = "",
    ) -> None:
        """A landmark's new position, facing and sigma (its index box moves with it)."""
        self._writable()
        lat, lon, x, y = self._position(lat_deg, lon_deg, x_m, y_m)
        sigma = _sigma(position_sigma_m)
        facing = None if facing_deg is None else _finite("facing", facing_deg) % 360.0
        with self._lock, self._tx():
            n = self._conn.execute(
                "UPDATE landmarks SET lat_deg = ?, lon_deg = ?, x_m = ?, y_m = ?, facing_deg = ?,"
                " position_sigma_m = ?, source = ? WHERE id = ?",
                (lat, lon, x, y, facing, sigma, source, landmark_id),
            ).rowcount
            if n == 0:
                raise LandmarkDbError(f"no landmark {landmark_id}")
            self._conn.execute("DELETE FROM landmark_index WHERE id = ?", (landmark_id,))
            self._conn.execute(
                "INSERT INTO landmark_index VALUES (?, ?, ?, ?, ?)", (landmark_id, x, x, y, y)
            )

    @contextmanager
    def batch(self) -> Iterator[None]:
        """One transaction around many writes: all of them are in the file, or none (an
        error or a kill rolls every one back)."""
        self._writable()
        with self._lock:
            if self._in_batch:
                yield
                return
            self._in_batch = True
            try:
                with self._conn:
                    yield
            finally:
                self._in_batch = False

    def add_many_precomputed(
        self,
        rows: Sequence[tuple[str, float, float]],
        features: Features,
        image_data: bytes,
        position_sigma_m: float = 0.0,
        index: bool = True,
    ) -> None:
        """Bulk insert (name, x, y) landmarks sharing one photo and its features.

        For benchmarks and simulated cities of many landmarks, where describing a photo
        per landmark would dominate; positions are local metres. ``features`` must come
        from this file's extractor. The global index is rebuilt once at the end (``index``;
        a caller making many such calls passes False and calls ``rebuild_global_index``).
        """
        self._writable()
        digest = hashlib.sha256(image_data).hexdigest()
        now = _utc_now()
        with self._lock, self._conn:
            for name, x, y in rows:
                lat, lon = self.origin.to_geodetic(x, y)
                cur = self._conn.execute(
                    "INSERT INTO landmarks (name, lat_deg, lon_deg, x_m, y_m, facing_deg,"
                    " position_sigma_m, added_utc, source) VALUES (?, ?, ?, ?, ?, NULL, ?, ?, ?)",
                    (name, lat, lon, x, y, position_sigma_m, now, "bulk"),
                )
                lid = cur.lastrowid
                cur = self._conn.execute(
                    "INSERT INTO photos (landmark_id, format, width, height, sha256, data,"
                    " added_utc, source) VALUES (?, 'png', ?, ?, ?, ?, ?, 'bulk')",
                    (lid, features.width, features.height, digest, image_data, now),
                )
                assert cur.lastrowid is not None
                self._insert_features(cur.lastrowid, features, index=False)
                self._conn.execute(
                    "INSERT INTO landmark_index VALUES (?, ?, ?, ?, ?)", (lid, x, x, y, y)
                )
            if rows and index:  # one vocabulary and encoding for the whole bulk insert
                global_index.rebuild(self._conn, self.extractor)

    def rename(self, landmark_id: int, name: str) -> None:
        """A landmark's new name (checked as ``add`` checks one)."""
        self._writable()
        _check_name(name)
        with self._lock, self._tx():
            n = self._conn.execute(
                "UPDATE landmarks SET name = ? WHERE id = ?", (name, landmark_id)
            ).rowcount
            if n == 0:
                raise LandmarkDbError(f"no landmark {landmark_id}")

    def remove(self, landmark_id: int) -> bool:
        """Delete a landmark with its photos, features and index row; False if absent."""
        self._writable()
        with self._lock, self._tx():
            n = self._conn.execute("DELETE FROM landmarks WHERE id = ?", (landmark_id,)).rowcount
            self._conn.execute(
                "DELETE FROM photo_features WHERE photo_id IN"
                " (SELECT id FROM photos WHERE landmark_id = ?)",
                (landmark_id,),
            )
            self._conn.execute("DELETE FROM photos WHERE landmark_id = ?", (landmark_id,))
            self._conn.execute("DELETE FROM landmark_index WHERE id = ?", (landmark_id,))
        return n > 0


def name_problem(name: str) -> str | None:
    """Why ``name`` cannot be a landmark's, or None."""
    if not name.strip():
        return "a landmark needs a name"
    if len(name) > MAX_NAME_CHARS:
        return f"a landmark name has at most {MAX_NAME_CHARS} characters"
    if any(unicodedata.category(ch)[0] == "C" for ch in name):
        return f"landmark name {name!r} holds control characters"
    if name.strip().isdigit():  # `remove DB 1` would take it for landmark id 1 (issue 40)
        return f"landmark name {name!r} is all digits: the tools would read it as an id"
    return None


def _check_name(name: str) -> None:
    why = name_problem(name)
    if why is not None:
        raise LandmarkDbError(why)


def _sigma(value: float) -> float:
    sigma = _finite("position sigma", value)
    why = sigma_problem(sigma)
    if why is not None:
        raise LandmarkDbError(why)
    return sigma
