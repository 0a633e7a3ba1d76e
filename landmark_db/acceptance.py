"""Real-image acceptance: precision and recall of the matcher on public image pairs.

The folders hold pairs ``<name>A.<ext>`` / ``<name>B.<ext>`` (homogr_magsac) and the OpenCV
``box.png`` / ``box_in_scene.png`` pair. Every pair's A image becomes a landmark; every B
image is a query that should match its own A. Every other landmark is a distractor for it.
Images that are pixel-identical (LePoint2A = LePoint3A; box_rgb_zcmgyu = box) are one
landmark; an unpaired image is a query that must match nothing unless it duplicates a
landmark's photo.

Two runs:

* **full**: each query against every landmark; a match to the wrong landmark is false;
* **leave-one-out**: each B query against every landmark *except* its own: any match is
  false (this is the look-alike test on real photos).

Recall = correct matches / paired queries (full run); precision = correct / all matches
(both runs together).
"""

from __future__ import annotations

import hashlib
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from landmark_db.features import OrbConfig
from landmark_db.geo import Origin
from landmark_db.recognise import Recogniser, RecogniserConfig, RecognitionResult
from landmark_db.store import LandmarkDbError, create_db

IMAGE_EXTS = (".png", ".jpg", ".jpeg")
KNOWN_PAIRS = {"box": "box_in_scene"}
"""Pairs whose names do not follow the A/B convention: reference stem -> query stem."""


@dataclass(frozen=True, slots=True)
class Query:
    path: Path
    expected: str | None
    """Name of the landmark it should match (None: must match nothing)."""


@dataclass(frozen=True, slots=True)
class Outcome:
    query: Path
    expected: str | None
    matched: str | None
    leave_one_out: bool
    result: RecognitionResult

    @property
    def correct(self) -> bool:
        return self.matched is not None and self.matched == self.expected

    @property
    def false_match(self) -> bool:
        return self.matched is not None and self.matched != self.expected


@dataclass(frozen=True, slots=True)
class AcceptanceReport:
    landmarks: int
    outcomes: tuple[Outcome, ...]

    @property
    def positives(self) -> int:
        return sum(1 for o in self.outcomes if not o.leave_one_out and o.expected is not None)

    @property
    def true_matches(self) -> int:
        return sum(1 for o in self.outcomes if o.correct)

    @property
    def false_matches(self) -> int:
        return sum(1 for o in self.outcomes if o.false_match)

    @property
    def recall(self) -> float:
        return self.true_matches / self.positives if self.positives else 0.0

    @property
    def precision(self) -> float:
        n = self.true_matches + self.false_matches
        return self.true_matches / n if n else 1.0


def _pixel_key(path: Path) -> str:
    image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if image is None:
        raise LandmarkDbError(f"{path}: cannot read image")
    return hashlib.sha256(np.ascontiguousarray(image).tobytes()).hexdigest()


def _images(folder: Path) -> Iterator[Path]:
    for p in sorted(folder.rglob("*")):
        if p.is_file() and p.suffix.lower() in IMAGE_EXTS:
            yield p


def discover(folder: Path) -> tuple[dict[str, Path], list[Query]]:
    """(landmark name -> reference image, queries) for the image folders under ``folder``."""
    files = list(_images(folder))
    if not files:
        raise LandmarkDbError(f"{folder}: no images found")
    by_stem = {(p.parent, p.stem): p for p in files}
    refs: dict[Path, Path] = {}  # query -> reference
    for (parent, stem), p in by_stem.items():
        if stem.endswith("A") and (parent, stem[:-1] + "B") in by_stem:
            refs[by_stem[(parent, stem[:-1] + "B")]] = p
        if stem in KNOWN_PAIRS and (parent, KNOWN_PAIRS[stem]) in by_stem:
            refs[by_stem[(parent, KNOWN_PAIRS[stem])]] = p
    landmarks: dict[str, Path] = {}
    name_of_pixels: dict[str, str] = {}
    name_of_ref: dict[Path, str] = {}
    for ref in sorted(set(refs.values())):
        key = _pixel_key(ref)
        name = name_of_pixels.setdefault(key, ref.stem)
        if name == ref.stem:
            landmarks[name] = ref
        name_of_ref[ref] = name
    queries = [Query(q, name_of_ref[r]) for q, r in sorted(refs.items())]
    used = set(refs) | set(refs.values())
    for p in files:
        if p not in used:
            queries.append(Query(p, name_of_pixels.get(_pixel_key(p))))
    return landmarks, queries


def evaluate(
    folder: Path,
    config: RecogniserConfig | None = None,
    photo_orb: OrbConfig | None = None,
    workdir: Path | None = None,
) -> AcceptanceReport:
    """Build a database of the reference images and run both query sets (module docstring).

    ``photo_orb`` sets the ORB parameters of the database photos (default: ``OrbConfig()``).
    """
    landmarks, queries = discover(folder)
    with tempfile.TemporaryDirectory(dir=workdir) as tmp:
        db = create_db(Path(tmp) / "acceptance.sqlite", Origin(0.0, 0.0), photo_orb)
        ids: dict[str, int] = {}
        for i, (name, path) in enumerate(sorted(landmarks.items())):
            ids[name] = db.add(name, path.read_bytes(), x_m=1000.0 * i, y_m=0.0)
        names = {v: k for k, v in ids.items()}
        rec = Recogniser(db, config)
        outcomes: list[Outcome] = []
        try:
            for q in queries:
                image = cv2.imread(str(q.path), cv2.IMREAD_COLOR)
                if image is None:
                    raise LandmarkDbError(f"{q.path}: cannot read image")
                res = rec.match_image(image)
                matched = None if res.landmark_id is None else names[res.landmark_id]
                outcomes.append(Outcome(q.path, q.expected, matched, False, res))
                if q.expected is not None:
                    others = [i for n, i in ids.items() if n != q.expected]
                    res = rec.match_image(image, others)
                    matched = None if res.landmark_id is None else names[res.landmark_id]
                    outcomes.append(Outcome(q.path, None, matched, True, res))
        finally:
            rec.close()
    return AcceptanceReport(len(landmarks), tuple(outcomes))
