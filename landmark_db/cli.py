"""``landmark-db``: build, inspect, query and check the landmark database (docs/landmarks.md).

Every error the user can fix prints one line on stderr and exits with status 2.
"""

from __future__ import annotations

import argparse
import csv
import importlib.metadata
import math
import sqlite3
import sys
from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np

from guidance.errors import UserError
from landmark_db.features import OrbConfig
from landmark_db.gate import GATE_PROBABILITY_2SIGMA
from landmark_db.geo import Origin
from landmark_db.recognise import Recogniser, RecogniserConfig, RecognitionResult
from landmark_db.store import (
    DEFAULT_POSITION_SIGMA_M,
    LandmarkDb,
    LandmarkDbError,
    create_db,
    migrate,
    open_db,
    query_gate,
)

EXIT_USER_ERROR = 2
_ORB = OrbConfig()
_REC = RecogniserConfig()


def _read_image(path: Path) -> np.ndarray:
    image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if image is None:
        raise UserError(f"{path}: not a readable image")
    return image


def _ellipse_cov(semi_major_m: float, semi_minor_m: float, angle_deg: float) -> np.ndarray:
    """Covariance whose 2-sigma ellipse has these semi-axes, major axis ``angle_deg`` from x."""
    a = math.radians(angle_deg)
    rot = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
    d = np.diag([(semi_major_m / 2.0) ** 2, (semi_minor_m / 2.0) ** 2])
    return np.asarray(rot @ d @ rot.T)


def _position(db: LandmarkDb, args: argparse.Namespace) -> tuple[float, float]:
    if args.latlon:
        return db.origin.to_local(*args.latlon)
    if args.at:
        return float(args.at[0]), float(args.at[1])
    raise UserError("give a position: --at X Y or --latlon LAT LON")


def _area(
    db: LandmarkDb, args: argparse.Namespace
) -> tuple[tuple[float, float], list[list[float]], float]:
    """(mean, covariance, range) of a query from --at/--latlon with --radius/--cov/--ellipse."""
    mean = _position(db, args)
    if args.cov:
        pxx, pxy, pyy = args.cov
        cov = np.array([[pxx, pxy], [pxy, pyy]], dtype=np.float64)
        if not (pxx >= 0 and pyy >= 0 and pxx * pyy - pxy * pxy >= 0):
            raise UserError("--cov must be a positive semi-definite covariance")
        return mean, cov.tolist(), args.range
    if args.ellipse:
        major, minor, angle = args.ellipse
        if not (major >= minor >= 0):
            raise UserError("--ellipse needs SEMI_MAJOR >= SEMI_MINOR >= 0")
        return mean, _ellipse_cov(major, minor, angle).tolist(), args.range
    return mean, [[0.0, 0.0], [0.0, 0.0]], args.radius


def _print_landmark_row(lm_id: int, db: LandmarkDb, extra: str = "") -> None:
    lm = db.get(lm_id)
    if lm is None:
        return
    facing = "-" if lm.facing_deg is None else f"{lm.facing_deg:.0f}"
    print(
        f"{lm.id:>6}  {lm.name:<24.24} {lm.lat_deg:11.6f} {lm.lon_deg:11.6f}"
        f" {lm.x_m:10.1f} {lm.y_m:10.1f} {facing:>6} {extra}"
    )


HEADER = f"{'id':>6}  {'name':<24} {'lat':>11} {'lon':>11} {'x_m':>10} {'y_m':>10} {'facing':>6}"


# --- commands ---------------------------------------------------------------------------------


def cmd_init(args: argparse.Namespace) -> None:
    try:
        origin = Origin(args.origin[0], args.origin[1])
        orb = OrbConfig(n_features=args.features, max_side_px=args.max_side)
    except ValueError as exc:
        raise UserError(str(exc)) from exc
    with create_db(args.db, origin, orb) as db:
        print(f"created {db.path} (origin {origin.lat_deg:.6f}, {origin.lon_deg:.6f})")


def cmd_migrate(args: argparse.Namespace) -> None:
    path = Path(args.db)
    if not path.is_file():
        raise UserError(f"{path}: no such file")
    conn = sqlite3.connect(path)
    try:
        version = migrate(conn, path)
    finally:
        conn.close()
    print(f"{path}: schema v{version}")


def _add_kwargs(lat: float | None, lon: float | None, x: float | None, y: float | None) -> dict:
    if lat is not None and lon is not None:
        return {"lat_deg": lat, "lon_deg": lon}
    if x is not None and y is not None:
        return {"x_m": x, "y_m": y}
    raise UserError("give a position: --latlon LAT LON or --xy X Y")


