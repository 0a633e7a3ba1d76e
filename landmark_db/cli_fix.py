"""``landmark-db migrate``, ``remove`` and ``edit``: bring a file up to date, mend one landmark.

``migrate`` works on a copy beside the file (SQLite's backup, with the file's mode): the
schema migrations, every landmark row and photo checked against the limits ``import`` uses
(``landmark_db.limits``), the features recomputed, and the copy opened as the car opens it
(read-only, every row checked) before it is renamed over the original. Rows the car would
refuse are refused with a line each and nothing changes; with ``--quarantine DIR`` they are
moved out of the file into DIR as ``landmarks.csv`` plus ``images/`` (the ``export`` format,
with a ``problem`` column), to be fixed and imported again. Any failure leaves the original
file as it was. ``remove ID`` deletes one landmark; ``edit ID`` changes its position, sigma,
facing or name, through the same checks as ``add``.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import math
import os
import sqlite3
import stat
from collections.abc import Callable
from pathlib import Path

from guidance.errors import UserError, number, number_in
from landmark_db.cli_args import err, out, safe
from landmark_db.cli_io import cell
from landmark_db.features import PHOTO_MAX_SIDE_PX, ExtractorConfig, decode_image
from landmark_db.limits import (
    MAX_TEXT_CHARS,
    MIN_PHOTO_FEATURES,
    agreement_problem,
    photo_problem,
    position_problem,
    sigma_problem,
)
from landmark_db.schema import SCHEMA_VERSION, LandmarkDbError
from landmark_db.store import MAX_ID_DIGITS, LandmarkDb, open_db
from landmark_db.writes import name_problem

Problem = tuple[int, int | None, str]
"""(landmark id, photo id or None for the whole landmark, why)."""


def _num(v: object) -> float:
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
        raise ValueError(f"{safe(v)!r} is not a finite number")
    return float(v)


def _landmark_problems(db: LandmarkDb) -> list[Problem]:
    """Every landmark row the tools would not write (``add`` / ``import``)."""
    found: list[Problem] = []
    rows = db._conn.execute(
        "SELECT id, name, lat_deg, lon_deg, x_m, y_m, facing_deg, position_sigma_m, source"
        " FROM landmarks ORDER BY id"
    ).fetchall()
    for lid, name, lat, lon, x, y, facing, sigma, source in rows:
        why: str | None
        try:
            why = name_problem(name if isinstance(name, str) else "")
            x_m, y_m = _num(x), _num(y)
            why = why or position_problem(x_m, y_m) or sigma_problem(_num(sigma))
            if why is None:
                la, lo = _num(lat), _num(lon)
                if not (-90.0 <= la <= 90.0 and -180.0 <= lo <= 180.0):
                    why = f"lat/lon {la}, {lo} out of range"
                else:
                    ex, ey = db.origin.to_local(la, lo)
                    why = agreement_problem(ex - x_m, ey - y_m)
            if why is None and facing is not None:
                _num(facing)
            if why is None and len(str(source)) > MAX_TEXT_CHARS:
                why = f"source longer than {MAX_TEXT_CHARS} characters"
        except ValueError as exc:
            why = f"a value {exc}"
        if why is not None:
            found.append((int(lid), None, why))
    return found


def _photo_problems(db: LandmarkDb, decode: bool) -> list[Problem]:
    """Photos of a refused size, that do not decode (``decode``), or with too few features."""
    found: list[Problem] = []
    rows = db._conn.execute(
        "SELECT p.landmark_id, p.id, p.width, p.height, p.data, f.count FROM photos p"
        " LEFT JOIN photo_features f ON f.photo_id = p.id ORDER BY p.id"
    ).fetchall()
    for lid, pid, w, h, data, count in rows:
        why = None
        if not (isinstance(w, int) and isinstance(h, int)):
            why = "its size is not a number"
        else:
            why = photo_problem(w, h)
        if why is None and decode:
            try:
                decode_image(bytes(data))
            except (ValueError, TypeError):
                why = "it does not decode"
        if why is None and not decode and isinstance(count, int) and count < MIN_PHOTO_FEATURES:
            why = f"{count} features, fewer than {MIN_PHOTO_FEATURES}"
        if why is not None:
            found.append((int(lid), int(pid), why))
    return found


class _Quarantine:
    """The rows moved out of a migrated file: ``landmarks.csv`` + ``images/`` in ``folder``."""

    def __init__(self, folder: Path) -> None:
        if folder.exists() and (not folder.is_dir() or any(folder.iterdir())):
            raise UserError(f"{folder} exists and is not an empty folder")
        self.folder = folder
        self.rows: list[list[object]] = []

    def take(self, db: LandmarkDb, problems: list[Problem]) -> None:
        """Copy the refused landmarks and photos here, then delete them from ``db``."""
        (self.folder / "images").mkdir(parents=True, exist_ok=True)
        c = db._conn
        for lid, pid, why in problems:
            lm = c.execute(
                "SELECT name, lat_deg, lon_deg, x_m, y_m, facing_deg, position_sigma_m"
                " FROM landmarks WHERE id = ?",
                (lid,),
            ).fetchone()
            sql = "SELECT id, format, data, facing_deg, conditions FROM photos WHERE landmark_id=?"
            if lm is None:  # moved out already (a landmark and one of its photos refused)
                continue
            photos = c.execute(sql + ("" if pid is None else " AND id = ?"),
                               (lid,) if pid is None else (lid, pid)).fetchall()  # fmt: skip
            for ph_id, fmt, data, ph_facing, conditions in photos:
                ext = "jpg" if fmt == "jpeg" else "png"
                fname = f"images/{lid:06d}-{ph_id:06d}.{ext}"
                (self.folder / fname).write_bytes(bytes(data))
                name, lat, lon, x, y, facing, sigma = lm
                self.rows.append([
                    lid, cell(str(name)), fname, lat, lon, x, y,
                    ph_facing if ph_facing is not None else facing, sigma,
                    cell(str(conditions)), why,
                ])  # fmt: skip
            if pid is not None:
                with c:
                    c.execute("DELETE FROM photo_features WHERE photo_id = ?", (pid,))
                    c.execute("DELETE FROM photos WHERE id = ?", (pid,))
                left = c.execute("SELECT count(*) FROM photos WHERE landmark_id = ?", (lid,))
                if left.fetchone()[0] > 0:
                    continue
            db.remove(lid)  # a refused landmark, or one left without a photo

    def write(self) -> None:
        with (self.folder / "landmarks.csv").open("w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(["id", "name", "image", "lat", "lon", "x_m", "y_m", "facing_deg",
                        "sigma_m", "conditions", "problem"])  # fmt: skip
            w.writerows(self.rows)


def _refuse_or_quarantine(
    path: Path, db: LandmarkDb, problems: list[Problem], quarantine: _Quarantine | None
) -> None:
    for lid, pid, why in problems:
        what = f"landmark {lid}" + ("" if pid is None else f" photo {pid}")
        err(f"landmark-db: {path}: {what}: {why}" + (" (quarantined)" if quarantine else ""))
    if problems and quarantine is None:
        raise UserError(
            f"{path}: {len(problems)} row(s) the car would refuse; nothing migrated, the file is"
            " unchanged: fix them (`landmark-db edit`, `remove`) or move them out with"
            " `--quarantine DIR`"
        )
    if problems and quarantine is not None:
        quarantine.take(db, problems)


def _copy(src: Path, dest: Path) -> None:
    """``src`` copied to ``dest`` through SQLite (a consistent snapshot), with its mode."""
    mode = stat.S_IMODE(src.stat().st_mode)
    source = sqlite3.connect(src, timeout=2.0)
    try:
        target = sqlite3.connect(dest)
        try:
            source.backup(target)
            target.execute("PRAGMA journal_mode = DELETE")
        finally:
            target.close()
    finally:
        source.close()
    os.chmod(dest, mode)


def cmd_migrate(args: argparse.Namespace) -> None:
    """See the module docstring."""
    path = Path(args.db)
    if not path.is_file():
        raise UserError(f"{path}: no such file")
    target = path.resolve()  # a symbolic link stays one: the file it names is migrated
    mode = stat.S_IMODE(target.stat().st_mode)
    if not mode & 0o222 or not os.access(target, os.W_OK):
        raise UserError(f"{path} is read-only (mode {mode:04o}): nothing migrated")
    quarantine = _Quarantine(Path(args.quarantine)) if args.quarantine else None
    tmp = target.with_name(f".{target.name}.migrate-{os.getpid()}.tmp")
    try:
        _copy(target, tmp)
        for side in ("-wal", "-journal"):
            other = target.with_name(target.name + side)
            if other.exists() and other.stat().st_size > 0:
                raise UserError(f"{path}: {other.name} beside it: another program has it open")
        with open_db(tmp, readonly=False) as db:  # the schema migrations, on the copy
            db.path = path  # messages name the user's file
            if args.extractor:
                max_side = args.max_side or PHOTO_MAX_SIDE_PX[args.extractor]
                try:
                    ext = ExtractorConfig(args.extractor, args.features, max_side)
                except ValueError as exc:
                    raise UserError(str(exc)) from exc
            else:
                ext = db.extractor
            problems = _landmark_problems(db) + _photo_problems(db, decode=True)
            _refuse_or_quarantine(path, db, problems, quarantine)
            n = db.refresh_features(ext)
            late = _photo_problems(db, decode=False)
            _refuse_or_quarantine(path, db, late, quarantine)
            moved = len(problems) + len(late)
        try:
            open_db(tmp).close()  # the car's open: every row checked
        except LandmarkDbError as exc:
            why = str(exc).replace(str(tmp), str(path))
            raise UserError(f"{why}; nothing migrated, the file is unchanged") from None
        if quarantine is not None and moved:
            quarantine.write()
        fd = os.open(tmp, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
        os.replace(tmp, target)
    finally:
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()
        with contextlib.suppress(FileNotFoundError):
            tmp.with_name(tmp.name + "-journal").unlink()
    out(f"{path}: schema v{SCHEMA_VERSION}; features {ext.ident} ({n} photo(s) recomputed)")
    if quarantine is not None and moved:
        out(
            f"{moved} row(s) moved to {quarantine.folder} (landmarks.csv + images/): fix them"
            f" there, then `landmark-db import {path} {quarantine.folder}`"
        )


def _landmark(db: LandmarkDb, key: str) -> int:
    """The id of the landmark ``key`` names (ASCII digits: an id; else a name), read even when
    its values are bad. An id beyond SQLite's integers (30 digits) is no landmark, never a
    traceback; a name two landmarks share is refused (which one would go?)."""
    if key.isascii() and key.isdigit():
        if len(key) > MAX_ID_DIGITS:  # SQLite's integers end at 2^63 - 1
            raise UserError(f"no landmark {safe(key[:24])!r}")
        rows = db._conn.execute("SELECT id FROM landmarks WHERE id = ?", (int(key),)).fetchall()
    else:
        rows = db._conn.execute(
            "SELECT id FROM landmarks WHERE name = ? ORDER BY id LIMIT 2", (key,)
        ).fetchall()
    if not rows:
        raise UserError(f"no landmark {safe(key[:80])!r}")
    if len(rows) > 1:
        raise UserError(f"more than one landmark is named {safe(key[:80])!r}: give its id")
    return int(rows[0][0])


def cmd_remove(args: argparse.Namespace) -> None:
    with open_db(args.db, readonly=False) as db:
        lid = _landmark(db, args.landmark)
        db.remove(lid)
        out(f"removed landmark {lid} ({len(db)} left)")


def cmd_edit(args: argparse.Namespace) -> None:
    with open_db(args.db, readonly=False) as db:
        lid = _landmark(db, args.landmark)
        row = db._conn.execute(
            "SELECT x_m, y_m, facing_deg, position_sigma_m, source FROM landmarks WHERE id = ?",
            (lid,),
        ).fetchone()
        x, y, facing, sigma, source = row
        if args.latlon is not None:
            pos = {"lat_deg": args.latlon[0], "lon_deg": args.latlon[1]}
        elif args.xy is not None:
            pos = {"x_m": args.xy[0], "y_m": args.xy[1]}
        else:  # where it is (a bad stored position is refused: give --xy or --latlon)
            pos = {"x_m": x, "y_m": y}
        try:
            with db.batch():
                db.update(
                    lid,
                    facing_deg=args.facing if args.facing is not None else facing,
                    position_sigma_m=args.sigma if args.sigma is not None else sigma,
                    source=str(source),
                    **pos,
                )
                if args.name is not None:
                    same = db.by_name(args.name)
                    if same is not None and same.id != lid:  # names are spoken and used by --to
                        raise LandmarkDbError(
                            f"a landmark named {safe(args.name)!r} exists (id {same.id})"
                        )
                    db.rename(lid, args.name)
        except (LandmarkDbError, TypeError, ValueError) as exc:
            raise UserError(f"landmark {lid} not changed: {exc}") from None
        lm = db.get(lid)
        assert lm is not None
        out(
            f"landmark {lid} ({safe(lm.name)}): x {lm.x_m:.2f} m, y {lm.y_m:.2f} m, sigma"
            f" {lm.position_sigma_m:g} m, facing {'-' if lm.facing_deg is None else lm.facing_deg}"
        )


def add_fix_parsers(
    sub: argparse._SubParsersAction,
    extractor_args: Callable[[argparse.ArgumentParser, str | None], None],
) -> None:
    """``migrate``, ``remove`` and ``edit``; ``extractor_args(parser, default)`` adds the
    extractor options (``landmark_db.cli``)."""
    p = sub.add_parser(
        "migrate", help="bring an older file to the current schema and features (all or nothing)"
    )
    p.add_argument("db")
    extractor_args(p, None)
    p.add_argument(
        "--quarantine",
        metavar="DIR",
        help="move rows the car would refuse into DIR (landmarks.csv + images/) instead of"
        " refusing the migration",
    )
    p.set_defaults(func=cmd_migrate)

    p = sub.add_parser("remove", help="delete one landmark (by id or name) with its photos")
    p.add_argument("db")
    p.add_argument("landmark", metavar="ID|NAME")
    p.set_defaults(func=cmd_remove)

    p = sub.add_parser("edit", help="change one landmark's position, sigma, facing or name")
    p.add_argument("db")
    p.add_argument("landmark", metavar="ID|NAME")
    where = p.add_mutually_exclusive_group()  # one position, never two
    where.add_argument("--latlon", nargs=2, type=number, metavar=("LAT", "LON"))
    where.add_argument("--xy", nargs=2, type=number, metavar=("X", "Y"), help="local metres")
    p.add_argument("--sigma", type=number, help="1-sigma of the position (m)")
    p.add_argument(
        "--facing",
        type=number_in(-360.0, 360.0),
        help="heading the photo faces (deg clockwise from N)",
    )
    p.add_argument("--name", help="a new name")
    p.set_defaults(func=cmd_edit)
