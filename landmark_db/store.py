"""The landmark database: one SQLite file with an R*Tree spatial index (SPEC section 6).

Tables (docs/landmarks.md has the full schema):

* ``schema_version``: one row, the version the migrations below have brought the file to;
* ``metadata``: key/value text, holding the local frame's origin and the extractor;
* ``landmarks``: id, name, lat/lon, local x/y metres, optional facing heading, position sigma;
* ``photos``: any number of photos per landmark, encoded (PNG or JPEG bytes), each with its
  own facing and capture conditions;
* ``photo_features``: keypoints and descriptors of each photo, as blobs, with the extractor
  (name, version, parameters) that made them;
* ``landmark_index``: an R*Tree over x/y (a point box per landmark) for candidate queries.

The car opens the file read-only (``mode=ro`` URI); only the tools write. Every problem
with a file (missing, not SQLite, wrong schema, corrupt) is raised as ``LandmarkDbError``,
a ``UserError``, with a one-line message.
"""

from __future__ import annotations

import math
import sqlite3
import threading
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from guidance.core.geo import Origin
from landmark_db.features import ExtractorConfig
from landmark_db.integrity import CheckReport
from landmark_db.limits import (
    MAX_COORDINATE_M,
    MAX_POSITION_SIGMA_M,
    MIN_POSITION_SIGMA_M,
    position_problem,
    sigma_problem,
)
from landmark_db.photos import Photo, _utc_now
from landmark_db.query import Candidate, query_gate, query_radius
from landmark_db.schema import (
    MIGRATIONS,
    SCHEMA_VERSION,
    TABLES,
    V1,
    LandmarkDbError,
    file_version,
    migrate,
    roll_back_hot_journal,
)
from landmark_db.writes import DEFAULT_POSITION_SIGMA_M, LandmarkWriter

__all__ = [
    "DEFAULT_POSITION_SIGMA_M",
    "MAX_ID_DIGITS",
    "MIGRATIONS",
    "SCHEMA_VERSION",
    "Candidate",
    "CheckReport",
    "LandmarkDb",
    "LandmarkDbError",
    "LandmarkRecord",
    "Photo",
    "create_db",
    "migrate",
    "open_db",
    "query_gate",
    "query_radius",
]


_READ_ERRORS = (sqlite3.DatabaseError, UnicodeDecodeError)
"""What reading a damaged file raises (UnicodeDecodeError: text or an error message that is
not UTF-8)."""

MAX_ID_DIGITS = 18
"""Longest landmark id as text: SQLite's integers end at 2**63 - 1 (19 digits, not all of
which fit); a longer run of digits is no id."""
_MAX_FLOAT = "1.7976931348623157e308"
_FINITE_SQL = f"coalesce({{c}} BETWEEN -{_MAX_FLOAT} AND {_MAX_FLOAT}, 0)"
"""SQL true for a finite number only: NULL, text, blobs and infinities fail it."""


@dataclass(frozen=True, slots=True)
class LandmarkRecord:
    """One landmark row. Positions in degrees and local metres; ``facing_deg`` clockwise from N."""

    id: int
    name: str
    lat_deg: float
    lon_deg: float
    x_m: float
    y_m: float
    facing_deg: float | None
    position_sigma_m: float
    added_utc: str = ""
    source: str = ""