def cmd_add(args: argparse.Namespace) -> None:
    path = Path(args.image)
    if not path.is_file():
        raise UserError(f"{path}: no such image")
    lat, lon = args.latlon if args.latlon else (None, None)
    x, y = args.xy if args.xy else (None, None)
    with open_db(args.db, readonly=False) as db:
        lid = db.add(
            args.name or path.stem,
            path.read_bytes(),
            facing_deg=args.facing,
            position_sigma_m=args.sigma,
            source=str(path.name),
            **_add_kwargs(lat, lon, x, y),
        )
        print(f"added landmark {lid}")
        print(HEADER)
        _print_landmark_row(lid, db)


def _csv_float(row: dict[str, str], *keys: str) -> float | None:
    for k in keys:
        v = (row.get(k) or "").strip()
        if v:
            return float(v)
    return None


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
        added = 0
        for i, row in enumerate(rows, start=2):
            where = f"{csv_path}:{i}"
            name = (row.get("image") or row.get("file") or "").strip()
            if not name:
                raise UserError(f"{where}: no image column value")
            image = folder / name
            if not image.is_file():
                raise UserError(f"{where}: {image} not found")
            try:
                kw = _add_kwargs(
                    _csv_float(row, "lat", "lat_deg"),
                    _csv_float(row, "lon", "lon_deg"),
                    _csv_float(row, "x_m", "x"),
                    _csv_float(row, "y_m", "y"),
                )
                facing = _csv_float(row, "facing_deg", "facing")
                sigma = _csv_float(row, "sigma_m", "position_sigma_m")
            except ValueError as exc:
                raise UserError(f"{where}: {exc}") from exc
            except UserError as exc:
                raise UserError(f"{where}: {exc}") from exc
            try:
                db.add(
                    (row.get("name") or "").strip() or image.stem,
                    image.read_bytes(),
                    facing_deg=facing,
                    position_sigma_m=DEFAULT_POSITION_SIGMA_M if sigma is None else sigma,
                    source=name,
                    **kw,
                )
            except LandmarkDbError as exc:
                raise UserError(f"{where}: {exc}") from exc
            added += 1
        print(f"imported {added} landmarks into {db.path} ({len(db)} in total)")


def cmd_list(args: argparse.Namespace) -> None:
    with open_db(args.db) as db:
        print(HEADER)
        n = 0
        for lm in db.landmarks():
            _print_landmark_row(lm.id, db)
            n += 1
        print(f"{n} landmarks")


def cmd_show(args: argparse.Namespace) -> None:
    with open_db(args.db) as db:
        lm = db.find(args.landmark)
        if lm is None:
            raise UserError(f"no landmark {args.landmark!r}")
        feats = db.features(lm.id)
        img = db.image_bytes(lm.id)
        for key in ("id", "name", "lat_deg", "lon_deg", "x_m", "y_m", "facing_deg"):
            print(f"{key:>18}: {getattr(lm, key)}")
        print(f"{'position_sigma_m':>18}: {lm.position_sigma_m}")
        print(f"{'added_utc':>18}: {lm.added_utc}")
        print(f"{'source':>18}: {lm.source}")
        if img is not None:
            print(f"{'image':>18}: {img[0]}, {len(img[1])} bytes")
        if feats is not None:
            print(f"{'features':>18}: {len(feats)} ORB keypoints on {feats.width}x{feats.height}")
        if args.image_out and img is not None:
            Path(args.image_out).write_bytes(img[1])
            print(f"photo written to {args.image_out}")


def cmd_query(args: argparse.Namespace) -> None:
    with open_db(args.db) as db:
        mean, cov, range_m = _area(db, args)
        cands = query_gate(db, mean, cov, range_m, limit=args.limit)
        print(
            f"gate: 2-sigma ellipse (P={GATE_PROBABILITY_2SIGMA:.3f}) around"
            f" ({mean[0]:.1f}, {mean[1]:.1f}) plus {range_m:.1f} m"
        )
        print(HEADER + f" {'dist_m':>8}")
        for c in cands:
            _print_landmark_row(c.id, db, f"{c.distance_m:8.1f}")
        print(f"{len(cands)} candidates")


def _print_match(res: RecognitionResult, db: LandmarkDb) -> None:
    if res.reason is None and res.landmark_id is not None:
        lm = db.get(res.landmark_id)
        name = lm.name if lm else "?"
        print(f"match: landmark {res.landmark_id} ({name})")
    else:
        print(f"no match: {res.reason}")
    print(f"frame features: {res.frame_features}; {res.elapsed_s * 1000:.0f} ms")
    print(f"{'id':>6}  {'name':<24} {'good':>5} {'inliers':>7}  result")
    for e in sorted(res.evidence, key=lambda e: (-e.inliers, -e.good_matches)):
        lm = db.get(e.landmark_id)
        print(
            f"{e.landmark_id:>6}  {(lm.name if lm else '?'):<24.24} {e.good_matches:>5}"
            f" {e.inliers:>7}  {e.reason or 'verified (' + e.model + ')'}"
        )


