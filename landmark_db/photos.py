"""Photos of landmarks and their features: the part of ``LandmarkDb`` that reads and writes
the ``photos`` and ``photo_features`` tables (several photos per landmark, issue 15)."""

from __future__ import annotations

import hashlib
import sqlite3
import time
from collections.abc import Iterator
from contextlib import AbstractContextManager, contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from guidance.errors import checked_number
from landmark_db import global_index
from landmark_db.features import ExtractorConfig, Features, decode_image, encode_image, extract
from landmark_db.limits import MAX_TEXT_CHARS, MIN_PHOTO_FEATURES, photo_problem
from landmark_db.schema import LandmarkDbError


@dataclass(frozen=True, slots=True)
class Photo:
    """One photo of a landmark (without its pixels); ``facing_deg`` clockwise from N."""

    id: int
    landmark_id: int
    format: str
    width: int
    height: int
    facing_deg: float | None
    conditions: str
    source: str


def _utc_now() -> str:
    return time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())


def _check_text(*texts: str) -> None:
    for text in texts:
        if len(text) > MAX_TEXT_CHARS:
            raise LandmarkDbError(f"text longer than {MAX_TEXT_CHARS} characters")


def _finite(name: str, value: float) -> float:
    return checked_number(value, name, error=LandmarkDbError)


