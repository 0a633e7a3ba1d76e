"""The landmark database: one SQLite file with an R*Tree spatial index (SPEC section 6).

Tables (docs/landmarks.md has the full schema):

* ``schema_version``: one row, the version the migrations below have brought the file to;
* ``metadata``: key/value text, holding the local frame's origin and the ORB parameters;
* ``landmarks``: id, name, lat/lon, local x/y metres, optional facing heading, position sigma;
* ``images``: the reference photo of each landmark, encoded (PNG or JPEG bytes);
* ``features``: ORB keypoints and descriptors of the reference photo, as blobs;
* ``landmark_index``: an R*Tree over x/y (a point box per landmark) for candidate queries.

The car opens the file read-only (``mode=ro`` URI); only the tools write. Every problem
with a file (missing, not SQLite, wrong schema, corrupt) is raised as ``LandmarkDbError``,
a ``UserError``, with a one-line message.
"""

from __future__ import annotations

import hashlib
import math
import sqlite3
import threading
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from guidance.core.model import CHI2_2D_2SIGMA
from guidance.errors import UserError
from landmark_db.features import Features, OrbConfig, decode_image, encode_image, extract
from landmark_db.gate import gate_box, in_gate, mahalanobis_sq
from landmark_db.geo import Origin

SCHEMA_VERSION = 2
"""The version this code writes and reads; older files are migrated by ``open_db(writable)``."""

DEFAULT_POSITION_SIGMA_M = 3.0
"""1-sigma of a surveyed landmark position when the source gives none (consumer GPS)."""


class LandmarkDbError(UserError):
    """A landmark database that cannot be used: the message says why, in one line."""

    def __init__(self, message: str) -> None:
        # One line whatever it quotes: SQLite echoes a damaged schema's bytes, paths may hold
        # newlines.
        super().__init__(" ".join(str(message).split()))


_READ_ERRORS = (sqlite3.DatabaseError, UnicodeDecodeError)
"""What reading a damaged file raises (UnicodeDecodeError: text or an error message that is
not UTF-8)."""

_MAX_FLOAT = "1.7976931348623157e308"
_FINITE_SQL = f"coalesce({{c}} BETWEEN -{_MAX_FLOAT} AND {_MAX_FLOAT}, 0)"
"""SQL true for a finite number only: NULL, text, blobs and infinities fail it."""


