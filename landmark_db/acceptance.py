"""Acceptance: recall and precision of recognition on real photos, calibrated on negatives.

Input: a landmark database (``landmark-db init`` / ``import``, one or several photos per
landmark) and a ground-truth CSV with a ``query`` column (an image path, relative to the
CSV's folder or ``--images``), an ``expected`` column (the landmark's name or id; empty or
``none`` for a *negative*: a photo of a place that is not in the database) and an optional
``condition`` column (``viewpoint``, ``zoom``, ``night``...).

Runs, with the single-image check (no gate, no temporal confirmation):

* **full**: every query against every landmark; a match to another landmark is false, any
  match of a negative is false;
* **leave-one-out**: every positive query against every landmark *except* its own: any
  match is false (the look-alike test: the right answer is missing).

Scores are recorded at a raw inlier threshold of 4 (``CALIBRATION_MIN_INLIERS``), so one run
gives every decision at every threshold: a landmark is verified when its best photo's
inliers reach the threshold, and the recogniser's ambiguity rule picks among the verified
ones (``decide``). The report: precision and recall at the shipped threshold, recall by
condition, the inlier distribution of wrong pairs (every landmark other than the expected
one, both runs), the smallest threshold with zero false matches and the recommended one
with the margin ``MARGIN`` (docs/landmarks.md).

``shared_layout`` turns ../shared/data/images (A/B pairs) into such a database and CSV.
"""

from __future__ import annotations

import csv
import hashlib
import math
import tempfile
from collections import Counter, defaultdict
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from landmark_db.features import ExtractorConfig, decode_image
from landmark_db.geo import Origin
from landmark_db.matcher import MatchConfig
from landmark_db.recognise import Recogniser, RecogniserConfig
from landmark_db.store import LandmarkDb, LandmarkDbError, create_db

IMAGE_EXTS = (".png", ".jpg", ".jpeg")
CALIBRATION_MIN_INLIERS = 4
FUTURE_PAIRS_FACTOR = 10.0
"""The recommended threshold must hold for this many times the calibration's wrong pairs."""
FUTURE_FALSE_MATCHES = 0.05
"""... with at most this many expected wrong pairs reaching it (``recommended_threshold``)."""


@dataclass(frozen=True, slots=True)
class TruthRow:
    query: Path
    expected: str | None
    """Landmark name (or id) it shows; None for a negative (must match nothing)."""
    condition: str = ""


@dataclass(frozen=True, slots=True)
class Outcome:
    query: Path
    expected: str | None
    leave_one_out: bool
    condition: str
    scores: dict[str, int]
    """Landmark name -> inliers of its best photo (0: no plausible homography)."""


def decide(scores: dict[str, int], threshold: int, ambiguity_ratio: float) -> str | None:
    """The recogniser's decision from per-landmark scores: the best verified landmark unless
    a second verified one comes within ``ambiguity_ratio`` (``Recogniser._match``)."""
    ok = sorted(((v, k) for k, v in scores.items() if v >= threshold), reverse=True)
    if not ok or (len(ok) > 1 and ok[0][0] < ambiguity_ratio * ok[1][0]):
        return None
    return ok[0][1]


