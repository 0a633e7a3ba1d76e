"""``landmark-db``: build, inspect, query and check the landmark database (docs/landmarks.md).

Every error the user can fix prints one line on stderr and exits with status 2.
"""

from __future__ import annotations

import argparse
import importlib.metadata
import math
import os
import sqlite3
import sys
from collections.abc import Sequence
from pathlib import Path

from guidance.core.geo import Origin
from guidance.errors import UserError, number, number_in
from landmark_db.cli_args import HEADER, area, area_args, print_landmark_row, safe
from landmark_db.cli_fix import add_fix_parsers
from landmark_db.cli_io import add_io_parsers, add_kwargs
from landmark_db.cli_match import add_match_parsers
from landmark_db.features import (
    EXTRACTOR_VERSIONS,
    PHOTO_MAX_SIDE_PX,
    ExtractorConfig,
    decode_image,
    extract,
)
from landmark_db.gate import GATE_PROBABILITY_2SIGMA
from landmark_db.inputs import read_photo
from landmark_db.matcher import (
    SAME_PLACE_RADIUS_M,
    agreement_config,
    photo_agreement,
)
from landmark_db.query import query_radius
from landmark_db.recognise import RecogniserConfig
from landmark_db.store import (
    DEFAULT_POSITION_SIGMA_M,
    LandmarkDb,
    create_db,
    open_db,
    query_gate,
)

EXIT_USER_ERROR = 2
_EXT = ExtractorConfig()


# --- commands ---------------------------------------------------------------------------------


def _extractor(args: argparse.Namespace) -> ExtractorConfig:
    try:
        side = args.max_side or PHOTO_MAX_SIDE_PX[args.extractor]
        return ExtractorConfig(args.extractor, args.features, side)
    except ValueError as exc:
        raise UserError(str(exc)) from exc


def cmd_init(args: argparse.Namespace) -> None:
    try:
        origin = Origin(args.origin[0], args.origin[1])
    except ValueError as exc:
        raise UserError(str(exc)) from exc
    with create_db(args.db, origin, _extractor(args)) as db:
        print(
            f"created {db.path} (origin {origin.lat_deg:.6f}, {origin.lon_deg:.6f};"
            f" features {db.extractor.ident})"
        )


def _check_agreement(
    db: LandmarkDb, lid: int, name: str, path: Path, data: bytes, near: bool = False
) -> None:
    """Refuse (one line, with the figures) a photo that does not match the landmark's own
    photos by the decision rule, or by the weaker level when its position agrees (``near``:
    ``matcher.agreement_config``)."""
    try:
        feats = extract(decode_image(data), db.extractor)
    except ValueError as exc:
        raise UserError(f"{path}: not a readable image ({exc})") from exc
    cfg = agreement_config(db.extractor.kind, near)
    e = photo_agreement(lid, feats, db.photo_features(lid), cfg)
    if e is None or e.verified:
        return
    nfa = f"{e.log_nfa:.1f}" if math.isfinite(e.log_nfa) else "none"
    level = cfg.nfa_needed(db.extractor.kind)
    kind = db.extractor.kind
    weak = agreement_config(kind, True).nfa_needed(kind)
    hint = (
        ""
        if near or weak == level
        else f"; <= {weak:g} with --xy/--latlon within {SAME_PLACE_RADIUS_M:.0f} m"
    )
    raise UserError(
        f"{path} does not match the photos of landmark {lid} ({safe(name)}): best"
        f" {e.inliers} inliers, log10 NFA {nfa} (the rule needs <= {level:g}"
        f" and >= {cfg.min_inliers} inliers{hint}); a photo that does not show the same place"
        " would make the landmark match what it shows: add it as a landmark of its own"
    )


def _near_landmark(db: LandmarkDb, lm_xy: tuple[float, float], args: argparse.Namespace) -> bool:
    """Whether ``add --to`` was given a position (--xy/--latlon) within the same-place
    radius of the landmark; a position farther away is refused."""
    if not (args.xy or args.latlon):
        return False
    xy = tuple(args.xy) if args.xy else db.origin.to_local(*args.latlon)
    d = math.hypot(xy[0] - lm_xy[0], xy[1] - lm_xy[1])
    if d > SAME_PLACE_RADIUS_M:
        raise UserError(
            f"the photo was taken {d:.0f} m from the landmark: farther than the"
            f" {SAME_PLACE_RADIUS_M:.0f} m of one place; add it as a landmark of its own"
        )
    return True


