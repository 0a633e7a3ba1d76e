"""``landmark-db check``: SQLite's integrity check plus the landmark file's own consistency."""

from __future__ import annotations

import hashlib
import sqlite3
from dataclasses import dataclass

from guidance.core.geo import Origin
from landmark_db.features import ExtractorConfig, Features, decode_image
from landmark_db.limits import (
    MIN_PHOTO_FEATURES,
    agreement_problem,
    position_problem,
    sigma_problem,
)


@dataclass(frozen=True, slots=True)
class CheckReport:
    """What ``check`` found: ``problems`` empty means the file is sound."""

    landmarks: int
    problems: tuple[str, ...]

    @property
    def ok(self) -> bool:
        return not self.problems


_ORPHANS = (
    (
        "without a photo",
        "SELECT id FROM landmarks WHERE id NOT IN (SELECT landmark_id FROM photos)",
    ),
    (
        "with a photo without features",
        "SELECT DISTINCT landmark_id FROM photos"
        " WHERE id NOT IN (SELECT photo_id FROM photo_features)",
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
        "SELECT landmark_id FROM photos WHERE landmark_id NOT IN (SELECT id FROM landmarks)",
    ),
    (
        "features for no photo (photo ids)",
        "SELECT photo_id FROM photo_features WHERE photo_id NOT IN (SELECT id FROM photos)",
    ),
    (
        "index box not at its position",
        "SELECT l.id FROM landmarks l JOIN landmark_index r ON r.id = l.id"
        " WHERE abs(r.min_x - l.x_m) > 0.01 OR abs(r.max_x - l.x_m) > 0.01"
        " OR abs(r.min_y - l.y_m) > 0.01 OR abs(r.max_y - l.y_m) > 0.01",
    ),
    (
        f"with a photo of fewer than {MIN_PHOTO_FEATURES} features",
        "SELECT p.landmark_id FROM photo_features f JOIN photos p ON p.id = f.photo_id"
        f" WHERE f.count < {MIN_PHOTO_FEATURES}",
    ),
)


def check(
    c: sqlite3.Connection, origin: Origin, extractor: ExtractorConfig, decode_images: bool
) -> CheckReport:
    """Every landmark has at least one photo, every photo features from the file's extractor
    that decode, the R*Tree has exactly one matching box per landmark, positions agree with
    lat/lon through the origin (within 1 m), photo checksums match and photos decode."""
    problems: list[str] = []
    try:
        res = [str(r[0]) for r in c.execute("PRAGMA integrity_check").fetchall()]
    except sqlite3.DatabaseError as exc:
        return CheckReport(0, (f"integrity_check failed: {exc}",))
    if res != ["ok"]:
        problems.extend(f"integrity: {r}" for r in res[:20])
    n = int(c.execute("SELECT count(*) FROM landmarks").fetchone()[0])
    for label, sql in _ORPHANS:
        ids = [int(r[0]) for r in c.execute(sql).fetchall()]
        if ids:
            shown = ", ".join(map(str, ids[:10])) + (" ..." if len(ids) > 10 else "")
            problems.append(f"{len(ids)} landmark(s) {label}: {shown}")
    rows = c.execute("SELECT id, lat_deg, lon_deg, x_m, y_m, position_sigma_m FROM landmarks")
    for lid, lat, lon, x, y, sigma in rows:
        try:
            why = position_problem(float(x), float(y)) or sigma_problem(float(sigma))
            if why is None:
                ex, ey = origin.to_local(float(lat), float(lon))
                why = agreement_problem(ex - x, ey - y)
        except (TypeError, ValueError) as exc:
            why = f"not a number ({exc})"
        if why is not None:
            problems.append(f"landmark {lid}: {why}")
    rows = c.execute(
        "SELECT p.landmark_id, f.photo_id, f.extractor, f.count, f.width, f.height,"
        " f.keypoints, f.descriptors FROM photo_features f JOIN photos p ON p.id = f.photo_id"
    )
    for lid, pid, ident, count, w, h, kp, desc in rows:
        if ident != extractor.ident:
            problems.append(
                f"landmark {lid} photo {pid}: features from {ident}, not {extractor.ident}"
                " (run `landmark-db migrate`)"
            )
            continue
        try:
            f = Features.from_blobs(bytes(kp), bytes(desc), w, h, extractor.kind)
            if len(f) != count:
                raise ValueError(f"{len(f)} features stored, count says {count}")
        except (ValueError, TypeError) as exc:
            problems.append(f"landmark {lid} photo {pid}: bad features: {exc}")
    if decode_images:
        for lid, pid, data, digest in c.execute("SELECT landmark_id, id, data, sha256 FROM photos"):
            if hashlib.sha256(bytes(data)).hexdigest() != digest:
                problems.append(f"landmark {lid} photo {pid}: checksum mismatch")
                continue
            try:
                decode_image(bytes(data))
            except ValueError:
                problems.append(f"landmark {lid} photo {pid}: does not decode")
    return CheckReport(n, tuple(problems))
