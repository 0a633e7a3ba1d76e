"""The landmark database's SQL schema and its migrations (docs/landmarks.md, "The database file").

``MIGRATIONS`` lists ``(version, script)``: script k brings a file from version k-1 to k.

* v1: landmarks, one photo (``images``) and its ORB features (``features``) per landmark,
  the R*Tree ``landmark_index``;
* v2: an index on ``landmarks(name)``;
* v3: any number of photos per landmark (``photos``, each with its own facing and capture
  conditions) and their features (``photo_features``, with the extractor's name, version
  and parameters); the v1 tables' rows move over with their ids, and the file keeps
  describing photos as before (metadata ``extractor``). Recomputing features for another
  extractor is ``LandmarkDb.refresh_features`` (``landmark-db migrate --extractor``).
* v4: the whole-database search's global descriptors (``landmark_db.global_index``): the
  VLAD ``vocabulary`` (one row) and a vector per photo (``photo_global``). Both start empty;
  the next write (or ``landmark-db migrate``) builds them, and a read-only open of a file
  without them computes them in memory.
"""

from __future__ import annotations

import sqlite3
from pathlib import Path

from guidance.errors import UserError


class LandmarkDbError(UserError):
    """A landmark database that cannot be used: the message says why, in one line."""

    def __init__(self, message: str) -> None:
        # One line whatever it quotes: SQLite echoes a damaged schema's bytes, paths may hold
        # newlines.
        super().__init__(" ".join(str(message).split()))


SCHEMA_VERSION = 4
"""The version this code writes and reads; older files are migrated by ``open_db(writable)``."""

V1 = """
CREATE TABLE schema_version (version INTEGER NOT NULL);
CREATE TABLE metadata (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE landmarks (
    id INTEGER PRIMARY KEY,
    name TEXT NOT NULL,
    lat_deg REAL NOT NULL,
    lon_deg REAL NOT NULL,
    x_m REAL NOT NULL,
    y_m REAL NOT NULL,
    facing_deg REAL,
    position_sigma_m REAL NOT NULL,
    added_utc TEXT NOT NULL,
    source TEXT NOT NULL DEFAULT ''
);
CREATE TABLE images (
    landmark_id INTEGER PRIMARY KEY REFERENCES landmarks(id) ON DELETE CASCADE,
    format TEXT NOT NULL,
    width INTEGER NOT NULL,
    height INTEGER NOT NULL,
    sha256 TEXT NOT NULL,
    data BLOB NOT NULL
);
CREATE TABLE features (
    landmark_id INTEGER PRIMARY KEY REFERENCES landmarks(id) ON DELETE CASCADE,
    count INTEGER NOT NULL,
    width INTEGER NOT NULL,
    height INTEGER NOT NULL,
    keypoints BLOB NOT NULL,
    descriptors BLOB NOT NULL
);
CREATE VIRTUAL TABLE landmark_index USING rtree(id, min_x, max_x, min_y, max_y);
INSERT INTO schema_version VALUES (1);
"""

V2 = """
CREATE INDEX landmarks_name ON landmarks(name);
UPDATE schema_version SET version = 2;
"""

V3 = """
CREATE TABLE photos (
    id INTEGER PRIMARY KEY,
    landmark_id INTEGER NOT NULL REFERENCES landmarks(id) ON DELETE CASCADE,
    format TEXT NOT NULL,
    width INTEGER NOT NULL,
    height INTEGER NOT NULL,
    sha256 TEXT NOT NULL,
    data BLOB NOT NULL,
    facing_deg REAL,
    conditions TEXT NOT NULL DEFAULT '',
    added_utc TEXT NOT NULL DEFAULT '',
    source TEXT NOT NULL DEFAULT ''
);
CREATE INDEX photos_landmark ON photos(landmark_id);
CREATE TABLE photo_features (
    photo_id INTEGER PRIMARY KEY REFERENCES photos(id) ON DELETE CASCADE,
    extractor TEXT NOT NULL,
    count INTEGER NOT NULL,
    width INTEGER NOT NULL,
    height INTEGER NOT NULL,
    keypoints BLOB NOT NULL,
    descriptors BLOB NOT NULL
);
INSERT INTO metadata (key, value) SELECT 'extractor', 'orb/1:'
    || coalesce((SELECT value FROM metadata WHERE key = 'orb_n_features'), '1000') || '@'
    || coalesce((SELECT value FROM metadata WHERE key = 'orb_max_side_px'), '1024')
    WHERE NOT EXISTS (SELECT 1 FROM metadata WHERE key = 'extractor');
INSERT INTO photos (id, landmark_id, format, width, height, sha256, data, facing_deg,
                    added_utc, source)
    SELECT i.landmark_id, i.landmark_id, i.format, i.width, i.height, i.sha256, i.data,
           l.facing_deg, l.added_utc, l.source
    FROM images i JOIN landmarks l ON l.id = i.landmark_id;
INSERT INTO photo_features (photo_id, extractor, count, width, height, keypoints, descriptors)
    SELECT f.landmark_id, (SELECT value FROM metadata WHERE key = 'extractor'),
           f.count, f.width, f.height, f.keypoints, f.descriptors
    FROM features f WHERE f.landmark_id IN (SELECT id FROM photos);
DROP TABLE images;
DROP TABLE features;
UPDATE schema_version SET version = 3;
"""