NEAR_M = 2.0 * RecogniserConfig().sighting_range_m
"""Two landmarks closer than this can be in view from one place (their sighting discs meet)."""


def _check_distinct(db: LandmarkDb, path: Path, data: bytes, where: dict[str, float]) -> None:
    """Refuse a new landmark whose photo verifies against a landmark within ``NEAR_M``: a
    match could not tell the two apart, so they are one place (add the photo ``--to`` it)."""
    try:
        if "x_m" in where:
            xy = (where["x_m"], where["y_m"])
        else:
            xy = db.origin.to_local(where["lat_deg"], where["lon_deg"])
        feats = extract(decode_image(data), db.extractor)
    except ValueError:
        return  # ``add`` refuses the position or the photo itself, with its own message
    for c in query_radius(db, xy[0], xy[1], NEAR_M):
        e = photo_agreement(c.id, feats, db.photo_features(c.id))
        if e is not None and e.verified:
            lm = db.get(c.id)
            name = safe(lm.name) if lm else "?"
            d = math.hypot(c.x_m - xy[0], c.y_m - xy[1])
            raise UserError(
                f"{path} shows landmark {c.id} ({name}) {d:.0f} m away ({e.inliers} inliers,"
                f" log10 NFA {e.log_nfa:.1f}): a match could not tell the two apart; add the"
                f" photo to it with --to {c.id}"
            )


def cmd_add(args: argparse.Namespace) -> None:
    path = Path(args.image)
    if not path.is_file():
        raise UserError(f"{path}: no such image")
    lat, lon = args.latlon if args.latlon else (None, None)
    x, y = args.xy if args.xy else (None, None)
    with open_db(args.db, readonly=False) as db:
        if args.to is not None:
            lm = db.find(args.to)
            if lm is None:
                raise UserError(f"no landmark {args.to!r}")
            data = read_photo(path)
            near = _near_landmark(db, (lm.x_m, lm.y_m), args)
            _check_agreement(db, lm.id, lm.name, path, data, near)
            pid = db.add_photo(
                lm.id, data, facing_deg=args.facing, conditions=args.conditions,
                source=path.name,
            )  # fmt: skip
            print(f"added photo {pid} to landmark {lm.id} ({safe(lm.name)})")
            print(HEADER)
            print_landmark_row(lm.id, db)
            return
        name = args.name or path.stem
        same = db.by_name(name)
        if same is not None and not args.same_name:  # names are spoken and used by --to
            raise UserError(
                f"a landmark named {safe(name)!r} exists (id {same.id}): add this photo to it "
                f"with --to {same.id}, give the new one another --name, or --same-name to keep "
                "both"
            )
        data = read_photo(path)
        kwargs = add_kwargs(lat, lon, x, y)
        _check_distinct(db, path, data, kwargs)
        lid = db.add(
            name,
            data,
            facing_deg=args.facing,
            position_sigma_m=args.sigma,
            source=str(path.name),
            conditions=args.conditions,
            **kwargs,
        )
        print(f"added landmark {lid}")
        print(HEADER)
        print_landmark_row(lid, db)


def cmd_list(args: argparse.Namespace) -> None:
    with open_db(args.db) as db:
        counts = db.photo_counts()
        print(HEADER)
        n = 0
        for lm in db.landmarks():
            print_landmark_row(lm.id, db, photos=counts.get(lm.id, 0))
            n += 1
        print(f"{n} landmarks, {sum(counts.values())} photos")


def cmd_show(args: argparse.Namespace) -> None:
    with open_db(args.db) as db:
        lm = db.find(args.landmark)
        if lm is None:
            raise UserError(f"no landmark {args.landmark!r}")
        img = db.image_bytes(lm.id)
        for key in ("id", "name", "lat_deg", "lon_deg", "x_m", "y_m", "facing_deg"):
            print(f"{key:>18}: {safe(getattr(lm, key))}")
        print(f"{'position_sigma_m':>18}: {lm.position_sigma_m}")
        print(f"{'added_utc':>18}: {safe(lm.added_utc)}")
        print(f"{'source':>18}: {safe(lm.source)}")
        feats = dict(db.photo_features(lm.id))
        for ph in db.photos(lm.id):
            f = feats.get(ph.id)
            desc = f"{len(f)} {db.extractor.kind} on {f.width}x{f.height}" if f else "no features"
            facing = "-" if ph.facing_deg is None else f"{ph.facing_deg:.0f}"
            print(
                f"{'photo ' + str(ph.id):>18}: {ph.format} {ph.width}x{ph.height}, facing {facing},"
                f" {desc}; {safe(ph.conditions) or '-'}; {safe(ph.source)}"
            )
        if args.image_out and img is not None:
            Path(args.image_out).write_bytes(img[1])
            print(f"photo written to {args.image_out}")


