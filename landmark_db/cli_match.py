"""``landmark-db match``, ``locate`` and ``acceptance`` (the recognition commands)."""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np

from guidance.errors import UserError
from landmark_db.acceptance import AcceptanceReport, evaluate, evaluate_db, read_truth
from landmark_db.cli_args import area, area_args, err, out, safe
from landmark_db.features import decode_image
from landmark_db.inputs import read_photo
from landmark_db.limits import frame_problem
from landmark_db.recognise import Recogniser, RecognitionResult
from landmark_db.store import LandmarkDb, open_db, query_gate


def read_image(path: Path) -> np.ndarray:
    """An image file's pixels; ``UserError`` (one line) if missing, damaged or not an image."""
    try:
        data = read_photo(path)
    except OSError as exc:
        raise UserError(f"{path}: {exc.strerror or exc}") from exc
    try:
        return decode_image(data)
    except ValueError as exc:
        raise UserError(f"{path}: not a readable image ({exc})") from exc


def _name(db: LandmarkDb, lid: int | None) -> str | None:
    if lid is None:
        return None
    lm = db.get(lid)
    return lm.name if lm else "?"


def match_record(query: str, res: RecognitionResult, db: LandmarkDb) -> dict[str, object]:
    """One query's outcome as a JSON-ready dict (``match --json`` prints one per line)."""
    verified = res.reason is None and res.landmark_id is not None
    return {
        "query": query,
        "landmark_id": res.landmark_id if verified else None,
        "name": _name(db, res.landmark_id) if verified else None,
        "reason": res.reason,
        "frame_features": res.frame_features,
        "ms": round(res.elapsed_s * 1000.0, 1),
        "evidence": [
            {
                "landmark_id": e.landmark_id,
                "name": _name(db, e.landmark_id),
                "photo_id": e.photo_id,
                "good_matches": e.good_matches,
                "inliers": e.inliers,
                "log10_nfa": round(e.log_nfa, 2) if math.isfinite(e.log_nfa) else None,
                "result": e.reason or "verified",
            }
            for e in sorted(res.evidence, key=lambda e: (-e.inliers, -e.good_matches))
        ],
    }


def _print_match(
    query: str, res: RecognitionResult, db: LandmarkDb, many: bool, detail: str | None
) -> None:
    rec = match_record(query, res, db)
    head = f"{query}: " if many else ""
    if rec["landmark_id"] is not None:
        out(f"{head}match: landmark {rec['landmark_id']} ({rec['name']})")
    else:
        out(f"{head}no match: {res.reason}" + (f" ({detail})" if detail else ""))
    out(f"frame features: {res.frame_features}; {res.elapsed_s * 1000:.0f} ms")
    out(f"{'id':>6}  {'name':<24} {'photo':>6} {'good':>5} {'inliers':>7} {'log10 NFA':>9}  result")
    for e in sorted(res.evidence, key=lambda e: (-e.inliers, -e.good_matches)):
        out(
            f"{e.landmark_id:>6}  {safe(_name(db, e.landmark_id) or '?'):<24.24} {e.photo_id:>6}"
            f" {e.good_matches:>5} {e.inliers:>7} {_nfa(e.log_nfa):>9}"
            f"  {e.reason or 'verified (' + e.model + ')'}"
        )


def cmd_match(args: argparse.Namespace) -> None:
    """Every image in one process (the database and the photo indexes are loaded once).

    A damaged or unreadable image is reported in one line (on stderr, or as an ``error``
    record with ``--json``) and the others are still matched; the exit status is then 2.
    """
    if len(args.images) == 1:
        read_image(Path(args.images[0]))  # a single bad image: the usual one-line error
    failed = 0
    with open_db(args.db) as db:
        rec = Recogniser(db)
        ids = None
        if args.at or args.latlon:
            mean, cov, range_m = area(db, args)
            ids = [c.id for c in query_gate(db, mean, cov, range_m, limit=args.limit)]
            if not args.json:
                out(f"{len(ids)} candidates near ({mean[0]:.1f}, {mean[1]:.1f})")
        many = len(args.images) > 1
        for path in args.images:
            image = _image_or_report(path, args.json, "query")
            if image is None:
                failed += 1
                continue
            res = rec.match_image(image, ids)
            detail = frame_problem(image.shape[1], image.shape[0])
            if args.json:
                record = match_record(path, res, db)
                if detail:
                    record["detail"] = detail
                out(json.dumps(record))
            else:
                _print_match(path, res, db, many, detail)
    if failed:
        raise UserError("")  # each was reported in its line; exit status 2


def locate_record(image: str, res: RecognitionResult, db: LandmarkDb) -> dict[str, object]:
    """One image's whole-database search as a JSON-ready dict (``locate --json``)."""
    base = match_record(image, res, db)
    return {
        "image": image,
        "landmark": base["name"],
        "id": base["landmark_id"],
        "reason": res.reason,
        "level_log10_nfa": round(res.level, 2) if math.isfinite(res.level) else None,
        "shortlist": [
            {"id": lid, "name": _name(db, lid), "cosine": round(sim, 4)}
            for lid, sim in res.shortlist
        ],
        "frame_features": res.frame_features,
        "ms": base["ms"],
        "evidence": base["evidence"],
    }


def _image_or_report(path: str, as_json: bool, key: str) -> np.ndarray | None:
    """The image, or None with its error reported in the command's format (a JSON record under
    ``key``, or one ``error:`` line)."""
    try:
        return read_image(Path(path))
    except UserError as exc:
        if as_json:
            out(json.dumps({key: path, "error": str(exc)}))
        else:
            err(f"landmark-db: error: {exc}")
        return None