V4 = """
CREATE TABLE vocabulary (
    extractor TEXT NOT NULL,
    photos INTEGER NOT NULL,
    k INTEGER NOT NULL,
    dims INTEGER NOT NULL,
    centres BLOB NOT NULL,
    mean BLOB NOT NULL,
    projection BLOB NOT NULL
);
CREATE TABLE photo_global (
    photo_id INTEGER PRIMARY KEY REFERENCES photos(id) ON DELETE CASCADE,
    vocabulary TEXT NOT NULL,
    vector BLOB NOT NULL
);
UPDATE schema_version SET version = 4;
"""

MIGRATIONS: tuple[tuple[int, str], ...] = ((1, V1), (2, V2), (3, V3), (4, V4))
"""(version, script): applying script k brings a file from version k-1 to version k."""

TABLES = frozenset(
    {"metadata", "landmarks", "photos", "photo_features", "landmark_index", "vocabulary",
     "photo_global"}
)  # fmt: skip
"""The tables a current file must have (besides ``schema_version``)."""


def file_version(conn: sqlite3.Connection, path: Path) -> int:
    """The schema version of an open file; ``LandmarkDbError`` if it is no landmark database."""
    try:
        tables = {r[0] for r in conn.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
    except sqlite3.DatabaseError as exc:
        raise LandmarkDbError(f"{path}: not a landmark database ({exc})") from exc
    if "schema_version" not in tables:
        raise LandmarkDbError(f"{path}: not a landmark database (no schema_version table)")
    row = conn.execute("SELECT version FROM schema_version").fetchone()
    if row is None or not isinstance(row[0], int):
        raise LandmarkDbError(f"{path}: schema_version table is empty or bad")
    return int(row[0])


def migrate(conn: sqlite3.Connection, path: Path, target: int = SCHEMA_VERSION) -> int:
    """Apply the migrations after the file's version up to ``target``; returns the new version."""
    current = file_version(conn, path)
    for version, script in MIGRATIONS:
        if current < version <= target:
            try:
                conn.executescript(f"BEGIN; {script} COMMIT;")
            except sqlite3.DatabaseError as exc:
                conn.rollback()
                raise LandmarkDbError(f"{path}: migration to v{version} failed: {exc}") from exc
            current = version
    return current


def roll_back_hot_journal(path: Path) -> None:
    """A write that was killed (``landmark-db import``) leaves ``<file>-journal`` beside the
    file, and a read-only open cannot roll it back ("attempt to write a readonly database").
    SQLite rolls it back, restoring the last committed state, on a writable connection's
    first read (only when no live writer holds the file). When that is not possible here
    (read-only file or folder, a writer busy), one line says what is there and what to run."""
    journal = path.with_name(path.name + "-journal")
    try:
        if journal.stat().st_size == 0:
            return
    except OSError:
        return
    try:
        conn = sqlite3.connect(path, timeout=2.0)
        try:
            conn.execute("SELECT count(*) FROM sqlite_master").fetchone()
        finally:
            conn.close()
    except sqlite3.Error as exc:
        raise LandmarkDbError(
            f"{path}: {journal.name} beside it holds a write that was interrupted (or is still"
            f" running) and it cannot be rolled back here ({exc}); run `landmark-db check"
            f" {path}` with write access to the file and its folder"
        ) from exc