class LandmarkDb(LandmarkWriter):
    """A landmark database file. Construct with ``create_db`` or ``open_db``.

    Thread-safe for the uses here: one connection guarded by a lock, opened with
    ``check_same_thread=False`` so a recogniser may query from an executor thread.
    """

    def __init__(self, conn: sqlite3.Connection, path: Path, readonly: bool) -> None:
        self._conn = conn
        self.path = path
        self.readonly = readonly
        self._lock = threading.RLock()
        self._in_batch = False
        self.origin = self._read_origin()
        self.extractor = self._read_extractor()

    @property
    def orb(self) -> ExtractorConfig:
        """The photo extractor (named ``orb`` before schema v3, when ORB was the only one)."""
        return self.extractor

    # --- opening ------------------------------------------------------------------------------

    def close(self) -> None:
        with self._lock:
            self._conn.close()

    def __enter__(self) -> LandmarkDb:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _read_meta(self) -> dict[str, str]:
        return dict(self._conn.execute("SELECT key, value FROM metadata").fetchall())

    def _read_origin(self) -> Origin:
        meta = self._read_meta()
        try:
            alt = float(meta.get("origin_alt_m", "0"))
            if not math.isfinite(alt):
                raise ValueError(f"origin_alt_m {alt!r}")
            return Origin(float(meta["origin_lat_deg"]), float(meta["origin_lon_deg"]), alt)
        except (KeyError, ValueError, TypeError) as exc:
            raise LandmarkDbError(
                f"{self.path}: missing or bad origin in metadata ({exc})"
            ) from exc

    def _read_extractor(self) -> ExtractorConfig:
        try:
            return ExtractorConfig.parse(str(self._read_meta()["extractor"]))
        except (KeyError, ValueError, TypeError) as exc:
            raise LandmarkDbError(
                f"{self.path}: missing or bad extractor in metadata ({exc})"
            ) from exc

    def metadata(self) -> dict[str, str]:
        with self._reading():
            return self._read_meta()

    @contextmanager
    def _reading(self) -> Iterator[sqlite3.Connection]:
        """The connection, under the lock; a damaged file's errors as ``LandmarkDbError``."""
        with self._lock:
            try:
                yield self._conn
            except _READ_ERRORS as exc:
                raise LandmarkDbError(f"{self.path}: unreadable landmark database ({exc})") from exc

    def _check_rows(self) -> None:
        """Every landmark's position, facing and sigma, and every index box, are finite
        numbers: one scan of each table at open, so a damaged row never becomes a fix.
        Features made by another extractor (or version) must be recomputed first."""
        cols = ("lat_deg", "lon_deg", "x_m", "y_m", "position_sigma_m")
        bad = " OR ".join(f"NOT {_FINITE_SQL.format(c=c)}" for c in cols)
        bad += f" OR (facing_deg IS NOT NULL AND NOT {_FINITE_SQL.format(c='facing_deg')})"
        box = " OR ".join(
            f"NOT {_FINITE_SQL.format(c=c)}" for c in ("min_x", "max_x", "min_y", "max_y")
        )
        bad += (
            f" OR abs(x_m) > {MAX_COORDINATE_M!r} OR abs(y_m) > {MAX_COORDINATE_M!r}"
            f" OR NOT position_sigma_m BETWEEN {MIN_POSITION_SIGMA_M!r}"
            f" AND {MAX_POSITION_SIGMA_M!r}"
        )
        with self._reading() as c:
            row = c.execute(f"SELECT {self._COLS} FROM landmarks WHERE {bad} LIMIT 1").fetchone()
            if row is not None:
                lm = self._row(row)  # raises for a value that is no number, naming the column
                why = position_problem(lm.x_m, lm.y_m) or sigma_problem(lm.position_sigma_m)
                raise LandmarkDbError(
                    f"{self.path}: landmark {lm.id} ({lm.name!r}): {why or 'bad position'}"
                )
            r = c.execute(f"SELECT id FROM landmark_index WHERE {box} LIMIT 1").fetchone()
            if r is not None:
                raise LandmarkDbError(f"{self.path}: index box of landmark {r[0]!r} is not finite")
        stale = self.stale_features()
        if stale:
            raise LandmarkDbError(
                f"{self.path}: {stale} photo(s) have features from another extractor than"
                f" {self.extractor.ident}; run `landmark-db migrate` on it"
            )

    # --- writing ------------------------------------------------------------------------------

    def _writable(self) -> None:
        if self.readonly:
            raise LandmarkDbError(f"{self.path} is open read-only")

    # --- reading ------------------------------------------------------------------------------

    _COLS = "id, name, lat_deg, lon_deg, x_m, y_m, facing_deg, position_sigma_m, added_utc, source"

    _NUMBERS = ("lat_deg", "lon_deg", "x_m", "y_m", "facing_deg", "position_sigma_m")

    def _row(self, r: Sequence[object]) -> LandmarkRecord:
        """A landmark from a row of ``_COLS``; a value that is not a finite number (a damaged
        file) raises ``LandmarkDbError`` naming the landmark and the column."""
        lid = r[0]
        if not isinstance(lid, int):
            raise LandmarkDbError(f"{self.path}: landmark id {lid!r} is not an integer")
        nums: list[float | None] = []
        for col, v in zip(self._NUMBERS, r[2:8], strict=True):
            if v is None and col == "facing_deg":
                nums.append(None)
            elif isinstance(v, int | float) and math.isfinite(v):
                nums.append(float(v))
            else:
                raise LandmarkDbError(
                    f"{self.path}: landmark {lid}: {col} is not a finite number ({v!r})"
                )
        lat, lon, x, y, facing, sigma = nums
        assert lat is not None and lon is not None and x is not None and y is not None
        assert sigma is not None
        return LandmarkRecord(lid, str(r[1]), lat, lon, x, y, facing, sigma, str(r[8]), str(r[9]))

    def __len__(self) -> int:
        with self._reading() as c:
            return int(c.execute("SELECT count(*) FROM landmarks").fetchone()[0])

    def landmarks(self) -> Iterator[LandmarkRecord]:
        """All landmarks by id."""
        with self._reading() as c:
            rows = c.execute(f"SELECT {self._COLS} FROM landmarks ORDER BY id").fetchall()
        return (self._row(r) for r in rows)

    def get(self, landmark_id: int) -> LandmarkRecord | None:
        with self._reading():
            r = self._conn.execute(
                f"SELECT {self._COLS} FROM landmarks WHERE id = ?", (landmark_id,)
            ).fetchone()
        return None if r is None else self._row(r)

    def find(self, key: str) -> LandmarkRecord | None:
        """A landmark by id (ASCII digits) or by exact name (the first such). Only ASCII digits
        are an id: ``int`` also reads Arabic-Indic or full-width digits ("٣" is 3), which would
        take a landmark's name for another landmark's id (issue 40); an id beyond SQLite's
        integers (19 digits and more) is no landmark."""
        if key.isascii() and key.isdigit():
            return self.get(int(key)) if len(key) <= MAX_ID_DIGITS else None
        return self.by_name(key)

    def by_name(self, name: str) -> LandmarkRecord | None:
        """The first landmark (lowest id) with exactly this name."""
        with self._reading():
            r = self._conn.execute(
                f"SELECT {self._COLS} FROM landmarks WHERE name = ? ORDER BY id LIMIT 1", (name,)
            ).fetchone()
        return None if r is None else self._row(r)

    def in_box(
        self, min_x: float, max_x: float, min_y: float, max_y: float
    ) -> tuple[np.ndarray, np.ndarray]:
        """Ids (int64) and x/y (N x 2 float64) of the landmarks in an axis-aligned box (R*Tree)."""
        with self._reading():
            rows = self._conn.execute(
                "SELECT id, min_x, min_y FROM landmark_index"
                " WHERE max_x >= ? AND min_x <= ? AND max_y >= ? AND min_y <= ?",
                (min_x, max_x, min_y, max_y),
            ).fetchall()
        if not rows:
            return np.zeros(0, np.int64), np.zeros((0, 2))
        try:
            arr = np.asarray(rows, dtype=np.float64)
        except (TypeError, ValueError) as exc:  # not an R*Tree any more
            raise LandmarkDbError(f"{self.path}: bad landmark index ({exc})") from exc
        return arr[:, 0].astype(np.int64), arr[:, 1:3]

    def check(self, decode_images: bool = True) -> CheckReport:
        """``PRAGMA integrity_check`` plus consistency (``landmark_db.integrity``)."""
        from landmark_db.integrity import check

        with self._lock:
            return check(self._conn, self.origin, self.extractor, decode_images)


