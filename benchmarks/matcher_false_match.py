"""False-match rate and recall of the landmark decision rule (issue 22; docs/landmarks.md).

``--part synthetic``: the calibration. Simulated facades (``hal_sim.sim_camera``), one photo
per building; frames of each building, of a look-alike of it (same style and window grid,
other details) and of an unrelated facade, every frame against every photo of another
building (the wrong pairs). Prints the tail of ``-log10 NFA`` over the wrong pairs, its
exponential fit, and the level at which the fitted tail gives ``--target`` false matches per
frame with ``--photos`` photos compared per frame. This is where ``matcher.MAX_LOG10_NFA``
comes from; no real photo takes part.

``--part real``: the check, on data the rule was not chosen on. Every ordered pair of
distinct files of ../shared/data/images and ../shared/data/images2: the wrong pairs (two
places) with the shipped rule, per pair and per query (a query against every photo of every
other place), with 95 % Wilson intervals; recall over the positive pairs, by condition.

``--frames dark3 dark5 blur``: the same with the queries degraded (``wrong_pairs.degrade``:
underexposed by 3 or 5 stops, motion blur), the photos as they are.

    python benchmarks/matcher_false_match.py [--part synthetic|real|all] [--frames none dark5]
        [--cache DIR]   # e.g. three runs, --fit-seeds 22 23 / 24 25 / 26 27, then one pooling
"""

from __future__ import annotations

import argparse
import math
import time
from collections import defaultdict
from pathlib import Path

import cv2
import numpy as np

from landmark_db.features import (
    EXTRACTOR_VERSIONS,
    PHOTO_MAX_SIDE_PX,
    ExtractorConfig,
    Features,
    extract,
)
from landmark_db.matcher import (
    MAX_LOG10_NFA,
    MIN_COSINE,
    RATIO_EXCLUSION_PX,
    REPROJ_PX,
    MatchConfig,
    PairMatcher,
    PhotoIndex,
)
from landmark_db.recognise import FRAME_FEATURES
from landmark_db.wrong_pairs import (
    DEGRADATIONS,
    decide_queries,
    positive,
    query_false_matches,
    score_pairs,
    shared_images,
    wilson,
    wrong,
)

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"


def _rate(k: int, n: int) -> str:
    lo, hi = wilson(k, n)
    return f"{k}/{n} = {k / max(n, 1):.4f} (95% {lo:.4f}-{hi:.4f})"


def _synthetic_pairs(n_buildings: int, seed: int, kind: str) -> np.ndarray:
    """Every (frame, photo) pair of one synthetic city: structured rows (frame kind: 0
    landmark, 1 look-alike, 2 unrelated scene; right: the frame shows that photo's building;
    log10 NFA; inliers)."""
    from hal_sim.sim_camera import SimCamera, facade

    ext = ExtractorConfig(kind, max_side_px=PHOTO_MAX_SIDE_PX[kind])
    frame_ext = ext.for_frames(FRAME_FEATURES)
    det, frame_det = ext.create(), frame_ext.create()
    cam = SimCamera([], seed)
    rng = np.random.default_rng([seed, 22])
    seeds = [int(s) for s in rng.integers(1, 2**40, n_buildings)]
    index = [PhotoIndex(i, extract(facade(s), ext, det)) for i, s in enumerate(seeds)]
    frames: list[tuple[int, int, Features]] = []  # (building shown or -1, kind, features)
    for i, s in enumerate(seeds):
        d = float(rng.uniform(0.0, 20.0))
        frames.append((i, 0, extract(cam.view(facade(s), d), frame_ext, frame_det)))
        other = int(rng.integers(1, 2**40))
        look = facade(other, family_seed=s)
        frames.append((-1, 1, extract(cam.view(look, d), frame_ext, frame_det)))
        frames.append((-1, 2, extract(cam.view(facade(other + 1), d), frame_ext, frame_det)))
    matcher = PairMatcher(MatchConfig())
    rows = []
    for shown, fkind, f in frames:
        desc = f.for_matching()
        for ph in index:
            e = matcher.verify(ph.photo_id, f, desc, ph)
            rows.append((fkind, ph.photo_id == shown, e.log_nfa, e.inliers))
    return np.array(rows, dtype=PAIR_DTYPE)


PAIR_DTYPE = np.dtype([("frame", "i1"), ("right", "?"), ("log_nfa", "f8"), ("inliers", "i4")])
FRAME_KINDS = ("landmark", "lookalike", "scene")


