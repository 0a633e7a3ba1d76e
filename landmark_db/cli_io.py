"""``landmark-db import``, ``export`` and ``survey``: photos in and out of the database."""

from __future__ import annotations

import argparse
import csv
import re
import sys
from pathlib import Path
from typing import TextIO

from guidance.errors import UserError
from landmark_db.cli_args import out
from landmark_db.inputs import open_csv, read_photo
from landmark_db.limits import MAX_CSV_FIELD_CHARS, MAX_CSV_ROWS, MAX_PHOTO_BYTES
from landmark_db.store import DEFAULT_POSITION_SIGMA_M, LandmarkDb, open_db


def add_kwargs(lat: float | None, lon: float | None, x: float | None, y: float | None) -> dict:
    if lat is not None and lon is not None:
        return {"lat_deg": lat, "lon_deg": lon}
    if x is not None and y is not None:
        return {"x_m": x, "y_m": y}
    raise UserError("give a position: --latlon LAT LON or --xy X Y")


_NUMBER = re.compile(r"[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?")
_FORMULA_START = ("=", "+", "-", "@", "\t", "\r")


def _csv_float(row: dict[str, str], *keys: str) -> float | None:
    for k in keys:
        v = (row.get(k) or "").strip()
        if v:
            if not _NUMBER.fullmatch(v):
                raise UserError(f"{k} {v[:40]!r} is not a number")
            return float(v)
    return None


def _text(row: dict[str, str], *keys: str) -> str:
    """A text cell; the quote ``export`` puts before a formula-like text is taken off."""
    for k in keys:
        v = (row.get(k) or "").strip()
        if v:
            return v[1:] if v[:1] == "'" and v[1:2] in ("=", "+", "-", "@") else v
    return ""


def cell(text: str) -> str:
    """A text cell as ``export`` writes it: a leading = + - @ (a spreadsheet formula) or
    control character is neutralised by a quote in front (OWASP CSV injection)."""
    return "'" + text if text.startswith(_FORMULA_START) else text


def read_csv(path: Path) -> list[dict[str, str]]:
    """The rows of a CSV file, bounded before reading (``limits``); one-line errors."""
    rows: list[dict[str, str]] = []
    line = 0
    try:
        with open_csv(path, "utf-8-sig") as fh:
            reader = csv.DictReader(fh)
            for row in reader:
                line = reader.line_num
                if len(rows) >= MAX_CSV_ROWS:
                    raise UserError(f"{path}: more than {MAX_CSV_ROWS} rows")
                if None in row:
                    raise UserError(f"{path}:{line}: more fields than the header names")
                for k, v in row.items():
                    if len(k or "") > MAX_CSV_FIELD_CHARS or len(v or "") > MAX_CSV_FIELD_CHARS:
                        raise UserError(
                            f"{path}:{line}: a field longer than {MAX_CSV_FIELD_CHARS} characters"
                        )
                rows.append(row)
    except csv.Error as exc:
        raise UserError(f"{path}:{line + 1}: {exc}") from exc
    except UnicodeDecodeError as exc:
        raise UserError(f"{path}: not UTF-8 text ({exc.reason} at byte {exc.start})") from exc
    except OSError as exc:
        raise UserError(f"{path}: {exc.strerror}") from exc
    return rows


def _resolved(path: Path, what: str) -> Path:
    """``path`` through its symbolic links; a loop of them (RuntimeError before Python 3.13,
    OSError after) or another failure is one line naming ``what``."""
    try:
        return path.resolve()
    except RuntimeError:
        raise UserError(f"{what}: a loop of symbolic links") from None
    except OSError as exc:
        raise UserError(f"{what}: {exc.strerror or exc}") from None


def _image_path(root: Path, value: str, allow_outside: bool) -> Path:
    """The photo a CSV row names: inside the import folder (no absolute path, no ``..``,
    no symbolic link out of it) unless ``allow_outside``; at most ``MAX_PHOTO_BYTES``."""
    rel = Path(value)
    if not allow_outside and (rel.is_absolute() or ".." in rel.parts):
        raise UserError(f"image {value!r} is outside the folder (--allow-outside permits it)")
    image = _resolved(root / rel, f"image {value!r}")
    if not allow_outside and not image.is_relative_to(root):
        raise UserError(f"image {value!r} leads outside the folder (--allow-outside permits it)")
    if not image.is_file():
        raise UserError(f"{image} not found")
    if image.stat().st_size > MAX_PHOTO_BYTES:
        raise UserError(f"{image}: larger than {MAX_PHOTO_BYTES // 2**20} MiB")
    return image


