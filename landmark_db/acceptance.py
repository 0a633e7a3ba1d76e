"""Acceptance: recall and precision of recognition on real photos, with negatives.

Input: a landmark database (``landmark-db init`` / ``import``, one or several photos per
landmark) and a ground-truth CSV with a ``query`` column (an image path, relative to the
CSV's folder or ``--images``), an ``expected`` column (the landmark's name or id; several
acceptable ones separated by ``|`` for a photo that shows two; empty or ``none`` for a
*negative*: a photo of a place that is not in the database) and an optional ``condition``
column (``viewpoint``, ``zoom``, ``night``...).

Runs, with the single-image check (no gate, no temporal confirmation):

* **full**: every query against every landmark; a match to a landmark it does not show is
  false, any match of a negative is false;
* **leave-one-out**: every positive query against every landmark *except* the ones it
  shows: any match is false (the look-alike test: the right answer is missing).

Every landmark's evidence is recorded (its best photo's inliers and log10 NFA), so one run
gives the decision at every level of the rule (``decide``, the recogniser's rule). The
report: precision and recall at the shipped rule, recall by condition, the most
significant wrong pairs (every landmark a query does not show, both runs) and the margin
of the rule over them. The rule itself is not fitted here: ``matcher.MAX_LOG10_NFA`` comes
from a null model (docs/landmarks.md, "The decision rule").

``shared_layout`` turns ../shared/data/images (A/B pairs) into such a database and CSV.
"""

from __future__ import annotations

import hashlib
import math
import tempfile
from collections import defaultdict
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from guidance.core.geo import Origin
from landmark_db.features import ExtractorConfig, decode_image
from landmark_db.inputs import read_csv_rows, read_photo
from landmark_db.matcher import MatchConfig
from landmark_db.recognise import Recogniser, RecogniserConfig
from landmark_db.store import LandmarkDb, LandmarkDbError, create_db

IMAGE_EXTS = (".png", ".jpg", ".jpeg")


@dataclass(frozen=True, slots=True)
class TruthRow:
    query: Path
    expected: str | None
    """Landmark name (or id) it shows; None for a negative (must match nothing)."""
    condition: str = ""
    also: tuple[str, ...] = ()
    """Other landmarks the photo shows (a match to one of them is right too)."""


@dataclass(frozen=True, slots=True)
class Outcome:
    query: Path
    expected: str | None
    leave_one_out: bool
    condition: str
    scores: dict[str, int]
    """Landmark name -> inliers of its best photo (0: no plausible homography)."""
    nfa: dict[str, float] = field(default_factory=dict)
    """Landmark name -> log10 NFA of its best photo (inf: no plausible homography)."""
    accept: frozenset[str] = frozenset()
    """Every landmark the query shows (``expected`` and the others)."""

    def right(self, name: str) -> bool:
        return not self.leave_one_out and (name == self.expected or name in self.accept)


def decide(
    scores: dict[str, int], nfa: dict[str, float], match: MatchConfig, kind: str, ratio: float
) -> str | None:
    """The recogniser's decision from per-landmark evidence: the best verified landmark
    unless a second verified one comes within ``ratio`` of its inliers (``Recogniser._match``)."""
    ok = sorted(
        ((v, k) for k, v in scores.items() if match.accepts(kind, v, nfa.get(k, math.inf))),
        reverse=True,
    )
    if not ok or (len(ok) > 1 and ok[0][0] < ratio * ok[1][0]):
        return None
    return ok[0][1]