@dataclass(frozen=True, slots=True)
class AcceptanceReport:
    landmarks: int
    photos: int
    outcomes: tuple[Outcome, ...]
    threshold: int
    """The threshold the figures below are at (the shipped default unless overridden)."""
    ambiguity_ratio: float

    def matched(self, o: Outcome, threshold: int | None = None) -> str | None:
        t = self.threshold if threshold is None else threshold
        return decide(o.scores, t, self.ambiguity_ratio)

    @property
    def positives(self) -> int:
        return sum(1 for o in self.outcomes if not o.leave_one_out and o.expected is not None)

    def true_matches(self, threshold: int | None = None) -> int:
        return sum(
            1 for o in self.outcomes if o.expected is not None and not o.leave_one_out
            and self.matched(o, threshold) == o.expected
        )  # fmt: skip

    def false_matches(self, threshold: int | None = None) -> list[tuple[Outcome, str]]:
        out = []
        for o in self.outcomes:
            m = self.matched(o, threshold)
            if m is not None and (o.leave_one_out or m != o.expected):
                out.append((o, m))
        return out

    def recall(self, threshold: int | None = None) -> float:
        return self.true_matches(threshold) / self.positives if self.positives else 0.0

    def precision(self, threshold: int | None = None) -> float:
        t, f = self.true_matches(threshold), len(self.false_matches(threshold))
        return t / (t + f) if t + f else 1.0

    def recall_by_condition(self, threshold: int | None = None) -> dict[str, tuple[int, int]]:
        """condition -> (correct, positives) in the full run."""
        out: dict[str, list[int]] = defaultdict(lambda: [0, 0])
        for o in self.outcomes:
            if o.expected is None or o.leave_one_out:
                continue
            out[o.condition or "-"][1] += 1
            out[o.condition or "-"][0] += self.matched(o, threshold) == o.expected
        return {k: (v[0], v[1]) for k, v in sorted(out.items())}

    def wrong_scores(self) -> list[tuple[int, Outcome, str]]:
        """(inliers, outcome, landmark) of every wrong pair, highest first."""
        out = [
            (v, o, name)
            for o in self.outcomes
            for name, v in o.scores.items()
            if o.leave_one_out or name != o.expected
        ]
        return sorted(out, key=lambda t: -t[0])

    @property
    def max_wrong(self) -> int:
        w = self.wrong_scores()
        return w[0][0] if w else 0

    @property
    def zero_false_threshold(self) -> int:
        """The smallest threshold at which no wrong pair verifies."""
        return max(self.max_wrong + 1, CALIBRATION_MIN_INLIERS)

    def tail_ratio(self) -> float:
        """Fitted ratio of the wrong pairs' inlier tail, P(score >= k + 1) / P(score >= k), over
        the recorded scores (>= 4): the decay is close to geometric (docs/landmarks.md)."""
        scores = [v for v, _o, _n in self.wrong_scores() if v >= CALIBRATION_MIN_INLIERS]
        if len(scores) < 2:
            return 0.5
        # maximum likelihood for a geometric distribution shifted to start at 4
        mean_excess = float(np.mean(scores)) - CALIBRATION_MIN_INLIERS
        return min(max(mean_excess / (1.0 + mean_excess), 0.05), 0.95)

    @property
    def recommended_threshold(self) -> int:
        """The margin: the smallest threshold at which ``FUTURE_PAIRS_FACTOR`` times as many
        wrong pairs as calibrated would, by the fitted geometric tail, verify fewer than
        ``FUTURE_FALSE_MATCHES`` times; never below the zero-false threshold + 1."""
        wrong = self.wrong_scores()
        n_tail = sum(1 for v, _o, _n in wrong if v >= CALIBRATION_MIN_INLIERS)
        r = self.tail_ratio()
        budget = FUTURE_FALSE_MATCHES / (FUTURE_PAIRS_FACTOR * max(n_tail, 1))
        extra = math.ceil(math.log(budget) / math.log(r)) if n_tail else 0
        return max(CALIBRATION_MIN_INLIERS + extra, self.zero_false_threshold + 1)

    def wrong_histogram(self) -> dict[int, int]:
        return dict(sorted(Counter(v for v, _o, _n in self.wrong_scores()).items()))


def read_truth(path: Path, images_root: Path | None = None) -> list[TruthRow]:
    """The ground-truth CSV (module docstring); raises LandmarkDbError naming the row."""
    root = images_root or path.parent
    try:
        with path.open(newline="") as fh:
            rows = list(csv.DictReader(fh))
    except OSError as exc:
        raise LandmarkDbError(f"{path}: {exc.strerror}") from exc
    out = []
    for i, row in enumerate(rows, start=2):
        q = (row.get("query") or row.get("image") or "").strip()
        if not q:
            raise LandmarkDbError(f"{path}:{i}: no query image")
        exp = (row.get("expected") or "").strip()
        out.append(
            TruthRow(
                root / q,
                None if exp.lower() in ("", "none", "-") else exp,
                (row.get("condition") or "").strip(),
            )
        )
    if not out:
        raise LandmarkDbError(f"{path}: no rows")
    return out


def evaluate_db(
    db: LandmarkDb, truth: Sequence[TruthRow], config: RecogniserConfig | None = None
) -> AcceptanceReport:
    """Every truth row through the single-image check: full run and leave-one-out."""
    cfg = config or RecogniserConfig()
    threshold = cfg.match.inliers_needed(db.extractor.kind)
    raw = replace(
        cfg,
        match=replace(cfg.match, min_inliers=CALIBRATION_MIN_INLIERS),
        max_photos=10**6,
    )
    lms = list(db.landmarks())
    names = {lm.id: lm.name for lm in lms}
    by_key = {lm.name: lm.name for lm in lms} | {str(lm.id): lm.name for lm in lms}
    rec = Recogniser(db, raw)
    outcomes = []
    for row in truth:
        try:
            image = decode_image(row.query.read_bytes())
        except (OSError, ValueError) as exc:
            raise LandmarkDbError(f"{row.query}: {exc}") from exc
        expected = None
        if row.expected is not None:
            expected = by_key.get(row.expected)
            if expected is None:
                raise LandmarkDbError(f"{row.query}: no landmark {row.expected!r} in {db.path}")
        runs = [(False, list(names))]
        if expected is not None:
            runs.append((True, [i for i, n in names.items() if n != expected]))
        for loo, ids in runs:
            res = rec.match_image(image, ids)
            scores: dict[str, int] = {}
            for e in res.evidence:
                n = names[e.landmark_id]
                scores[n] = max(scores.get(n, 0), e.inliers)
            outcomes.append(Outcome(row.query, expected, loo, row.condition, scores))
    n_photos = sum(db.photo_counts().values())
    return AcceptanceReport(len(lms), n_photos, tuple(outcomes), threshold, cfg.ambiguity_ratio)