def _import_row(
    db: LandmarkDb,
    root: Path,
    row: dict[str, str],
    groups: dict[str, int],
    allow_outside: bool,
) -> str:
    """Add or update one CSV row: its landmark (same ``id`` value, else same name, as an
    earlier row: another photo of it; a landmark of that name already in the file: updated,
    not duplicated) and its photo (the same photo again: updated). A landmark without a
    ``name`` is named by its ``id`` value, else by the image's file name. Returns "added",
    "updated" or "photo"."""
    name_col = _text(row, "image", "file")
    if not name_col:
        raise UserError("no image column value")
    image = _image_path(root, name_col, allow_outside)
    group = _text(row, "id")
    name = _text(row, "name") or group or image.stem
    key = f"id:{group}" if group else f"name:{name}"
    facing = _csv_float(row, "facing_deg", "facing")
    sigma = _csv_float(row, "sigma_m", "position_sigma_m")
    conditions = _text(row, "conditions", "condition")
    data = read_photo(image)
    if key in groups:
        db.add_photo(groups[key], data, facing_deg=facing, conditions=conditions, source=name_col)
        return "photo"
    kw = add_kwargs(
        _csv_float(row, "lat", "lat_deg"),
        _csv_float(row, "lon", "lon_deg"),
        _csv_float(row, "x_m", "x"),
        _csv_float(row, "y_m", "y"),
    )
    sigma_m = DEFAULT_POSITION_SIGMA_M if sigma is None else sigma
    existing = db.by_name(name)
    if existing is not None:
        db.update(existing.id, facing_deg=facing, position_sigma_m=sigma_m, source=name_col, **kw)
        db.add_photo(existing.id, data, facing_deg=facing, conditions=conditions, source=name_col)
        groups[key] = existing.id
        return "updated"
    groups[key] = db.add(
        name, data, facing_deg=facing, position_sigma_m=sigma_m, source=name_col,
        conditions=conditions, **kw,
    )  # fmt: skip
    return "added"