def cmd_locate(args: argparse.Namespace) -> None:
    """Each image searched against the whole database (``Recogniser.locate``): the place or
    ``none``, with the evidence; an unreadable image is reported in its line (exit 2)."""
    if len(args.images) == 1:
        read_image(Path(args.images[0]))
    failed = 0
    with open_db(args.db) as db:
        rec = Recogniser(db)
        for path in args.images:
            image = _image_or_report(path, args.json, "image")
            if image is None:
                failed += 1
                continue
            res = rec.locate(image)
            record = locate_record(path, res, db)
            if args.json:
                out(json.dumps(record))
                continue
            if record["id"] is not None:
                out(f"{path}: landmark {record['id']} ({safe(str(record['landmark']))})")
            else:
                out(f"{path}: none ({res.reason})")
            n_places = len(db)
            out(
                f"searched {n_places} places (shortlist {len(res.shortlist)}); level log10 NFA"
                f" <= {_nfa(res.level)}; {res.frame_features} frame features;"
                f" {res.elapsed_s * 1000:.0f} ms"
            )
            for e in sorted(res.evidence, key=lambda e: (-e.inliers, -e.good_matches)):
                out(
                    f"  {e.landmark_id:>6}  {safe(_name(db, e.landmark_id) or '?'):<24.24}"
                    f" {e.inliers:>4} inliers  log10 NFA {_nfa(e.log_nfa):>7}"
                    f"  {e.reason or 'verified'}"
                )
    if failed:
        raise UserError("")


def _nfa(v: float) -> str:
    return f"{v:.1f}" if math.isfinite(v) else "-"


def _print_report(r: AcceptanceReport, verbose: bool) -> None:
    if verbose:
        out(f"{'query':<24} {'run':<5} {'expected':<14} {'matched':<14} best-expected best-wrong")
        for o in r.outcomes:
            right = max((o.scores.get(n, 0) for n in o.accept), default=0)
            right = 0 if o.leave_one_out else right
            wrong = max((v for n, v in o.scores.items() if not o.right(n)), default=0)
            out(
                f"{o.query.name:<24.24} {'loo' if o.leave_one_out else 'full':<5}"
                f" {o.expected or '-':<14.14} {r.matched(o) or '-':<14.14} {right:>13} {wrong:>10}"
            )
    negatives = sum(1 for o in r.outcomes if o.expected is None)
    loo = sum(1 for o in r.outcomes if o.leave_one_out)
    out(
        f"landmarks {r.landmarks} ({r.photos} photos); positive queries {r.positives};"
        f" negative queries {negatives}; leave-one-out runs {loo}"
    )
    false = r.false_matches()
    out(
        f"at the shipped rule (log10 NFA <= {r.level:g}, >= {r.match.min_inliers} inliers):"
        f" correct {r.true_matches()}; false matches {len(false)};"
        f" precision {r.precision():.3f}; recall {r.recall():.3f}"
    )
    for o, got in false:
        out(f"  false match: {o.query.name} ({'loo' if o.leave_one_out else 'full'}) -> {got}")
    by = ", ".join(f"{k} {a}/{b}" for k, (a, b) in r.recall_by_condition().items())
    out(f"recall by condition: {by}")
    worst = r.wrong_scores()[:3]
    top = "; ".join(f"{o.query.name} -> {name}: {_nfa(n)} ({v} inliers)" for n, v, o, name in worst)
    out(
        f"wrong pairs {r.wrong_pairs}; most inliers {r.max_wrong}; most significant"
        f" (log10 NFA): {top or '-'}"
    )
    z = r.zero_false_level()
    margin = z - r.level if math.isfinite(z) else math.inf
    out(
        f"margin of the rule over the wrong pairs: {_nfa(margin)} decades"
        f" (zero false matches down to {_nfa(z)}, recall there {r.recall(z):.3f})"
    )


def cmd_acceptance(args: argparse.Namespace) -> None:
    if args.truth:
        if not args.db:
            raise UserError("--truth needs --db (a database made with init/import)")
        truth = read_truth(Path(args.truth), Path(args.images) if args.images else None)
        with open_db(args.db) as db:
            report = evaluate_db(db, truth)
    else:
        folder = Path(args.folder)
        if not folder.is_dir():
            raise UserError(f"{folder}: not a folder (the shared data is optional)")
        report = evaluate(folder, several=args.several)
    _print_report(report, not args.quiet)


def add_match_parsers(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("match", help="match images against candidates (or all), with evidence")
    p.add_argument("db")
    p.add_argument("images", nargs="+", metavar="image")
    p.add_argument("--json", action="store_true", help="one JSON object per image and line")
    area_args(p)
    p.set_defaults(func=cmd_match)

    p = sub.add_parser("locate", help="search the whole database for each image's place")
    p.add_argument("db")
    p.add_argument("images", nargs="+", metavar="image")
    p.add_argument("--json", action="store_true", help="one JSON object per image and line")
    p.set_defaults(func=cmd_locate)

    p = sub.add_parser("acceptance", help="precision/recall on real photos, with negatives")
    p.add_argument("folder", nargs="?", default=str(Path("..") / "shared" / "data" / "images"))
    p.add_argument("--several", action="store_true", help="all A photos of a place (shared set)")
    p.add_argument("--db", help="a database built with init/import")
    p.add_argument("--truth", help="CSV: query,expected[,condition]; expected empty = negative")
    p.add_argument("--images", help="folder the truth CSV's paths are relative to")
    p.add_argument("--quiet", action="store_true", help="summary only")
    p.set_defaults(func=cmd_acceptance)
