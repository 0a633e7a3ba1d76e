"""Issue 36's figures on the shared real photos, through the command line (validation only:
nothing here chose a threshold).

Places: ../shared/data/images (A/B pairs, LePoint1-3 one place, the box) and images2 (two
places). Each place's first file is its photo (``landmark-db import``, places 100 m apart);
its other files are queries.

* ``add --to``: every query offered to its own landmark with the landmark's position
  (``--xy``, so the weaker same-place check applies) is accepted or refused; every query
  offered to another place at that place's position must be refused (a false admission).
* ``locate``: a database of every place's photo among ``--distractors`` simulated facades
  (``landmark-db locate --json``), each query located; then leave-one-out: each place removed
  (``landmark-db remove``) and its queries located again, where any answer is false.

One photo / several photos per place and their leave-one-out runs are ``landmark-db
acceptance`` (run it beside this: ``landmark-db acceptance ../shared/data/images [--several]``).

    python benchmarks/landmark_real_cli.py [--distractors 300] [--extractor rootsift]
        [--frames none|dark3|dark5|blur]   # the queries as a worse camera takes them
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import io
import json
import shutil
import tempfile
import time
from collections import defaultdict
from dataclasses import replace
from pathlib import Path

import numpy as np

from hal_sim.sim_camera import facade, photo_seed
from landmark_db.cli import main as cli
from landmark_db.features import (
    PHOTO_MAX_SIDE_PX,
    ExtractorConfig,
    decode_image,
    encode_image,
    extract,
)
from landmark_db.search import scene_decades
from landmark_db.store import open_db
from landmark_db.threads import cap_threads
from landmark_db.wrong_pairs import DEGRADATIONS, LabelledImage, degrade, shared_images, wilson

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"


def run(*argv: str) -> tuple[int, str]:
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf), contextlib.redirect_stderr(io.StringIO()):
        code = cli(list(argv))
    return code, buf.getvalue()


def _rate(k: int, n: int) -> str:
    lo, hi = wilson(k, n)
    return f"{k}/{n} = {k / max(n, 1):.2f} (95% {lo:.2f}-{hi:.2f})"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--distractors", type=int, default=300)
    ap.add_argument("--extractor", default="rootsift")
    ap.add_argument(
        "--frames",
        choices=DEGRADATIONS,
        default="none",
        help="the queries as taken (wrong_pairs.degrade: darkN underexposed by N stops, blur)",
    )
    ap.add_argument("--images", type=Path, default=SHARED / "images")
    ap.add_argument("--images2", type=Path, default=SHARED / "images2")
    args = ap.parse_args()
    cap_threads(1)
    ims = shared_images(args.images, args.images2)
    if not ims:
        print("no shared images: nothing to do")
        return
    first: dict[str, LabelledImage] = {}
    queries: list[LabelledImage] = []
    for im in ims:
        if im.place in first:
            queries.append(im)
        else:
            first[im.place] = im
    places = sorted(first)
    xy = {p: (100.0 * i, 0.0) for i, p in enumerate(places)}
    tmp = Path(tempfile.mkdtemp(prefix="real-cli-"))
    try:
        if args.frames != "none":
            (tmp / "queries").mkdir()
            taken = []
            for k, q in enumerate(queries):
                out = tmp / "queries" / f"{k:02d}-{q.path.stem}.png"
                img = degrade(decode_image(q.path.read_bytes()), args.frames, k)
                out.write_bytes(encode_image(img))
                taken.append(replace(q, path=out))
            queries = taken
        folder = tmp / "photos"
        folder.mkdir()
        with (folder / "landmarks.csv").open("w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(["image", "name", "x_m", "y_m"])
            for p in places:
                name = f"{p}{first[p].path.suffix}"
                shutil.copy(first[p].path, folder / name)
                w.writerow([name, p, *xy[p]])
        base = tmp / "base.sqlite"
        ext = ExtractorConfig(args.extractor, 1000, PHOTO_MAX_SIDE_PX[args.extractor])
        run("init", str(base), "--origin", "42.444", "-76.5019", "--extractor", ext.kind)
        code, _out = run("import", str(base), str(folder))
        assert code == 0, "import failed"
        print(
            f"{len(places)} places, {len(queries)} queries ({args.extractor}, queries"
            f" {args.frames})"
        )
        add_to(base, tmp, queries, places, xy)
        locate(base, tmp, queries, places, ext, args.distractors)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def add_to(
    base: Path, tmp: Path, queries: list[LabelledImage], places: list[str], xy: dict
) -> None:
    ok = 0
    by: dict[str, list[int]] = defaultdict(lambda: [0, 0])
    false = 0
    for k, q in enumerate(queries):
        db = tmp / f"add{k}.sqlite"
        shutil.copy(base, db)
        code, _ = run("add", str(db), str(q.path), "--to", q.place, "--xy", *map(str, xy[q.place]))
        ok += code == 0
        by[q.condition or "-"][0] += code == 0
        by[q.condition or "-"][1] += 1
        other = places[(places.index(q.place) + 1) % len(places)]
        code, _ = run("add", str(db), str(q.path), "--to", other, "--xy", *map(str, xy[other]))
        false += code == 0
        db.unlink()
    cond = ", ".join(f"{c} {a}/{b}" for c, (a, b) in sorted(by.items()))
    print(f"add --to (own landmark, its position): accepted {_rate(ok, len(queries))}; {cond}")
    print(
        f"add --to (another landmark, its position): accepted (false) {_rate(false, len(queries))}"
    )


def locate(
    base: Path,
    tmp: Path,
    queries: list[LabelledImage],
    places: list[str],
    ext: ExtractorConfig,
    n_distractors: int,
) -> None:
    t0 = time.perf_counter()
    city = tmp / "city.sqlite"
    shutil.copy(base, city)
    tiny = encode_image(np.zeros((8, 8), np.uint8))
    det = ext.create()
    with open_db(city, readonly=False) as db:
        for i in range(n_distractors):
            f = extract(facade(photo_seed(3636, i)), ext, det)
            db.add_many_precomputed([(f"d{i:04d}", 5000.0 + 30.0 * i, 0.0)], f, tiny, index=False)
        db.rebuild_global_index()
    print(
        f"locate: {len(places)} places among {n_distractors} simulated facades"
        f" (built in {time.perf_counter() - t0:.0f} s)"
    )
    found = false = 0
    by: dict[str, list[int]] = defaultdict(lambda: [0, 0])
    ms: list[float] = []
    past: list[float] = []
    _code, out = run("locate", str(city), *[str(q.path) for q in queries], "--json")
    for q, line in zip(queries, out.splitlines(), strict=True):
        rec = json.loads(line)
        ms.append(rec.get("ms", 0.0))
        got = rec.get("landmark")
        found += got == q.place
        if got == q.place:
            nfa = min(e["log10_nfa"] for e in rec["evidence"] if e["name"] == got)
            past.append(rec["level_log10_nfa"] - nfa)
        false += got is not None and got != q.place
        by[q.condition or "-"][0] += got == q.place
        by[q.condition or "-"][1] += 1
    cond = ", ".join(f"{c} {a}/{b}" for c, (a, b) in sorted(by.items()))
    print(f"  located {_rate(found, len(queries))}; wrong place {false}; {cond}")
    if past:
        # what a lost car needs beyond the level to act on one frame (search.scene_level)
        margin = scene_decades(ext.kind)
        print(
            f"  located queries, decades past the level: min {min(past):.1f}, median"
            f" {float(np.median(past)):.1f}; past the lost car's margin ({margin:g}):"
            f" {sum(p >= margin for p in past)} of {len(past)}"
        )
    loo_false = loo_n = 0
    for p in places:
        qs = [q for q in queries if q.place == p]
        if not qs:
            continue
        db = tmp / "loo.sqlite"
        shutil.copy(city, db)
        run("remove", str(db), p)
        _code, out = run("locate", str(db), *[str(q.path) for q in qs], "--json")
        for line in out.splitlines():
            loo_n += 1
            loo_false += json.loads(line).get("landmark") is not None
        db.unlink()
    print(f"  leave-one-out (own place removed): false {loo_false} of {loo_n} runs")
    print(f"  locate ms median {np.median(ms):.0f}, max {np.max(ms):.0f}")


if __name__ == "__main__":
    main()