def _synthetic_city(
    n_buildings: int, seed: int, kind: str, cache: Path | None = None
) -> tuple[np.ndarray, dict[str, int], dict[str, int], int]:
    """(-log10 NFA of every wrong pair, verified wrong pairs by frame kind, wrong pairs by
    frame kind, right pairs verified) for one synthetic city, by the shipped rule. With
    ``cache``, the city's pair scores are kept there (keyed by the extractor's identity and
    the matcher's constants), so cities can be scored by several processes at once and
    pooled by a last run."""
    ident = ExtractorConfig(kind, max_side_px=PHOTO_MAX_SIDE_PX[kind]).ident.replace("/", "_")
    key = f"{ident}-{REPROJ_PX[kind]}-{MIN_COSINE}-{RATIO_EXCLUSION_PX}-{n_buildings}-{seed}"
    path = None if cache is None else cache / f"synthetic-{key}.npy"
    if path is not None and path.exists():
        pairs = np.load(path)
    else:
        pairs = _synthetic_pairs(n_buildings, seed, kind)
        if path is not None:
            path.parent.mkdir(parents=True, exist_ok=True)
            np.save(path.with_suffix(".part.npy"), pairs)
            path.with_suffix(".part.npy").rename(path)
    cfg = MatchConfig()
    ok = (pairs["inliers"] >= cfg.min_inliers) & (pairs["log_nfa"] <= cfg.nfa_needed(kind))
    wrong_ = ~pairs["right"]
    hits = {k: int(np.sum(ok & wrong_ & (pairs["frame"] == i))) for i, k in enumerate(FRAME_KINDS)}
    n_wrong = {k: int(np.sum(wrong_ & (pairs["frame"] == i))) for i, k in enumerate(FRAME_KINDS)}
    lnfa = pairs["log_nfa"][wrong_]
    t = np.where(np.isfinite(lnfa), -lnfa, -np.inf)
    return t, hits, n_wrong, int(np.sum(ok & pairs["right"]))


def tail_level(t: np.ndarray, per_pair: float, t0: float = 0.0) -> tuple[float, float, float]:
    """(level, p0, rate): the -log10 NFA at which an exponential tail fitted above ``t0``,
    ``P(T > t) = p0 exp(-rate (t - t0))``, reaches ``per_pair``; ``p0`` at its upper Wilson
    bound and the rate at a lower bound (normal approximation of the Gamma), so the fit is
    pessimistic on both counts."""
    exc = t[t > t0] - t0
    m = len(exc)
    if m < 5:
        return math.inf, 1.0, 0.0
    p0 = wilson(m, len(t))[1]
    lam = (m / float(exc.sum())) * max(1.0 - 1.96 / math.sqrt(m), 0.1)
    return t0 + math.log(p0 / per_pair) / lam, p0, lam


def synthetic(
    n_buildings: int, fit_seeds: list[int], check_seeds: list[int], target: float, photos: int,
    kind: str, cache: Path | None = None,
) -> None:  # fmt: skip
    per_pair = target / photos
    shipped = -MAX_LOG10_NFA[kind]
    pooled: list[np.ndarray] = []
    for part, seeds in (("fit", fit_seeds), ("check", check_seeds)):
        if not seeds:
            continue
        ts = []
        by_rule = 0
        for seed in seeds:
            t, hits, n_wrong, right_ok = _synthetic_city(n_buildings, seed, kind, cache)
            ts.append(t)
            by_rule += sum(hits.values())
            by = ", ".join(
                f"{k} {hits[k]}/{n_wrong[k]}" for k in ("landmark", "lookalike", "scene")
            )
            print(
                f"synthetic ({kind}) {part} city {seed}: {n_buildings} buildings,"
                f" {3 * n_buildings} frames; wrong pairs verified by the shipped rule, by frame:"
                f" {by}; right pairs verified {right_ok}/{n_buildings}"
            )
        t = np.concatenate(ts)
        n = len(t)
        print(f"  {part} ({len(seeds)} cities, {n} wrong pairs):")
        for lvl in (0, 2, 4, 6, 8):
            print(f"    -log10 NFA > {lvl}: {_rate(int(np.sum(t > lvl)), n)}")
        print(
            f"    at the shipped level: {_rate(int(np.sum(t >= shipped)), n)}; verified by the"
            f" shipped rule (with the inlier floor): {_rate(by_rule, n)}"
        )
        if part == "fit":
            pooled = ts
            level, p0, lam = tail_level(t, per_pair)
            print(
                f"    tail fit above 0: p0 <= {p0:.4f}, rate >= {lam:.2f} per decade (ORSA's"
                f" ideal null: {math.log(10):.2f}); level for {target:g} false matches per frame"
                f" at {photos} photos ({per_pair:.2g} per pair): log10 NFA <= {-level:.2f}"
                f" (shipped: {-shipped:g})"
            )
    if pooled and check_seeds:
        print(f"  (the check cities took no part in the fit; per pair the claim is {per_pair:.2g})")