def _connect(path: Path, readonly: bool) -> sqlite3.Connection:
    if readonly:
        roll_back_hot_journal(path)
        uri = f"{path.resolve().as_uri()}?mode=ro"
        conn = sqlite3.connect(uri, uri=True, check_same_thread=False)
    else:
        conn = sqlite3.connect(path, check_same_thread=False)
        conn.execute("PRAGMA foreign_keys = ON")
    return conn


def create_db(
    path: str | Path,
    origin: Origin,
    extractor: ExtractorConfig | None = None,
) -> LandmarkDb:
    """Create a new, empty database file (refuses to overwrite) and open it writable."""
    p = Path(path)
    if p.exists():
        raise LandmarkDbError(f"{p} already exists")
    if not p.parent.is_dir():
        raise LandmarkDbError(f"folder {p.parent} does not exist")
    ext = extractor or ExtractorConfig()
    conn = _connect(p, readonly=False)  # as open_db's: foreign keys on (ON DELETE CASCADE)
    try:
        conn.executescript(f"BEGIN; {V1} COMMIT;")
        with conn:
            conn.executemany(
                "INSERT INTO metadata VALUES (?, ?)",
                [
                    ("origin_lat_deg", repr(origin.lat_deg)),
                    ("origin_lon_deg", repr(origin.lon_deg)),
                    ("origin_alt_m", repr(origin.alt_m)),
                    ("extractor", ext.ident),
                    ("created_utc", _utc_now()),
                ],
            )
        migrate(conn, p)
    except BaseException:
        conn.close()
        p.unlink(missing_ok=True)
        raise
    return LandmarkDb(conn, p, readonly=False)


def open_db(path: str | Path, *, readonly: bool = True) -> LandmarkDb:
    """Open and validate an existing database. Read-only (the car's mode) unless asked.

    A read-only open also checks that every landmark's position, facing and sigma and every
    index box are finite numbers, so no damaged row can become a landmark fix.

    Writable opens migrate an older schema to the current one; read-only opens of an
    older or newer schema raise ``LandmarkDbError`` saying what to do.
    """
    p = Path(path)
    if not p.is_file():
        raise LandmarkDbError(f"{p}: no such landmark database file")
    try:
        conn = _connect(p, readonly)
    except sqlite3.Error as exc:
        raise LandmarkDbError(f"{p}: cannot open ({exc})") from exc
    try:
        version = file_version(conn, p)
        if version > SCHEMA_VERSION:
            raise LandmarkDbError(
                f"{p}: schema v{version} is newer than this software (v{SCHEMA_VERSION})"
            )
        if version < SCHEMA_VERSION:
            if readonly:
                raise LandmarkDbError(
                    f"{p}: schema v{version} is older than v{SCHEMA_VERSION};"
                    " run `landmark-db migrate` on it"
                )
            migrate(conn, p)
        tables = {r[0] for r in conn.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
        missing = TABLES - tables
        if missing:
            raise LandmarkDbError(f"{p}: not a landmark database (missing {sorted(missing)})")
        db = LandmarkDb(conn, p, readonly)
        if readonly:  # the car's open; the tools may open a damaged file writable to mend it
            db._check_rows()
        return db
    except _READ_ERRORS as exc:
        conn.close()
        raise LandmarkDbError(f"{p}: unreadable landmark database ({exc})") from exc
    except BaseException:
        conn.close()
        raise
