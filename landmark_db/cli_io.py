"""``landmark-db import``, ``export`` and ``survey``: photos in and out of the database."""

from __future__ import annotations

import argparse
import csv
from pathlib import Path

from guidance.errors import UserError
from landmark_db.cli_args import out
from landmark_db.store import DEFAULT_POSITION_SIGMA_M, LandmarkDb, open_db


def add_kwargs(lat: float | None, lon: float | None, x: float | None, y: float | None) -> dict:
    if lat is not None and lon is not None:
        return {"lat_deg": lat, "lon_deg": lon}
    if x is not None and y is not None:
        return {"x_m": x, "y_m": y}
    raise UserError("give a position: --latlon LAT LON or --xy X Y")


def _csv_float(row: dict[str, str], *keys: str) -> float | None:
    for k in keys:
        v = (row.get(k) or "").strip()
        if v:
            return float(v)
    return None


def _import_row(
    db: LandmarkDb, folder: Path, row: dict[str, str], where: str, groups: dict[str, int]
) -> bool:
    """Add one CSV row: a new landmark, or (same ``id`` value, else same name, as an earlier
    row) another photo of it. A landmark without a ``name`` is named by its ``id`` value,
    else by the image's file name. Returns True for a new landmark."""
    name_col = (row.get("image") or row.get("file") or "").strip()
    if not name_col:
        raise UserError(f"{where}: no image column value")
    image = folder / name_col
    if not image.is_file():
        raise UserError(f"{where}: {image} not found")
    group = (row.get("id") or "").strip()
    name = (row.get("name") or "").strip() or group or image.stem
    key = f"id:{group}" if group else f"name:{name}"
    try:
        facing = _csv_float(row, "facing_deg", "facing")
        sigma = _csv_float(row, "sigma_m", "position_sigma_m")
        conditions = (row.get("conditions") or row.get("condition") or "").strip()
        if key in groups:
            db.add_photo(
                groups[key], image.read_bytes(), facing_deg=facing, conditions=conditions,
                source=name_col,
            )  # fmt: skip
            return False
        kw = add_kwargs(
            _csv_float(row, "lat", "lat_deg"),
            _csv_float(row, "lon", "lon_deg"),
            _csv_float(row, "x_m", "x"),
            _csv_float(row, "y_m", "y"),
        )
        groups[key] = db.add(
            name,
            image.read_bytes(),
            facing_deg=facing,
            position_sigma_m=DEFAULT_POSITION_SIGMA_M if sigma is None else sigma,
            source=name_col,
            conditions=conditions,
            **kw,
        )
        return True
    except (ValueError, UserError) as exc:
        raise UserError(f"{where}: {exc}") from exc


def cmd_import(args: argparse.Namespace) -> None:
    folder = Path(args.folder)
    csv_path = Path(args.csv) if args.csv else folder / "landmarks.csv"
    if not folder.is_dir():
        raise UserError(f"{folder}: not a folder")
    try:
        with csv_path.open(newline="") as fh:
            rows = list(csv.DictReader(fh))
    except OSError as exc:
        raise UserError(f"{csv_path}: {exc.strerror}") from exc
    if not rows:
        raise UserError(f"{csv_path}: no rows")
    with open_db(args.db, readonly=False) as db:
        groups: dict[str, int] = {}
        added = 0
        for i, row in enumerate(rows, start=2):
            added += _import_row(db, folder, row, f"{csv_path}:{i}", groups)
        out(f"imported {added} landmarks ({len(rows)} photos) into {db.path} ({len(db)} in total)")


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
                        [lm.id, lm.name, fname, f"{lm.lat_deg:.9f}", f"{lm.lon_deg:.9f}",
                         f"{lm.x_m:.3f}", f"{lm.y_m:.3f}", "" if facing is None else facing,
                         lm.position_sigma_m, photo.conditions]
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
    with open_db(args.db, readonly=False) as db:
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