def real(images: Path, images2: Path, kind: str, frames_as: str = "none") -> None:
    ims = shared_images(images, images2)
    if not ims:
        print(f"no shared images under {images} or {images2}")
        return
    t0 = time.perf_counter()
    ext = ExtractorConfig(kind, max_side_px=PHOTO_MAX_SIDE_PX[kind])
    scores = score_pairs(ims, extractor=ext, frames_as=frames_as)
    dt = time.perf_counter() - t0
    cfg = MatchConfig()
    print(
        f"real ({kind}, queries {frames_as}): {len(ims)} images, {len(scores)} ordered pairs"
        f" scored in {dt:.1f} s;"
        f" rule: log10 NFA <= {cfg.nfa_needed(kind):g} and >= {cfg.min_inliers} inliers"
    )
    groups = sorted({im.group for im in ims})
    for g in [*groups, "all"]:
        sel = [s for s in scores if g == "all" or ims[s.query].group == g]
        w = wrong(ims, sel)
        fm = sum(s.verified for s in w)
        print(f"[{g}] wrong pairs verified (false matches per pair): {_rate(fm, len(w))}")
        qf = query_false_matches(ims, sel)
        qs = [q for q in qf if g == "all" or ims[q].group == g]
        print(
            f"[{g}] queries matching another place (all other places' photos):"
            f" {_rate(sum(qf[q] for q in qs), len(qs))}"
        )
        tw = [-s.log_nfa for s in w if math.isfinite(s.log_nfa)]
        worst = max(tw, default=-math.inf)
        print(
            f"[{g}] most significant wrong pair: log10 NFA {-worst:.2f};"
            f" most inliers of a wrong pair {max((s.inliers for s in w), default=0)}"
        )
        pos = positive(ims, sel)
        print(f"[{g}] recall over positive pairs: {_rate(sum(s.verified for s in pos), len(pos))}")
        by: dict[str, list[int]] = defaultdict(lambda: [0, 0])
        for s in pos:
            c = ims[s.query].condition or "-"
            by[c][0] += s.verified
            by[c][1] += 1
        cond = ", ".join(f"{c} {a}/{b}" for c, (a, b) in sorted(by.items()))
        print(f"[{g}] recall by condition: {cond}")
    for several in (False, True):
        dec = decide_queries(ims, scores, several)
        label = "several photos per place" if several else "one photo per place"
        for g in [*groups, "all"]:
            sel = [d for d in dec if g == "all" or ims[d.query].group == g]
            full = [d for d in sel if not d.leave_one_out]
            ok = sum(d.correct(ims) for d in full)
            fm = sum(d.false(ims) for d in sel)
            by: dict[str, list[int]] = defaultdict(lambda: [0, 0])
            for d in full:
                c = ims[d.query].condition or "-"
                by[c][0] += d.correct(ims)
                by[c][1] += 1
            cond = ", ".join(f"{c} {a}/{b}" for c, (a, b) in sorted(by.items()))
            print(
                f"[{g}] queries, {label} (database: every place of both sets): recall"
                f" {_rate(ok, len(full))}; false matches {fm} of {len(sel)} runs"
                f" (full + leave-one-out); by condition: {cond}"
            )
    # what the old rule (12 inliers) would do on the same pairs, for comparison
    w = wrong(ims, scores)
    pos = positive(ims, scores)
    print(
        "old rule (>= 12 inliers) on the same pairs: wrong"
        f" {sum(s.inliers >= 12 for s in w)}/{len(w)}, recall"
        f" {sum(s.inliers >= 12 for s in pos)}/{len(pos)}"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--part", choices=("synthetic", "real", "all"), default="all")
    ap.add_argument("--buildings", type=int, default=60)
    ap.add_argument("--fit-seeds", type=int, nargs="*", default=[22, 23, 24, 25])
    ap.add_argument("--check-seeds", type=int, nargs="*", default=[26, 27])
    ap.add_argument("--target", type=float, default=1e-3, help="false matches per frame")
    ap.add_argument("--photos", type=int, default=6, help="photos compared per frame")
    ap.add_argument("--extractor", choices=sorted(EXTRACTOR_VERSIONS), default="rootsift")
    ap.add_argument(
        "--frames",
        nargs="+",
        choices=DEGRADATIONS,
        default=["none"],
        help="--part real: the queries as taken (darkN: N stops underexposed; blur)",
    )
    ap.add_argument(
        "--cache",
        type=Path,
        default=None,
        help="keep each synthetic city's pair scores here (score cities in parallel runs)",
    )
    ap.add_argument("--images", type=Path, default=SHARED / "images")
    ap.add_argument("--images2", type=Path, default=SHARED / "images2")
    args = ap.parse_args()
    cv2.setNumThreads(1)
    if args.part in ("synthetic", "all"):
        synthetic(
            args.buildings, args.fit_seeds, args.check_seeds, args.target, args.photos,
            args.extractor, args.cache,
        )  # fmt: skip
    if args.part in ("real", "all"):
        for how in args.frames:
            real(args.images, args.images2, args.extractor, how)


if __name__ == "__main__":
    main()