def cmd_match(args: argparse.Namespace) -> None:
    image = _read_image(Path(args.image))
    with open_db(args.db) as db:
        rec = Recogniser(db)
        if args.at or args.latlon:
            mean, cov, range_m = _area(db, args)
            ids = [c.id for c in query_gate(db, mean, cov, range_m, limit=args.limit)]
            print(f"{len(ids)} candidates near ({mean[0]:.1f}, {mean[1]:.1f})")
        else:
            ids = None
        res = rec.match_image(image, ids)
        _print_match(res, db)


def cmd_check(args: argparse.Namespace) -> None:
    with open_db(args.db) as db:
        report = db.check(decode_images=not args.quick)
    for p in report.problems:
        print(p)
    if report.ok:
        print(f"{args.db}: ok ({report.landmarks} landmarks)")
    else:
        raise UserError(f"{args.db}: {len(report.problems)} problem(s)")


def cmd_export(args: argparse.Namespace) -> None:
    out = Path(args.out)
    if out.exists() and any(out.iterdir()):
        raise UserError(f"{out} exists and is not empty")
    (out / "images").mkdir(parents=True, exist_ok=True)
    with open_db(args.db) as db:
        n = 0
        with (out / "landmarks.csv").open("w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(["id", "name", "image", "lat", "lon", "x_m", "y_m", "facing_deg", "sigma_m"])
            for lm in db.landmarks():
                img = db.image_bytes(lm.id)
                fname = ""
                if img is not None:
                    fname = f"images/{lm.id:06d}.{'jpg' if img[0] == 'jpeg' else 'png'}"
                    (out / fname).write_bytes(img[1])
                w.writerow(
                    [
                        lm.id,
                        lm.name,
                        fname,
                        f"{lm.lat_deg:.9f}",
                        f"{lm.lon_deg:.9f}",
                        f"{lm.x_m:.3f}",
                        f"{lm.y_m:.3f}",
                        "" if lm.facing_deg is None else lm.facing_deg,
                        lm.position_sigma_m,
                    ]
                )
                n += 1
    print(f"exported {n} landmarks to {out} (landmarks.csv + images/)")
    print(f"re-import with: landmark-db import NEW.sqlite {out}")


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
        saved, notes = sv.survey(db, frames, marks, track, args.prefix, args.max_gap, args.sigma)
        for s in saved:
            print(
                f"saved landmark {s.landmark_id} {s.name}"
                f" (mark t={s.t_s:.2f}, frame t={s.frame_t_s:.2f})"
            )
        for n in notes:
            print(f"skipped: {n}")
        print(f"{len(saved)} landmarks saved, {len(notes)} marks skipped")


def cmd_acceptance(args: argparse.Namespace) -> None:
    from landmark_db.acceptance import evaluate

    folder = Path(args.folder)
    if not folder.is_dir():
        raise UserError(f"{folder}: not a folder (the shared data is optional)")
    report = evaluate(folder)
    print(f"{'query':<22} {'run':<5} {'expected':<14} {'matched':<14} {'reason':<16} good inl")
    for o in report.outcomes:
        best = max(o.result.evidence, key=lambda e: (e.inliers, e.good_matches), default=None)
        print(
            f"{o.query.name:<22} {'loo' if o.leave_one_out else 'full':<5}"
            f" {o.expected or '-':<14} {o.matched or '-':<14} {o.result.reason or 'match':<16}"
            f" {best.good_matches if best else 0:>4} {best.inliers if best else 0:>3}"
        )
    print(
        f"landmarks {report.landmarks}; positive queries {report.positives};"
        f" correct {report.true_matches}; false matches {report.false_matches};"
        f" precision {report.precision:.3f}; recall {report.recall:.3f}"
    )


# --- parser -----------------------------------------------------------------------------------


def _area_args(p: argparse.ArgumentParser, radius_default: float | None) -> None:
    p.add_argument("--at", nargs=2, type=float, metavar=("X", "Y"), help="local metres")
    p.add_argument("--latlon", nargs=2, type=float, metavar=("LAT", "LON"))
    g = p.add_mutually_exclusive_group()
    g.add_argument("--radius", type=float, default=radius_default, help="metres (a circle)")
    g.add_argument(
        "--cov",
        nargs=3,
        type=float,
        metavar=("PXX", "PXY", "PYY"),
        help="x-y covariance (m^2); gate = its 2-sigma ellipse plus --range",
    )
    g.add_argument(
        "--ellipse",
        nargs=3,
        type=float,
        metavar=("A", "B", "ANGLE_DEG"),
        help="2-sigma ellipse semi-axes (m) and major-axis angle from east (deg)",
    )
    p.add_argument(
        "--range",
        type=float,
        default=_REC.sighting_range_m,
        help="camera sighting range added to the ellipse (m, default %(default)s)",
    )
    p.add_argument("--limit", type=int, default=None, help="at most this many candidates")


def _version() -> str:
    """The urban-guidance distribution's version, as ``guidance.version.version`` finds it
    (landmark_db may not import it: tests/test_layers.py)."""
    try:
        return importlib.metadata.version("urban-guidance")
    except importlib.metadata.PackageNotFoundError:
        import tomllib

        try:
            pyproject = Path(__file__).resolve().parents[1] / "pyproject.toml"
            return str(tomllib.loads(pyproject.read_text())["project"]["version"])
        except (OSError, KeyError, TypeError, tomllib.TOMLDecodeError):
            return "unknown"


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="landmark-db", description=__doc__)
    ap.add_argument("--version", action="version", version=f"landmark-db {_version()}")
    sub = ap.add_subparsers(dest="command", required=True)

    p = sub.add_parser("init", help="create an empty database")
    p.add_argument("db")
    p.add_argument(
        "--origin",
        nargs=2,
        type=float,
        required=True,
        metavar=("LAT", "LON"),
        help="origin of the local east-north frame",
    )
    p.add_argument(
        "--features",
        type=int,
        default=_ORB.n_features,
        help="ORB features per photo (default %(default)s)",
    )
    p.add_argument(
        "--max-side",
        type=int,
        default=_ORB.max_side_px,
        help="photos are described at most this many pixels wide (default %(default)s)",
    )
    p.set_defaults(func=cmd_init)

    p = sub.add_parser("migrate", help="bring an older database file to the current schema")
    p.add_argument("db")
    p.set_defaults(func=cmd_migrate)

    p = sub.add_parser("add", help="add one landmark photo at a position")
    p.add_argument("db")
    p.add_argument("image")
    p.add_argument("--name")
    p.add_argument("--latlon", nargs=2, type=float, metavar=("LAT", "LON"))
    p.add_argument("--xy", nargs=2, type=float, metavar=("X", "Y"), help="local metres")
    p.add_argument("--facing", type=float, help="heading the photo faces (deg clockwise from N)")
    p.add_argument(
        "--sigma",
        type=float,
        default=DEFAULT_POSITION_SIGMA_M,
        help="1-sigma of the position (m, default %(default)s)",
    )
    p.set_defaults(func=cmd_add)

    p = sub.add_parser("import", help="a folder of photos plus a CSV of positions")
    p.add_argument("db")
    p.add_argument("folder")
    p.add_argument(
        "--csv",
        help="columns image,[name],lat,lon or x_m,y_m,[facing_deg],[sigma_m]"
        " (default FOLDER/landmarks.csv)",
    )
    p.set_defaults(func=cmd_import)

    p = sub.add_parser("list", help="all landmarks")
    p.add_argument("db")
    p.set_defaults(func=cmd_list)

    p = sub.add_parser("show", help="one landmark (by id or name)")
    p.add_argument("db")
    p.add_argument("landmark")
    p.add_argument("--image-out", help="write its photo to this file")
    p.set_defaults(func=cmd_show)

    p = sub.add_parser("query", help="candidates around a position or inside an ellipse")
    p.add_argument("db")
    _area_args(p, radius_default=_REC.sighting_range_m)
    p.set_defaults(func=cmd_query)

    p = sub.add_parser("match", help="match an image against candidates (or all) with evidence")
    p.add_argument("db")
    p.add_argument("image")
    _area_args(p, radius_default=_REC.sighting_range_m)
    p.set_defaults(func=cmd_match)

    p = sub.add_parser("check", help="integrity and consistency check")
    p.add_argument("db")
    p.add_argument("--quick", action="store_true", help="skip decoding every photo")
    p.set_defaults(func=cmd_check)

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
        "--max-gap", type=float, default=1.0, help="a mark needs a frame within this many seconds"
    )
    p.add_argument("--prefix", default="survey", help="name prefix of unnamed marks")
    p.add_argument("--sigma", type=float, default=5.0, help="position 1-sigma (m)")
    p.set_defaults(func=cmd_survey)

    p = sub.add_parser("acceptance", help="precision/recall on real image pairs")
    p.add_argument("folder", nargs="?", default=str(Path("..") / "shared" / "data" / "images"))
    p.set_defaults(func=cmd_acceptance)
    return ap


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        args.func(args)
    except (UserError, ValueError) as exc:
        print(f"landmark-db: error: {exc}", file=sys.stderr)
        return EXIT_USER_ERROR
    except sqlite3.Error as exc:
        print(f"landmark-db: error: database: {exc}", file=sys.stderr)
        return EXIT_USER_ERROR
    except OSError as exc:
        print(f"landmark-db: error: {exc.strerror or exc}: {exc.filename or ''}", file=sys.stderr)
        return EXIT_USER_ERROR
    except KeyboardInterrupt:
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(main())