_V1 = """
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

_V2 = """
CREATE INDEX landmarks_name ON landmarks(name);
UPDATE schema_version SET version = 2;
"""

MIGRATIONS: tuple[tuple[int, str], ...] = ((1, _V1), (2, _V2))
"""(version, script): applying script k brings a file from version k-1 to version k."""


@dataclass(frozen=True, slots=True)
class Landmark:
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


@dataclass(frozen=True, slots=True)
class CheckReport:
    """What ``check`` found: ``problems`` empty means the file is sound."""

    landmarks: int
    problems: tuple[str, ...]

    @property
    def ok(self) -> bool:
        return not self.problems


def _utc_now() -> str:
    return time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())


def _finite(name: str, value: float) -> float:
    v = float(value)
    if not math.isfinite(v):
        raise LandmarkDbError(f"{name} must be a finite number, not {value!r}")
    return v


class LandmarkDb:
    """A landmark database file. Construct with ``create_db`` or ``open_db``.

    Thread-safe for the uses here: one connection guarded by a lock, opened with
    ``check_same_thread=False`` so a recogniser may query from an executor thread.
    """

    def __init__(self, conn: sqlite3.Connection, path: Path, readonly: bool) -> None:
        self._conn = conn
        self.path = path
        self.readonly = readonly
        self._lock = threading.RLock()
        self.origin = self._read_origin()
        self.orb = self._read_orb()

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

    def _read_orb(self) -> OrbConfig:
        meta = self._read_meta()
        try:
            return OrbConfig(
                n_features=int(meta["orb_n_features"]),
                max_side_px=int(meta["orb_max_side_px"]),
            )
        except (KeyError, ValueError, TypeError) as exc:
            raise LandmarkDbError(
                f"{self.path}: missing or bad ORB parameters in metadata ({exc})"
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
        numbers: one scan of each table at open, so a damaged row never becomes a fix."""
        cols = ("lat_deg", "lon_deg", "x_m", "y_m", "position_sigma_m")
        bad = " OR ".join(f"NOT {_FINITE_SQL.format(c=c)}" for c in cols)
        bad += f" OR (facing_deg IS NOT NULL AND NOT {_FINITE_SQL.format(c='facing_deg')})"
        box = " OR ".join(
            f"NOT {_FINITE_SQL.format(c=c)}" for c in ("min_x", "max_x", "min_y", "max_y")
        )
        with self._reading() as c:
            row = c.execute(f"SELECT {self._COLS} FROM landmarks WHERE {bad} LIMIT 1").fetchone()
            if row is not None:
                self._row(row)  # raises, naming the landmark and the column
                raise LandmarkDbError(f"{self.path}: landmark {row[0]!r} has a bad position")
            r = c.execute(f"SELECT id FROM landmark_index WHERE {box} LIMIT 1").fetchone()
            if r is not None:
                raise LandmarkDbError(f"{self.path}: index box of landmark {r[0]!r} is not finite")

    # --- writing ------------------------------------------------------------------------------

    def _writable(self) -> None:
        if self.readonly:
            raise LandmarkDbError(f"{self.path} is open read-only")

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
    ) -> int:
        """Add a landmark with its photo (encoded bytes or an array); returns its id.

        Give either lat/lon or local x/y; the other pair is computed from the origin.
        Raises ``LandmarkDbError`` for a bad position or an undecodable image.
        """
        self._writable()
        if not name:
            raise LandmarkDbError("a landmark needs a name")
        if lat_deg is not None and lon_deg is not None:
            lat, lon = _finite("lat", lat_deg), _finite("lon", lon_deg)
            if not (-90.0 <= lat <= 90.0 and -180.0 <= lon <= 180.0):
                raise LandmarkDbError(f"lat/lon {lat}, {lon} out of range")
            x, y = self.origin.to_local(lat, lon)
        elif x_m is not None and y_m is not None:
            x, y = _finite("x", x_m), _finite("y", y_m)
            lat, lon = self.origin.to_geodetic(x, y)
        else:
            raise LandmarkDbError("give a position: lat and lon, or x and y")
        sigma = _finite("position sigma", position_sigma_m)
        if sigma < 0:
            raise LandmarkDbError("position sigma must not be negative")
        facing = None if facing_deg is None else _finite("facing", facing_deg) % 360.0
        if isinstance(image, bytes | bytearray | memoryview):
            data = bytes(image)
            try:
                pixels = decode_image(data)
            except ValueError as exc:
                raise LandmarkDbError(f"landmark {name!r}: {exc}") from exc
            fmt = (
                "jpeg" if data[:2] == b"\xff\xd8" else "png" if data[:4] == b"\x89PNG" else "other"
            )
        else:
            pixels = image
            data = encode_image(pixels, image_format)
            fmt = image_format.lstrip(".").replace("jpg", "jpeg")
        try:
            feats = extract(pixels, self.orb)
        except ValueError as exc:
            raise LandmarkDbError(f"landmark {name!r}: {exc}") from exc
        h, w = pixels.shape[:2]
        with self._lock, self._conn:
            cur = self._conn.execute(
                "INSERT INTO landmarks (name, lat_deg, lon_deg, x_m, y_m, facing_deg,"
                " position_sigma_m, added_utc, source) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?)",
                (name, lat, lon, x, y, facing, sigma, _utc_now(), source),
            )
            lid = cur.lastrowid
            assert lid is not None
            self._conn.execute(
                "INSERT INTO images VALUES (?, ?, ?, ?, ?, ?)",
                (lid, fmt, w, h, hashlib.sha256(data).hexdigest(), data),
            )
            self._conn.execute(
                "INSERT INTO features VALUES (?, ?, ?, ?, ?, ?)",
                (
                    lid,
                    len(feats),
                    feats.width,
                    feats.height,
                    feats.keypoint_blob(),
                    feats.descriptor_blob(),
                ),
            )
            self._conn.execute(
                "INSERT INTO landmark_index VALUES (?, ?, ?, ?, ?)", (lid, x, x, y, y)
            )
        return int(lid)

    def add_many_precomputed(
        self,
        rows: Sequence[tuple[str, float, float]],
        features: Features,
        image_data: bytes,
        position_sigma_m: float = 0.0,
    ) -> None:
        """Bulk insert (name, x, y) landmarks sharing one photo and its features.

        For benchmarks and simulated cities of many landmarks, where describing a photo
        per landmark would dominate; positions are local metres.
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
                self._conn.execute(
                    "INSERT INTO images VALUES (?, 'png', ?, ?, ?, ?)",
                    (lid, features.width, features.height, digest, image_data),
                )
                self._conn.execute(
                    "INSERT INTO features VALUES (?, ?, ?, ?, ?, ?)",
                    (
                        lid,
                        len(features),
                        features.width,
                        features.height,
                        features.keypoint_blob(),
                        features.descriptor_blob(),
                    ),
                )
                self._conn.execute(
                    "INSERT INTO landmark_index VALUES (?, ?, ?, ?, ?)", (lid, x, x, y, y)
                )

    def remove(self, landmark_id: int) -> bool:
        """Delete a landmark with its photo, features and index row; False if absent."""
        self._writable()
        with self._lock, self._conn:
            n = self._conn.execute("DELETE FROM landmarks WHERE id = ?", (landmark_id,)).rowcount
            self._conn.execute("DELETE FROM images WHERE landmark_id = ?", (landmark_id,))
            self._conn.execute("DELETE FROM features WHERE landmark_id = ?", (landmark_id,))
            self._conn.execute("DELETE FROM landmark_index WHERE id = ?", (landmark_id,))
        return n > 0

    # --- reading ------------------------------------------------------------------------------

    _COLS = "id, name, lat_deg, lon_deg, x_m, y_m, facing_deg, position_sigma_m, added_utc, source"

    _NUMBERS = ("lat_deg", "lon_deg", "x_m", "y_m", "facing_deg", "position_sigma_m")

    def _row(self, r: Sequence[object]) -> Landmark:
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
        return Landmark(lid, str(r[1]), lat, lon, x, y, facing, sigma, str(r[8]), str(r[9]))

    def __len__(self) -> int:
        with self._reading() as c:
            return int(c.execute("SELECT count(*) FROM landmarks").fetchone()[0])

    def landmarks(self) -> Iterator[Landmark]:
        """All landmarks by id."""
        with self._reading() as c:
            rows = c.execute(f"SELECT {self._COLS} FROM landmarks ORDER BY id").fetchall()
        return (self._row(r) for r in rows)

    def get(self, landmark_id: int) -> Landmark | None:
        with self._reading():
            r = self._conn.execute(
                f"SELECT {self._COLS} FROM landmarks WHERE id = ?", (landmark_id,)
            ).fetchone()
        return None if r is None else self._row(r)

    def find(self, key: str) -> Landmark | None:
        """A landmark by id (digits) or by exact name (the first such)."""
        if key.isdigit():
            return self.get(int(key))
        with self._reading():
            r = self._conn.execute(
                f"SELECT {self._COLS} FROM landmarks WHERE name = ? ORDER BY id LIMIT 1", (key,)
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

    def image_bytes(self, landmark_id: int) -> tuple[str, bytes] | None:
        """(format, encoded bytes) of a landmark's photo."""
        with self._reading():
            r = self._conn.execute(
                "SELECT format, data FROM images WHERE landmark_id = ?", (landmark_id,)
            ).fetchone()
        if r is not None and not isinstance(r[1], bytes):
            raise LandmarkDbError(f"{self.path}: landmark {landmark_id}: photo is not a blob")
        return None if r is None else (str(r[0]), r[1])

    def features(self, landmark_id: int) -> Features | None:
        with self._reading():
            r = self._conn.execute(
                "SELECT width, height, keypoints, descriptors FROM features WHERE landmark_id = ?",
                (landmark_id,),
            ).fetchone()
        if r is None:
            return None
        try:
            if not (isinstance(r[2], bytes) and isinstance(r[3], bytes)):
                raise ValueError("keypoints or descriptors are not blobs")
            if not (isinstance(r[0], int) and isinstance(r[1], int)):
                raise ValueError(f"image size {r[0]!r} x {r[1]!r} is not integer")
            return Features.from_blobs(r[2], r[3], r[0], r[1])
        except ValueError as exc:
            raise LandmarkDbError(f"{self.path}: landmark {landmark_id}: {exc}") from exc

    # --- integrity ----------------------------------------------------------------------------

    def check(self, decode_images: bool = True) -> CheckReport:
        """``PRAGMA integrity_check`` plus consistency: every landmark has a photo and
        features that decode, the R*Tree has exactly one matching box per landmark,
        positions agree with lat/lon through the origin (within 1 m)."""
        problems: list[str] = []
        with self._lock:
            c = self._conn
            try:
                res = [str(r[0]) for r in c.execute("PRAGMA integrity_check").fetchall()]
            except sqlite3.DatabaseError as exc:
                return CheckReport(0, (f"integrity_check failed: {exc}",))
            if res != ["ok"]:
                problems.extend(f"integrity: {r}" for r in res[:20])
            n = int(c.execute("SELECT count(*) FROM landmarks").fetchone()[0])
            for label, sql in (
                (
                    "without a photo",
                    "SELECT id FROM landmarks WHERE id NOT IN (SELECT landmark_id FROM images)",
                ),
                (
                    "without features",
                    "SELECT id FROM landmarks WHERE id NOT IN (SELECT landmark_id FROM features)",
                ),
                (
                    "without an index box",
                    "SELECT id FROM landmarks WHERE id NOT IN (SELECT id FROM landmark_index)",
                ),
                (
                    "index box for no landmark",
                    "SELECT id FROM landmark_index WHERE id NOT IN (SELECT id FROM landmarks)",
                ),
                (
                    "photo for no landmark",
                    "SELECT landmark_id FROM images WHERE landmark_id NOT IN"
                    " (SELECT id FROM landmarks)",
                ),
                (
                    "features for no landmark",
                    "SELECT landmark_id FROM features WHERE landmark_id NOT IN"
                    " (SELECT id FROM landmarks)",
                ),
                (
                    "index box not at its position",
                    "SELECT l.id FROM landmarks l JOIN landmark_index r ON r.id = l.id"
                    " WHERE abs(r.min_x - l.x_m) > 0.01 OR abs(r.max_x - l.x_m) > 0.01"
                    " OR abs(r.min_y - l.y_m) > 0.01 OR abs(r.max_y - l.y_m) > 0.01",
                ),
                ("with no keypoints", "SELECT landmark_id FROM features WHERE count < 1"),
            ):
                ids = [int(r[0]) for r in c.execute(sql).fetchall()]
                if ids:
                    shown = ", ".join(map(str, ids[:10])) + (" ..." if len(ids) > 10 else "")
                    problems.append(f"{len(ids)} landmark(s) {label}: {shown}")
            rows = c.execute(
                "SELECT l.id, l.lat_deg, l.lon_deg, l.x_m, l.y_m, f.count, f.width, f.height,"
                " f.keypoints, f.descriptors FROM landmarks l JOIN features f"
                " ON f.landmark_id = l.id"
            )
            for lid, lat, lon, x, y, count, w, h, kp, desc in rows:
                ex, ey = self.origin.to_local(lat, lon)
                if math.hypot(ex - x, ey - y) > 1.0:
                    problems.append(
                        f"landmark {lid}: x/y disagree with lat/lon by"
                        f" {math.hypot(ex - x, ey - y):.1f} m"
                    )
                try:
                    f = Features.from_blobs(bytes(kp), bytes(desc), w, h)
                    if len(f) != count:
                        raise ValueError(f"{len(f)} features stored, count says {count}")
                except ValueError as exc:
                    problems.append(f"landmark {lid}: bad features: {exc}")
            if decode_images:
                for lid, data, digest in c.execute("SELECT landmark_id, data, sha256 FROM images"):
                    if hashlib.sha256(bytes(data)).hexdigest() != digest:
                        problems.append(f"landmark {lid}: photo checksum mismatch")
                        continue
                    try:
                        decode_image(bytes(data))
                    except ValueError:
                        problems.append(f"landmark {lid}: photo does not decode")
        return CheckReport(n, tuple(problems))