class PhotoStore:
    """Mixin of ``LandmarkDb``: photos and their features. Uses the attributes below, which
    ``LandmarkDb`` provides."""

    _conn: sqlite3.Connection
    _lock: Any
    path: Path
    extractor: ExtractorConfig

    def _reading(self) -> AbstractContextManager[sqlite3.Connection]:
        raise NotImplementedError

    _in_batch: bool

    def _writable(self) -> None:
        raise NotImplementedError

    @contextmanager
    def _tx(self) -> Iterator[None]:
        """A write's transaction: its own (committed at the end), or the one ``batch`` holds."""
        if self._in_batch:
            yield
        else:
            with self._conn:
                yield

    def get(self, landmark_id: int) -> Any:
        raise NotImplementedError

    def stale_features(self) -> int:
        """Photos whose stored features were not made by this file's extractor (its current
        name, version and parameters): ``refresh_features`` recomputes them."""
        with self._reading() as c:
            return int(
                c.execute(
                    "SELECT count(*) FROM photos p LEFT JOIN photo_features f ON f.photo_id = p.id"
                    " WHERE f.extractor IS NULL OR f.extractor != ?",
                    (self.extractor.ident,),
                ).fetchone()[0]
            )

    def _encoded(
        self, label: str, image: np.ndarray | bytes, image_format: str
    ) -> tuple[bytes, np.ndarray, str, Features]:
        """(encoded bytes, pixels, format, features) of a photo given as bytes or an array."""
        if isinstance(image, bytes | bytearray | memoryview):
            data = bytes(image)
            try:
                pixels = decode_image(data)
            except ValueError as exc:
                raise LandmarkDbError(f"{label}: {exc}") from exc
            fmt = (
                "jpeg" if data[:2] == b"\xff\xd8" else "png" if data[:4] == b"\x89PNG" else "other"
            )
        else:
            pixels = image
            try:
                data = encode_image(pixels, image_format)
            except (ValueError, cv2.error) as exc:
                raise LandmarkDbError(f"{label}: {exc}") from exc
            fmt = image_format.lstrip(".").replace("jpg", "jpeg")
        h, w = pixels.shape[:2]
        why = photo_problem(w, h)
        if why is not None:
            raise LandmarkDbError(f"{label}: photo {why}")
        try:
            feats = extract(pixels, self.extractor)
        except (ValueError, cv2.error) as exc:
            raise LandmarkDbError(f"{label}: {exc}") from exc
        if len(feats) < MIN_PHOTO_FEATURES:
            raise LandmarkDbError(
                f"{label}: the photo has {len(feats)} features, fewer than the"
                f" {MIN_PHOTO_FEATURES} a recognition needs (too small, blurred or featureless)"
            )
        return data, pixels, fmt, feats

    def _insert_photo(
        self,
        lid: int,
        data: bytes,
        pixels: np.ndarray,
        fmt: str,
        feats: Features,
        facing: float | None,
        conditions: str,
        source: str,
    ) -> int:
        h, w = pixels.shape[:2]
        cur = self._conn.execute(
            "INSERT INTO photos (landmark_id, format, width, height, sha256, data, facing_deg,"
            " conditions, added_utc, source) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
            (lid, fmt, w, h, hashlib.sha256(data).hexdigest(), data, facing, conditions,
             _utc_now(), source),
        )  # fmt: skip
        pid = cur.lastrowid
        assert pid is not None
        self._insert_features(int(pid), feats)
        return int(pid)

    def _insert_features(self, pid: int, feats: Features, index: bool = True) -> None:
        """Store a photo's features and (``index``) its global descriptor, in the caller's
        transaction (``global_index.photo_added``: encoded, or everything rebuilt when due)."""
        self._conn.execute(
            "INSERT OR REPLACE INTO photo_features VALUES (?, ?, ?, ?, ?, ?, ?)",
            (pid, self.extractor.ident, len(feats), feats.width, feats.height,
             feats.keypoint_blob(), feats.descriptor_blob()),
        )  # fmt: skip
        if index:
            global_index.photo_added(self._conn, pid, feats, self.extractor)

    def add_photo(
        self,
        landmark_id: int,
        image: np.ndarray | bytes,
        *,
        facing_deg: float | None = None,
        conditions: str = "",
        source: str = "",
        image_format: str = ".png",
    ) -> int:
        """Another photo of an existing landmark (another distance, direction, light...);
        returns the photo's id. All photos of a landmark are scored as one place."""
        self._writable()
        if self.get(landmark_id) is None:
            raise LandmarkDbError(f"no landmark {landmark_id}")
        facing = None if facing_deg is None else _finite("facing", facing_deg) % 360.0
        _check_text(conditions, source)
        label = f"landmark {landmark_id}"
        data, pixels, fmt, feats = self._encoded(label, image, image_format)
        with self._lock, self._tx():
            same = self._conn.execute(
                "SELECT id FROM photos WHERE landmark_id = ? AND sha256 = ? ORDER BY id LIMIT 1",
                (landmark_id, hashlib.sha256(data).hexdigest()),
            ).fetchone()
            if same is not None:  # the same photo again: updated, never a duplicate
                self._conn.execute(
                    "UPDATE photos SET facing_deg = ?, conditions = ?, source = ? WHERE id = ?",
                    (facing, conditions, source, same[0]),
                )
                self._insert_features(int(same[0]), feats)
                return int(same[0])
            return self._insert_photo(
                landmark_id, data, pixels, fmt, feats, facing, conditions, source
            )

    def refresh_features(self, extractor: ExtractorConfig | None = None) -> int:
        """Make ``extractor`` (default: the file's own) the file's extractor and recompute
        every photo's features that it did not make; returns how many were recomputed.
        The migration for a new extractor, or a new version of one."""
        self._writable()
        ext = extractor or self.extractor
        with self._lock, self._conn:
            self._conn.execute(
                "INSERT OR REPLACE INTO metadata VALUES ('extractor', ?)", (ext.ident,)
            )
            self.extractor = ext
            rows = self._conn.execute(
                "SELECT p.id, p.data FROM photos p LEFT JOIN photo_features f"
                " ON f.photo_id = p.id WHERE f.extractor IS NULL OR f.extractor != ?",
                (ext.ident,),
            ).fetchall()
            for pid, data in rows:
                try:
                    feats = extract(decode_image(bytes(data)), ext)
                except ValueError as exc:
                    raise LandmarkDbError(f"{self.path}: photo {pid}: {exc}") from exc
                self._insert_features(int(pid), feats, index=False)
            if rows or global_index.needs_rebuild(self._conn, ext):
                global_index.rebuild(self._conn, ext)
        return len(rows)

    def rebuild_global_index(self) -> int:
        """Train the search's vocabulary on every photo and encode them all (``landmark-db
        migrate`` does it); returns the photos encoded."""
        self._writable()
        with self._lock, self._tx():
            return global_index.rebuild(self._conn, self.extractor)

    def photos(self, landmark_id: int) -> list[Photo]:
        """A landmark's photos, oldest first."""
        with self._reading() as c:
            rows = c.execute(
                "SELECT id, landmark_id, format, width, height, facing_deg, conditions, source"
                " FROM photos WHERE landmark_id = ? ORDER BY id",
                (landmark_id,),
            ).fetchall()
        return [Photo(*r) for r in rows]

    def photo_counts(self) -> dict[int, int]:
        """Landmark id -> number of photos."""
        with self._reading() as c:
            rows = c.execute("SELECT landmark_id, count(*) FROM photos GROUP BY landmark_id")
            return {int(a): int(b) for a, b in rows.fetchall()}

    def photo_bytes(self, photo_id: int) -> tuple[str, bytes] | None:
        """(format, encoded bytes) of one photo."""
        with self._reading():
            r = self._conn.execute(
                "SELECT format, data FROM photos WHERE id = ?", (photo_id,)
            ).fetchone()
        if r is not None and not isinstance(r[1], bytes):
            raise LandmarkDbError(f"{self.path}: photo {photo_id} is not a blob")
        return None if r is None else (str(r[0]), r[1])

    def image_bytes(self, landmark_id: int) -> tuple[str, bytes] | None:
        """(format, encoded bytes) of a landmark's first photo."""
        photos = self.photos(landmark_id)
        return self.photo_bytes(photos[0].id) if photos else None

    def photo_features(self, landmark_id: int) -> list[tuple[int, Features]]:
        """(photo id, features) of every photo of a landmark, oldest first."""
        with self._reading():
            rows = self._conn.execute(
                "SELECT p.id, f.width, f.height, f.keypoints, f.descriptors FROM photos p"
                " JOIN photo_features f ON f.photo_id = p.id WHERE p.landmark_id = ?"
                " ORDER BY p.id",
                (landmark_id,),
            ).fetchall()
        out = []
        for pid, w, h, kp, desc in rows:
            try:
                if not (isinstance(kp, bytes) and isinstance(desc, bytes)):
                    raise ValueError("keypoints or descriptors are not blobs")
                if not (isinstance(w, int) and isinstance(h, int)):
                    raise ValueError(f"image size {w!r} x {h!r} is not integer")
                out.append((int(pid), Features.from_blobs(kp, desc, w, h, self.extractor.kind)))
            except ValueError as exc:
                raise LandmarkDbError(f"{self.path}: landmark {landmark_id}: {exc}") from exc
        return out

    def features(self, landmark_id: int) -> Features | None:
        """Features of a landmark's first photo."""
        f = self.photo_features(landmark_id)
        return f[0][1] if f else None