@dataclass(frozen=True, slots=True)
class AcceptanceReport:
    landmarks: int
    photos: int
    outcomes: tuple[Outcome, ...]
    match: MatchConfig
    """The rule the figures below are at (the shipped one unless overridden)."""
    kind: str
    ambiguity_ratio: float

    def matched(self, o: Outcome, level: float | None = None) -> str | None:
        m = self.match if level is None else replace(self.match, max_log10_nfa=level)
        return decide(o.scores, o.nfa, m, self.kind, self.ambiguity_ratio)

    @property
    def level(self) -> float:
        return self.match.nfa_needed(self.kind)

    @property
    def positives(self) -> int:
        return sum(1 for o in self.outcomes if not o.leave_one_out and o.expected is not None)

    def true_matches(self, level: float | None = None) -> int:
        out = 0
        for o in self.outcomes:
            if o.expected is not None and not o.leave_one_out:
                m = self.matched(o, level)
                out += m is not None and o.right(m)
        return out

    def false_matches(self, level: float | None = None) -> list[tuple[Outcome, str]]:
        out = []
        for o in self.outcomes:
            m = self.matched(o, level)
            if m is not None and not o.right(m):
                out.append((o, m))
        return out

    def recall(self, level: float | None = None) -> float:
        return self.true_matches(level) / self.positives if self.positives else 0.0

    def precision(self, level: float | None = None) -> float:
        t, f = self.true_matches(level), len(self.false_matches(level))
        return t / (t + f) if t + f else 1.0

    def recall_by_condition(self, level: float | None = None) -> dict[str, tuple[int, int]]:
        """condition -> (correct, positives) in the full run."""
        out: dict[str, list[int]] = defaultdict(lambda: [0, 0])
        for o in self.outcomes:
            if o.expected is None or o.leave_one_out:
                continue
            m = self.matched(o, level)
            out[o.condition or "-"][1] += 1
            out[o.condition or "-"][0] += m is not None and o.right(m)
        return {k: (v[0], v[1]) for k, v in sorted(out.items())}

    def wrong_scores(self) -> list[tuple[float, int, Outcome, str]]:
        """(log10 NFA, inliers, outcome, landmark) of every wrong pair, most significant
        first."""
        out = [
            (o.nfa.get(name, math.inf), v, o, name)
            for o in self.outcomes
            for name, v in o.scores.items()
            if not o.right(name)
        ]
        return sorted(out, key=lambda t: (t[0], -t[1]))

    @property
    def wrong_pairs(self) -> int:
        return len(self.wrong_scores())

    @property
    def max_wrong(self) -> int:
        """The most inliers any wrong pair reached."""
        return max((v for _n, v, _o, _name in self.wrong_scores()), default=0)

    @property
    def most_significant_wrong(self) -> float:
        """The smallest log10 NFA of a wrong pair (inf when none had a plausible model)."""
        w = self.wrong_scores()
        return w[0][0] if w else math.inf

    def zero_false_level(self) -> float:
        """The loosest NFA level (a tenth of a decade below the most significant wrong
        pair) at which no wrong pair verifies: for the margin, never for choosing."""
        w = self.most_significant_wrong
        return math.floor(w * 10.0 - 1.0) / 10.0 if math.isfinite(w) else math.inf


def read_truth(path: Path, images_root: Path | None = None) -> list[TruthRow]:
    """The ground-truth CSV (module docstring); raises LandmarkDbError naming the row."""
    root = images_root or path.parent
    rows = read_csv_rows(path)
    out = []
    for i, row in enumerate(rows, start=2):
        q = (row.get("query") or row.get("image") or "").strip()
        if not q:
            raise LandmarkDbError(f"{path}:{i}: no query image")
        names = [n.strip() for n in (row.get("expected") or "").split("|")]
        names = [n for n in names if n and n.lower() not in ("none", "-")]
        out.append(
            TruthRow(
                root / q,
                names[0] if names else None,
                (row.get("condition") or "").strip(),
                tuple(names[1:]),
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
    raw = replace(cfg, max_photos=10**6)
    lms = list(db.landmarks())
    names = {lm.id: lm.name for lm in lms}
    by_key = {lm.name: lm.name for lm in lms} | {str(lm.id): lm.name for lm in lms}
    rec = Recogniser(db, raw)
    outcomes = []
    for row in truth:
        try:
            image = decode_image(read_photo(row.query))
        except (OSError, ValueError) as exc:
            raise LandmarkDbError(f"{row.query}: {exc}") from exc
        shown: list[str] = []
        for key in ([row.expected] if row.expected is not None else []) + list(row.also):
            name = by_key.get(key)
            if name is None:
                raise LandmarkDbError(f"{row.query}: no landmark {key!r} in {db.path}")
            shown.append(name)
        expected = shown[0] if shown else None
        runs = [(False, list(names))]
        if expected is not None:
            runs.append((True, [i for i, n in names.items() if n not in shown]))
        for loo, ids in runs:
            res = rec.match_image(image, ids)
            scores: dict[str, int] = {}
            nfa: dict[str, float] = {}
            for e in res.evidence:
                n = names[e.landmark_id]
                scores[n] = max(scores.get(n, 0), e.inliers)
                nfa[n] = min(nfa.get(n, math.inf), e.log_nfa)
            outcomes.append(
                Outcome(row.query, expected, loo, row.condition, scores, nfa, frozenset(shown))
            )
    n_photos = sum(db.photo_counts().values())
    return AcceptanceReport(
        len(lms), n_photos, tuple(outcomes), cfg.match, db.extractor.kind, cfg.ambiguity_ratio
    )


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
    pixels = np.ascontiguousarray(decode_image(read_photo(path)))
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
                    db.add_photo(ids[name], read_photo(path), source=path.name)
                else:
                    ids[name] = db.add(
                        name,
                        read_photo(path),
                        x_m=1000.0 * len(ids),
                        y_m=0.0,
                        source=path.name,
                    )
            return evaluate_db(db, truth, config)
        finally:
            db.close()


__all__ = ["AcceptanceReport", "MatchConfig", "TruthRow", "evaluate", "evaluate_db", "read_truth"]