def progress(what: str, done: int, total: int, stream: TextIO | None = None) -> None:
    """``what: done/total (N %)`` on stderr: rewritten in place on a terminal, else one line
    each tenth (a log stays short)."""
    stream = stream if stream is not None else sys.stderr
    tty = stream.isatty()
    step = max(1, total // 10)
    if not tty and done % step and done != total:
        return
    text = f"{what}: {done}/{total} ({100 * done // max(1, total)} %)"
    stream.write(f"\r{text}" + ("\n" if done == total or not tty else ""))
    stream.flush()


def cmd_import(args: argparse.Namespace) -> None:
    """All rows or none: one transaction; a landmark already in the file (by name) is updated
    and a photo already there is not added twice, so importing again changes nothing."""
    folder = Path(args.folder)
    csv_path = Path(args.csv) if args.csv else folder / "landmarks.csv"
    if not folder.is_dir():
        raise UserError(f"{folder}: not a folder")
    rows = read_csv(csv_path)
    if not rows:
        raise UserError(f"{csv_path}: no rows")
    root = _resolved(folder, str(folder))
    with open_db(args.db, readonly=False) as db:
        groups: dict[str, int] = {}
        done = {"added": 0, "updated": 0, "photo": 0}
        where = ""
        try:
            with db.batch():
                for i, row in enumerate(rows, start=2):
                    where = f"{csv_path}:{i}"
                    done[_import_row(db, root, row, groups, args.allow_outside)] += 1
                    if getattr(args, "progress", False):
                        progress("importing photos", i - 1, len(rows))
        except (ValueError, OSError, UserError) as exc:
            why = exc.strerror if isinstance(exc, OSError) and exc.strerror else exc
            raise UserError(f"{where}: {why} (nothing imported)") from exc
        updated = f"; {done['updated']} already there, updated" if done["updated"] else ""
        out(
            f"imported {done['added']} landmarks ({len(rows)} photos) into {db.path}"
            f" ({len(db)} in total){updated}"
        )


def cmd_export(args: argparse.Namespace) -> None:
    dest = Path(args.out)
    if dest.exists() and any(dest.iterdir()):
        raise UserError(f"{dest} exists and is not empty")
    (dest / "images").mkdir(parents=True, exist_ok=True)
    with open_db(args.db) as db:
        n = 0
        with (dest / "landmarks.csv").open("w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(
                ["id", "name", "image", "lat", "lon", "x_m", "y_m", "facing_deg", "sigma_m",
                 "conditions"]
            )  # fmt: skip
            for lm in db.landmarks():
                for photo in db.photos(lm.id):
                    img = db.photo_bytes(photo.id)
                    if img is None:
                        continue
                    ext = "jpg" if img[0] == "jpeg" else "png"
                    fname = f"images/{lm.id:06d}-{photo.id:06d}.{ext}"
                    (dest / fname).write_bytes(img[1])
                    facing = photo.facing_deg if photo.facing_deg is not None else lm.facing_deg
                    w.writerow(
                        [lm.id, cell(lm.name), fname, f"{lm.lat_deg:.9f}", f"{lm.lon_deg:.9f}",
                         f"{lm.x_m:.3f}", f"{lm.y_m:.3f}", "" if facing is None else facing,
                         lm.position_sigma_m, cell(photo.conditions)]
                    )  # fmt: skip
                n += 1
    out(f"exported {n} landmarks to {dest} (landmarks.csv + images/)")
    out(f"re-import with: landmark-db import NEW.sqlite {dest}")


def cmd_survey(args: argparse.Namespace) -> None:
    from landmark_db import survey as sv

    track = sv.read_nmea(Path(args.nmea)) if args.nmea else None
    if args.marks:
        marks = sv.read_marks(Path(args.marks))
    elif track is not None:
        marks = sv.marks_every(track, args.every)
    else:
        raise UserError("give --marks CSV and/or --nmea FILE")
    if track is not None and args.nmea_offset:
        track = sv.GpsTrack(track.t_s + args.nmea_offset, track.lat_deg, track.lon_deg)
    src = Path(args.frames)
    if src.is_dir():
        frames = sv.frames_from_folder(src, args.fps)
    elif src.is_file():
        frames = sv.frames_from_video(src)
    else:
        raise UserError(f"{src}: no such video or folder")
    with open_db(args.db, readonly=False) as db, db.batch():  # the whole survey, or nothing
        saved, notes = sv.survey(
            db, frames, marks, track, args.prefix, args.max_gap, args.sigma, args.frames_per_mark
        )
        for s in saved:
            out(
                f"saved landmark {s.landmark_id} {s.name} ({s.photos} photos;"
                f" mark t={s.t_s:.2f}, frame t={s.frame_t_s:.2f})"
            )
        for note in notes:
            out(f"skipped: {note}")
        out(f"{len(saved)} landmarks saved, {len(notes)} marks skipped")


def add_io_parsers(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("import", help="a folder of photos plus a CSV of positions")
    p.add_argument("db")
    p.add_argument("folder")
    p.add_argument(
        "--csv",
        help="columns image,[id],[name],lat,lon or x_m,y_m,[facing_deg],[sigma_m],[conditions];"
        " rows with the same id (else the same name) are photos of one landmark"
        " (default FOLDER/landmarks.csv)",
    )
    p.add_argument(
        "--allow-outside",
        action="store_true",
        help="let the image column name files outside FOLDER (absolute paths, ..)",
    )
    p.add_argument("--progress", action="store_true", help="show progress on stderr")
    p.set_defaults(func=cmd_import)

    p = sub.add_parser("export", help="CSV plus an images folder (re-importable)")
    p.add_argument("db")
    p.add_argument("out")
    p.set_defaults(func=cmd_export)

    p = sub.add_parser("survey", help="save frames at marked places as new landmarks")
    p.add_argument("db")
    p.add_argument("frames", help="a video file or a folder of images")
    p.add_argument("--nmea", help="GPS NMEA log (RMC/GGA) giving positions")
    p.add_argument(
        "--nmea-offset", type=float, default=0.0, help="frame-clock time of the first GPS fix (s)"
    )
    p.add_argument("--marks", help="CSV: t_s,[name],[lat,lon | x_m,y_m]")
    p.add_argument(
        "--every",
        type=float,
        default=100.0,
        help="with GPS and no marks: a landmark every this many metres",
    )
    p.add_argument("--fps", type=float, default=1.0, help="frame rate of an image folder")
    p.add_argument(
        "--max-gap", type=float, default=1.0, help="frames within this many seconds of a mark"
    )
    p.add_argument(
        "--frames-per-mark",
        type=int,
        default=3,
        help="photos kept per mark, spread over --max-gap either side (default %(default)s)",
    )
    p.add_argument("--prefix", default="survey", help="name prefix of unnamed marks")
    p.add_argument("--sigma", type=float, default=5.0, help="position 1-sigma (m)")
    p.set_defaults(func=cmd_survey)