def _connect(path: Path, readonly: bool) -> sqlite3.Connection:
    if readonly:
        uri = f"{path.resolve().as_uri()}?mode=ro"
        conn = sqlite3.connect(uri, uri=True, check_same_thread=False)
    else:
        conn = sqlite3.connect(path, check_same_thread=False)
        conn.execute("PRAGMA foreign_keys = ON")
    return conn


def _version(conn: sqlite3.Connection, path: Path) -> int:
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
    current = _version(conn, path)
    for version, script in MIGRATIONS:
        if current < version <= target:
            try:
                conn.executescript(f"BEGIN; {script} COMMIT;")
            except sqlite3.DatabaseError as exc:
                conn.rollback()
                raise LandmarkDbError(f"{path}: migration to v{version} failed: {exc}") from exc
            current = version
    return current


def create_db(
    path: str | Path,
    origin: Origin,
    orb: OrbConfig | None = None,
) -> LandmarkDb:
    """Create a new, empty database file (refuses to overwrite) and open it writable."""
    p = Path(path)
    if p.exists():
        raise LandmarkDbError(f"{p} already exists")
    if not p.parent.is_dir():
        raise LandmarkDbError(f"folder {p.parent} does not exist")
    orb = orb or OrbConfig()
    conn = sqlite3.connect(p, check_same_thread=False)
    try:
        conn.executescript(f"BEGIN; {_V1} COMMIT;")
        with conn:
            conn.executemany(
                "INSERT INTO metadata VALUES (?, ?)",
                [
                    ("origin_lat_deg", repr(origin.lat_deg)),
                    ("origin_lon_deg", repr(origin.lon_deg)),
                    ("origin_alt_m", repr(origin.alt_m)),
                    ("orb_n_features", str(orb.n_features)),
                    ("orb_max_side_px", str(orb.max_side_px)),
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
        version = _version(conn, p)
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
        missing = {"metadata", "landmarks", "images", "features", "landmark_index"} - tables
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


@dataclass(frozen=True, slots=True)
class Candidate:
    """A landmark that passed the gate, with its distance (m) to the 2-sigma ellipse."""

    id: int
    x_m: float
    y_m: float
    distance_m: float


def query_gate(
    db: LandmarkDb,
    mean_xy: Sequence[float],
    cov_xy: Sequence[Sequence[float]],
    range_m: float,
    k2: float = CHI2_2D_2SIGMA,
    limit: int | None = None,
) -> list[Candidate]:
    """Landmarks within ``range_m`` of the ``k2`` ellipse, nearest first (``landmark_db.gate``);
    those inside the ellipse by Mahalanobis distance from the mean.

    R*Tree box first, then the exact distance-to-ellipse test on what the box returned.
    """
    ids, xy = db.in_box(*gate_box(mean_xy, cov_xy, k2, range_m))
    if len(ids) == 0:
        return []
    mask, dist = in_gate(xy, mean_xy, cov_xy, k2, range_m)
    keep = np.flatnonzero(mask)
    # Nearest to the ellipse first; inside it (distance 0), most likely first (Mahalanobis).
    d2 = mahalanobis_sq(xy[keep], mean_xy, cov_xy)
    keep = keep[np.lexsort((ids[keep], d2, dist[keep]))]
    if limit is not None:
        keep = keep[:limit]
    return [Candidate(int(ids[i]), float(xy[i, 0]), float(xy[i, 1]), float(dist[i])) for i in keep]


def query_radius(db: LandmarkDb, x_m: float, y_m: float, radius_m: float) -> list[Candidate]:
    """Landmarks within ``radius_m`` of a point, nearest first (distance is to the point)."""
    return query_gate(db, (x_m, y_m), ((0.0, 0.0), (0.0, 0.0)), radius_m)