def cmd_query(args: argparse.Namespace) -> None:
    with open_db(args.db) as db:
        mean, cov, range_m = area(db, args)
        cands = query_gate(db, mean, cov, range_m, limit=args.limit)
        print(
            f"gate: 2-sigma ellipse (P={GATE_PROBABILITY_2SIGMA:.3f}) around"
            f" ({mean[0]:.1f}, {mean[1]:.1f}) plus {range_m:.1f} m"
        )
        print(HEADER + f" {'dist_m':>8}")
        for c in cands:
            print_landmark_row(c.id, db, f"{c.distance_m:8.1f}")
        print(f"{len(cands)} candidates")


def cmd_check(args: argparse.Namespace) -> None:
    with open_db(args.db) as db:
        report = db.check(decode_images=not args.quick)
    for p in report.problems:
        print(p)
    if report.ok:
        print(f"{args.db}: ok ({report.landmarks} landmarks)")
    else:
        raise UserError(f"{args.db}: {len(report.problems)} problem(s)")


# --- parser -----------------------------------------------------------------------------------


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


def _extractor_args(p: argparse.ArgumentParser, default: str | None) -> None:
    p.add_argument(
        "--extractor",
        choices=sorted(EXTRACTOR_VERSIONS),
        default=default,
        help="photo features (default %(default)s; docs/landmarks.md compares them)",
    )
    p.add_argument(
        "--features", type=int, default=_EXT.n_features, help="features per photo (%(default)s)"
    )
    p.add_argument(
        "--max-side",
        type=int,
        default=None,
        help="photos are described at most this many pixels wide (default: per extractor)",
    )


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="landmark-db", description=__doc__)
    ap.add_argument("--version", action="version", version=f"landmark-db {_version()}")
    sub = ap.add_subparsers(dest="command", required=True)

    p = sub.add_parser("init", help="create an empty database")
    p.add_argument("db")
    p.add_argument(
        "--origin",
        nargs=2,
        type=number,
        required=True,
        metavar=("LAT", "LON"),
        help="origin of the local east-north frame",
    )
    _extractor_args(p, _EXT.kind)
    p.set_defaults(func=cmd_init)

    add_fix_parsers(sub, _extractor_args)

    p = sub.add_parser("add", help="add a landmark photo at a position, or a photo --to one")
    p.add_argument("db")
    p.add_argument("image")
    p.add_argument("--to", metavar="ID|NAME", help="add the photo to this landmark")
    p.add_argument("--name", help="the landmark's name (default: the image's file name)")
    p.add_argument(
        "--same-name",
        action="store_true",
        help="add a new landmark even when one has this name already (refused otherwise)",
    )
    where = p.add_mutually_exclusive_group()  # one position, never two
    where.add_argument("--latlon", nargs=2, type=number, metavar=("LAT", "LON"))
    where.add_argument("--xy", nargs=2, type=number, metavar=("X", "Y"), help="local metres")
    p.add_argument(
        "--facing",
        type=number_in(-360.0, 360.0),
        help="heading the photo faces (deg clockwise from N)",
    )
    p.add_argument("--conditions", default="", help="free text: night, rain, 30 m west...")
    p.add_argument(
        "--sigma",
        type=number,
        default=DEFAULT_POSITION_SIGMA_M,
        help="1-sigma of the position (m, default %(default)s)",
    )
    p.set_defaults(func=cmd_add)

    add_io_parsers(sub)

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
    area_args(p)
    p.set_defaults(func=cmd_query)

    add_match_parsers(sub)

    p = sub.add_parser("check", help="integrity and consistency check")
    p.add_argument("db")
    p.add_argument("--quick", action="store_true", help="skip decoding every photo")
    p.set_defaults(func=cmd_check)

    return ap


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        args.func(args)
        sys.stdout.flush()
    except BrokenPipeError:
        # `landmark-db list DB | head`: the reader left; say nothing, like other Unix tools.
        # stdout is pointed at /dev/null so the interpreter's final flush cannot fail again.
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
        return 0
    except (UserError, ValueError) as exc:
        if str(exc):  # empty: already reported line by line (``match`` over many images)
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