# --- the shared A/B image pairs ---------------------------------------------------------------

SAME_PLACE = {"LePoint1": "LePoint", "LePoint2": "LePoint", "LePoint3": "LePoint"}
"""Pairs that show one place: LePoint1, 2 and 3 are one magazine (LePoint2A = LePoint3A)."""
CONDITIONS = {
    "Boston": "small_viewpoint", "BostonLib": "viewpoint", "BruggeSquare": "wide_viewpoint",
    "BruggeTower": "viewpoint", "Brussels": "wide_viewpoint", "CapitalRegion": "zoom",
    "Eiffel": "wide_viewpoint", "ExtremeZoom": "zoom", "LePoint": "wide_viewpoint",
    "WhiteBoard": "viewpoint", "adam": "viewpoint", "boat": "zoom", "city": "modality",
    "graf": "viewpoint", "box": "clutter",
}  # fmt: skip
"""What changes between a pair's A and B image (looked at, one word each)."""
KNOWN_PAIRS = {"box": "box_in_scene"}
"""Pairs whose names do not follow the A/B convention: reference stem -> query stem."""


def _images(folder: Path) -> Iterator[Path]:
    for p in sorted(folder.rglob("*")):
        if p.is_file() and p.suffix.lower() in IMAGE_EXTS:
            yield p


def _pixels(path: Path) -> str:
    pixels = np.ascontiguousarray(decode_image(path.read_bytes()))
    return hashlib.sha256(pixels.tobytes()).hexdigest()


def shared_layout(folder: Path, several: bool) -> tuple[list[tuple[Path, str]], list[TruthRow]]:
    """(photos as (path, landmark name), truth) for the A/B pairs under ``folder``.

    A place is a pair's name (``SAME_PLACE`` joins pairs of one place). Its A images are its
    photos (pixel-identical files once); with ``several`` False only the first is, and the
    others become queries. B images are queries of their place; unpaired images are
    queries that must match nothing, unless they copy a photo's pixels.
    """
    files = list(_images(folder))
    if not files:
        raise LandmarkDbError(f"{folder}: no images found")
    by_stem = {(p.parent, p.stem): p for p in files}
    refs: dict[Path, tuple[Path, str]] = {}  # query -> (reference, pair name)
    for (parent, stem), p in by_stem.items():
        if stem.endswith("A") and (parent, stem[:-1] + "B") in by_stem:
            refs[by_stem[(parent, stem[:-1] + "B")]] = (p, stem[:-1])
        if stem in KNOWN_PAIRS and (parent, KNOWN_PAIRS[stem]) in by_stem:
            refs[by_stem[(parent, KNOWN_PAIRS[stem])]] = (p, stem)
    photos: list[tuple[Path, str]] = []
    truth: list[TruthRow] = []
    place_of_pixels: dict[str, str] = {}
    for ref, pair in sorted(set(refs.values())):
        place = SAME_PLACE.get(pair, pair)
        key = _pixels(ref)
        if key in place_of_pixels:
            continue
        place_of_pixels[key] = place
        if several or all(name != place for _p, name in photos):
            photos.append((ref, place))
        else:
            truth.append(TruthRow(ref, place, "same_place"))
    for q, (_ref, pair) in sorted(refs.items()):
        place = SAME_PLACE.get(pair, pair)
        truth.append(TruthRow(q, place, CONDITIONS.get(place, "")))
    used = set(refs) | {r for r, _ in refs.values()}
    for p in files:
        if p not in used:
            copy_of = place_of_pixels.get(_pixels(p))
            truth.append(TruthRow(p, copy_of, "copy" if copy_of else "negative"))
    return photos, truth


def evaluate(
    folder: Path,
    config: RecogniserConfig | None = None,
    extractor: ExtractorConfig | None = None,
    several: bool = False,
    workdir: Path | None = None,
) -> AcceptanceReport:
    """``shared_layout`` into a temporary database, then ``evaluate_db``."""
    photos, truth = shared_layout(folder, several)
    with tempfile.TemporaryDirectory(dir=workdir) as tmp:
        db = create_db(Path(tmp) / "acceptance.sqlite", Origin(0.0, 0.0), extractor)
        try:
            ids: dict[str, int] = {}
            for path, name in photos:
                if name in ids:
                    db.add_photo(ids[name], path.read_bytes(), source=path.name)
                else:
                    ids[name] = db.add(
                        name, path.read_bytes(), x_m=1000.0 * len(ids), y_m=0.0, source=path.name
                    )
            return evaluate_db(db, truth, config)
        finally:
            db.close()


__all__ = ["AcceptanceReport", "MatchConfig", "TruthRow", "evaluate", "evaluate_db", "read_truth"]
