"""Camera landmark recognition: gate, match, verify, confirm (SPEC sections 2 and 6).

``Recogniser.process(frame, state)`` runs one camera frame through:

1. **gate** (``landmark_db.gate``): the landmarks within the sighting range of the
   2-sigma ellipse, nearest first, at most ``max_candidates``; none -> ``no_candidate``
   (and no image work at all);
2. **match** (``landmark_db.matcher``): features of the frame (the database's extractor),
   then per candidate photo k-NN matching with the ratio test (``few_matches``) and a
   MAGSAC++ homography with a calibrated minimum inlier count (``failed_geometry``). A
   landmark scores its best photo: photos of one place never compete. At most
   ``max_photos`` photos per frame, round robin over the candidates (the time budget). Two
   verified *landmarks* whose inlier counts are within ``ambiguity_ratio`` of each other
   -> ``ambiguous``;
3. **confirm**: the same landmark verified in ``confirm_frames`` consecutive frames, each
   within ``confirm_window_s`` of the previous (``not_consistent`` until then); a landmark
   already fixed less than ``refix_interval_s`` ago -> ``repeat`` (one fix per pass, so the
   filter does not count the same sighting many times).

**Lost** (``state.lost``): no gate; the whole database is searched (``landmark_db.search``:
a global shortlist, then the same check at a Bonferroni level), and one frame that verifies
a place ``search.SCENE_DECADES`` past that level gives a fix with ``relocalised=True`` (frames
of one scene are not independent, so a second agreeing frame earns no credit).
``locate(image)`` is the same search for one image, without temporal state
(``landmark-db locate``).

A confirmed match becomes a ``LandmarkFix`` at the landmark's surveyed position with
``sigma_m = sqrt((sighting_range_m / 2)^2 + position_sigma_m^2)``: the car is somewhere
within the sighting range, in an unknown direction (a uniform disc of radius r has a
per-axis standard deviation of r / 2), and the landmark's own survey error adds to that.
With the default 20 m range and an exactly known landmark, sigma = 10 m.

Matching is CPU-heavy; run it off the event loop with ``recognise_async`` (a thread of the
default executor: the OpenCV calls release the GIL) or in a ``RecogniserWorker`` process
(``landmark_db.worker``).
"""

from __future__ import annotations

import asyncio
import math
import threading
import time
from collections import Counter, OrderedDict
from collections.abc import Mapping, Sequence
from concurrent.futures import Executor
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from guidance.core.messages import CameraFrame, EstimateState, LandmarkFix, reset_sigma_m
from guidance.core.model import CHI2_2D_2SIGMA
from landmark_db.features import ExtractorConfig, Features, extract
from landmark_db.gate import valid_covariance
from landmark_db.limits import frame_problem
from landmark_db.matcher import (
    FAILED_GEOMETRY,
    FEW_MATCHES,
    MatchConfig,
    MatchEvidence,
    PairMatcher,
    PhotoIndex,
)
from landmark_db.search import SearchConfig, WholeDbSearch
from landmark_db.store import Candidate, LandmarkDb, open_db, query_gate

FRAME_FEATURES = 600
"""Features per camera frame (described at ``features.FRAME_MAX_SIDE_PX``)."""

NO_CANDIDATE = "no_candidate"
AMBIGUOUS = "ambiguous"
NOT_CONSISTENT = "not_consistent"
REPEAT = "repeat"
BAD_INPUT = "bad_input"
TOO_SMALL = "too_small"
REASONS = (
    NO_CANDIDATE,
    TOO_SMALL,
    FEW_MATCHES,
    FAILED_GEOMETRY,
    AMBIGUOUS,
    NOT_CONSISTENT,
    REPEAT,
    BAD_INPUT,
)
"""Every rejection carries one of these (docs/landmarks.md explains each)."""


@dataclass(frozen=True, slots=True)
class RecogniserConfig:
    """Settings of the recogniser; the defaults are the documented operating point."""

    sighting_range_m: float = 20.0
    """The camera recognises a landmark photo from at most this far (hal_sim uses the same)."""
    gate_chi2: float = CHI2_2D_2SIGMA
    """Gate ellipse d^2 <= this: 4 is the 2-sigma ellipse, P = 0.865 for 2 dof."""
    max_candidates: int = 5
    """At most this many gated landmarks, nearest to the ellipse first, are compared."""
    confirm_frames: int = 2
    """Consecutive frames that must verify the same landmark before a fix."""
    confirm_window_s: float = 5.0
    """Longest gap between two of those frames."""
    refix_interval_s: float = 30.0
    """No second fix from the same landmark within this time."""
    ambiguity_ratio: float = 1.5
    """The best verified candidate needs this many times the runner-up's inliers."""
    frame_features: int = FRAME_FEATURES
    frame_max_side_px: int | None = None
    """Frames are shrunk to this longer side (None: ``features.FRAME_MAX_SIDE_PX`` of the
    database's extractor)."""
    frame_orb: ExtractorConfig | None = None
    """Full override of the frame extractor (its kind must be the database's)."""
    max_photos: int = 6
    """Photos compared per frame at most, nearest candidates first: the time budget."""
    match: MatchConfig = field(default_factory=MatchConfig)
    feature_cache: int = 512
    """Landmarks whose photo features are kept in memory (LRU)."""
    search: SearchConfig = field(default_factory=SearchConfig)
    """The whole-database search of a lost car and of ``locate``."""

    def __post_init__(self) -> None:
        if not (math.isfinite(self.sighting_range_m) and self.sighting_range_m >= 0.0):
            raise ValueError("sighting_range_m must be a non-negative number")
        if not self.gate_chi2 > 0.0:
            raise ValueError("gate_chi2 must be positive")
        if min(self.max_candidates, self.confirm_frames, self.feature_cache, self.max_photos) < 1:
            raise ValueError(
                "max_candidates, confirm_frames, feature_cache and max_photos must be >= 1"
            )


@dataclass(frozen=True, slots=True)
class RecognitionResult:
    """What one frame gave: a fix, or a rejection ``reason`` with the evidence behind it."""

    t_s: float
    fix: LandmarkFix | None
    reason: str | None
    landmark_id: int | None
    """The best verified landmark, also when it is not yet confirmed."""
    candidates: tuple[Candidate, ...] = ()
    evidence: tuple[MatchEvidence, ...] = ()
    frame_features: int = 0
    elapsed_s: float = 0.0
    """Processing time (diagnostics only)."""
    shortlist: tuple[tuple[int, float], ...] = ()
    """A whole-database search's shortlist: (landmark id, global cosine), best first."""
    level: float = math.nan
    """A search's log10 NFA level (the rule's, lowered by the Bonferroni term); NaN when
    the frame was gated."""

    @property
    def verified(self) -> bool:
        return self.landmark_id is not None


def fix_sigma_m(sighting_range_m: float, position_sigma_m: float) -> float:
    """1-sigma of a landmark fix: sighting disc (r / 2 per axis) and the survey error."""
    return math.hypot(0.5 * sighting_range_m, position_sigma_m)


def state_xy(state: EstimateState) -> tuple[tuple[float, float], tuple[tuple[float, float], ...]]:
    """Mean and x-y covariance of an ``EstimateState``."""
    c = state.covariance
    return (state.x_m, state.y_m), ((c[0][0], c[0][1]), (c[1][0], c[1][1]))


class Recogniser:
    """Recognises database landmarks in camera frames: the app's ``Recogniser`` port
    (``guidance.app.ports``: ``process(frame, state)`` and ``stats()``; its ``NullRecogniser``
    is the default when no database is configured).

    Construct from an open database or with ``Recogniser.from_path(path)``, which opens the
    file read-only and validates it. Calls are serialised by a lock, so it may be used from
    an executor thread; the temporal-consistency state lives here.
    """

    def __init__(self, db: LandmarkDb, config: RecogniserConfig | None = None) -> None:
        self.db = db
        self.config = config or RecogniserConfig()
        self._matcher = PairMatcher(self.config.match)
        self.frame_extractor = self.config.frame_orb or db.extractor.for_frames(
            self.config.frame_features, self.config.frame_max_side_px
        )
        if self.frame_extractor.kind != db.extractor.kind:
            raise ValueError(
                f"frame extractor {self.frame_extractor.kind} cannot match photos described"
                f" by {db.extractor.kind}"
            )
        self._detector = self.frame_extractor.create()
        self._cache: OrderedDict[int, list[PhotoIndex]] = OrderedDict()
        self._sigma_cache: dict[int, tuple[float, float, float]] = {}
        self._lock = threading.Lock()
        self._counts: Counter[str] = Counter()
        self._streak_id: int | None = None
        self._streak_n = 0
        self._streak_t = -math.inf
        self._last_fix_t: dict[int, float] = {}
        self._search = WholeDbSearch(
            db._conn, db._lock, db.extractor, self.config.match, self.config.search
        )

    @classmethod
    def from_path(cls, path: str | Path, config: RecogniserConfig | None = None) -> Recogniser:
        """Open ``path`` read-only (raises ``LandmarkDbError`` on a bad file) and wrap it."""
        return cls(open_db(path, readonly=True), config)

    def close(self) -> None:
        self.db.close()

    # --- counters ----------------------------------------------------------------------------

    def stats(self) -> Mapping[str, int]:
        """Frames, fixes, verified frames, candidates compared, and rejections by reason."""
        with self._lock:
            keys = ("frames", "fixes", "relocalisations", "searched", "verified", "compared",
                    *REASONS)  # fmt: skip
            return {k: self._counts[k] for k in keys}

    # --- main entry points -------------------------------------------------------------------

    def process(self, frame: CameraFrame, state: EstimateState) -> RecognitionResult:
        """One frame against the landmarks gated by the estimator's published state, or,
        when ``state.lost``, against the whole database (``locate``'s search)."""
        mean, cov = state_xy(state)
        return self.process_xy(frame, mean, cov, lost=bool(state.lost))

    def process_xy(
        self,
        frame: CameraFrame,
        mean_xy: Sequence[float],
        cov_xy: Sequence[Sequence[float]],
        lost: bool = False,
    ) -> RecognitionResult:
        """As ``process``, from a mean and a 2x2 covariance (ignored when ``lost``)."""
        with self._lock:
            t0 = time.perf_counter()
            result = self._process_lost(frame) if lost else self._process(frame, mean_xy, cov_xy)
            self._counts["frames"] += 1
            self._counts["searched"] += lost
            if result.fix is not None:
                self._counts["fixes"] += 1
                self._counts["relocalisations"] += result.fix.relocalised
            else:
                assert result.reason is not None
                self._counts[result.reason] += 1
            if result.verified:
                self._counts["verified"] += 1
            self._counts["compared"] += len(result.evidence)
            return _with_elapsed(result, time.perf_counter() - t0)

    def reset(self) -> None:
        """Forget the temporal state (after a relocalisation or a new drive)."""
        with self._lock:
            self._streak_id, self._streak_n, self._streak_t = None, 0, -math.inf
            self._last_fix_t.clear()

    # --- internals ---------------------------------------------------------------------------

    def _landmark_photos(self, lid: int) -> list[PhotoIndex]:
        f = self._cache.get(lid)
        if f is not None:
            self._cache.move_to_end(lid)
            return f
        m = self.config.match
        f = [
            PhotoIndex(pid, feats, m.flann_checks, m.flann_trees)
            for pid, feats in self.db.photo_features(lid)
        ]
        self._cache[lid] = f
        if len(self._cache) > self.config.feature_cache:
            self._cache.popitem(last=False)
        return f

    def match_image(
        self, image: np.ndarray, landmark_ids: Sequence[int] | None = None
    ) -> RecognitionResult:
        """Single-image check, no gate and no temporal state: ``image`` against every photo
        of the given landmarks (all landmarks when None; no ``max_photos`` budget). ``fix``
        stays None; ``landmark_id`` is the verified match, if any. For the ``match`` command
        and the acceptance figures."""
        ids = [lm.id for lm in self.db.landmarks()] if landmark_ids is None else list(landmark_ids)
        with self._lock:
            t0 = time.perf_counter()
            if not isinstance(image, np.ndarray) or image.size == 0:
                return RecognitionResult(0.0, None, BAD_INPUT, None)
            if not ids:
                return RecognitionResult(0.0, None, NO_CANDIDATE, None)
            reason, lid, ev, n = self._match(image, ids, None)
            return RecognitionResult(0.0, None, reason, lid, (), ev, n, time.perf_counter() - t0)

    def _match(
        self, image: np.ndarray, ids: Sequence[int], max_photos: int | None
    ) -> tuple[str | None, int | None, tuple[MatchEvidence, ...], int]:
        """(reason, verified id, evidence, frame feature count) for one image against ``ids``
        (their photos in order, at most ``max_photos`` of them; None: all). A landmark's
        evidence is its best photo's."""
        feats = self._frame_features(image)
        if isinstance(feats, str):
            return feats, None, (), 0
        return self._match_features(feats, ids, max_photos, self._matcher)

    def _frame_features(self, image: np.ndarray) -> Features | str:
        """The frame's features, or the reason it has none (``too_small``, ``bad_input``)."""
        if image.dtype == np.uint8 and frame_problem(image.shape[1], image.shape[0]) is not None:
            return TOO_SMALL
        try:
            return extract(image, self.frame_extractor, self._detector)
        except ValueError:
            return BAD_INPUT

    def _match_features(
        self, feats: Features, ids: Sequence[int], max_photos: int | None, matcher: PairMatcher
    ) -> tuple[str | None, int | None, tuple[MatchEvidence, ...], int]:
        desc = feats.for_matching()
        photos = {lid: self._landmark_photos(lid) for lid in ids}
        # Round robin: every candidate's first photo, then every second photo... so a
        # budget of ``max_photos`` never starves the farther candidates.
        order = [
            (lid, ph)
            for rank in range(max((len(p) for p in photos.values()), default=0))
            for lid in ids
            if rank < len(photos[lid])
            for ph in (photos[lid][rank],)
        ]
        if max_photos is not None:
            order = order[:max_photos]
        per_lm: dict[int, MatchEvidence] = {}
        for lid, photo in order:
            # every photo in the budget is scored (no early stop on the first verified one):
            # the ambiguity rule compares each landmark's best photo
            e = matcher.verify(lid, feats, desc, photo)
            b = per_lm.get(lid)
            if b is None or _strength(e) > _strength(b):
                per_lm[lid] = e
        evidence = [per_lm[lid] for lid in ids if lid in per_lm]
        ev = tuple(evidence)
        verified = sorted((e for e in ev if e.verified), key=lambda e: -e.inliers)
        if not verified:
            reason = (
                FAILED_GEOMETRY if any(e.reason == FAILED_GEOMETRY for e in ev) else FEW_MATCHES
            )
            return reason, None, ev, len(feats)
        best = verified[0]
        if len(verified) > 1 and best.inliers < self.config.ambiguity_ratio * verified[1].inliers:
            return AMBIGUOUS, None, ev, len(feats)
        return None, best.landmark_id, ev, len(feats)

    def _break_streak(self) -> None:
        self._streak_id, self._streak_n = None, 0

    def _process(
        self, frame: CameraFrame, mean_xy: Sequence[float], cov_xy: Sequence[Sequence[float]]
    ) -> RecognitionResult:
        cfg = self.config
        t = float(frame.t_s)
        image = frame.image
        if (
            not isinstance(image, np.ndarray)
            or image.size == 0
            or not math.isfinite(t)
            or not all(math.isfinite(float(v)) for v in mean_xy)
            or not valid_covariance(cov_xy)
        ):
            self._break_streak()
            return RecognitionResult(t, None, BAD_INPUT, None)
        cands = query_gate(
            self.db, mean_xy, cov_xy, cfg.sighting_range_m, cfg.gate_chi2, cfg.max_candidates
        )
        if not cands:
            self._break_streak()
            return RecognitionResult(t, None, NO_CANDIDATE, None)
        ids = [c.id for c in cands]
        reason, lid, ev, n_feats = self._match(image, ids, cfg.max_photos)
        cands_t = tuple(cands)

        def out(
            reason: str | None, lid: int | None, fix: LandmarkFix | None = None
        ) -> RecognitionResult:
            return RecognitionResult(t, fix, reason, lid, cands_t, ev, n_feats)

        if lid is None:
            self._break_streak()
            return out(reason, None)
        fix, reason = self._confirm(lid, t, strong=False, relocalised=False)
        return out(reason, None if reason == NO_CANDIDATE else lid, fix)

    def locate(self, image: np.ndarray) -> RecognitionResult:
        """The whole-database search for one image, without gate or temporal state
        (``landmark_db.search``): ``landmark_id`` is the place verified at the search's
        level, if any; ``fix`` stays None."""
        with self._lock:
            t0 = time.perf_counter()
            if not isinstance(image, np.ndarray) or image.size == 0:
                return RecognitionResult(0.0, None, BAD_INPUT, None)
            return _with_elapsed(self._locate(image, 0.0), time.perf_counter() - t0)

    def _locate(self, image: np.ndarray, t: float) -> RecognitionResult:
        feats = self._frame_features(image)
        if isinstance(feats, str):
            return RecognitionResult(t, None, feats, None)
        short = tuple(self._search.shortlist(feats))
        level = self._search.level
        if not short:
            return RecognitionResult(t, None, NO_CANDIDATE, None, level=level)
        assert self._search.matcher is not None
        ids = [lid for lid, _sim in short]
        reason, lid, ev, n = self._match_features(
            feats, ids, self.config.search.max_photos, self._search.matcher
        )
        return RecognitionResult(t, None, reason, lid, (), ev, n, 0.0, short, level)

    def _process_lost(self, frame: CameraFrame) -> RecognitionResult:
        """A lost car's frame: the whole-database search; a place verified past the scene
        level (``WholeDbSearch.scene_level``) gives a ``relocalised`` fix."""
        t = float(frame.t_s)
        image = frame.image
        if not isinstance(image, np.ndarray) or image.size == 0 or not math.isfinite(t):
            self._break_streak()
            return RecognitionResult(t, None, BAD_INPUT, None)
        res = self._locate(image, t)
        lid = res.landmark_id
        if lid is None:
            self._break_streak()
            return res
        best = next(e for e in res.evidence if e.landmark_id == lid)
        strong = best.log_nfa <= self._search.scene_level()
        if not strong and not self.config.search.pair_at_level:
            # verified at the search level, not past the scene level: no credit (a second
            # view of the same scene is not independent evidence; landmark_db.search)
            self._break_streak()
            return replace(res, reason=NOT_CONSISTENT)
        fix, reason = self._confirm(lid, t, strong, relocalised=True)
        return replace(res, fix=fix, reason=reason)

    def _confirm(
        self, lid: int, t: float, strong: bool, relocalised: bool
    ) -> tuple[LandmarkFix | None, str | None]:
        """The temporal rule on a verified landmark: (fix, None) or (None, reason)."""
        cfg = self.config
        if lid == self._streak_id and t - self._streak_t <= cfg.confirm_window_s:
            self._streak_n += 1
        else:
            self._streak_id, self._streak_n = lid, 1
        self._streak_t = t
        if self._streak_n < cfg.confirm_frames and not strong:
            return None, NOT_CONSISTENT
        last = self._last_fix_t.get(lid)
        if last is not None and t - last < cfg.refix_interval_s:
            return None, REPEAT
        landmark = self.db.get(lid)
        if landmark is None:
            self._break_streak()
            return None, NO_CANDIDATE
        self._last_fix_t[lid] = t
        sigma = (reset_sigma_m if relocalised else fix_sigma_m)(
            cfg.sighting_range_m, landmark.position_sigma_m
        )  # a reset holds every point the place can be seen from
        return LandmarkFix(t, lid, landmark.x_m, landmark.y_m, sigma, relocalised), None


def _strength(e: MatchEvidence) -> tuple[bool, float, int, int]:
    """Which of a landmark's photos is its evidence: verified first, then the most
    significant (smallest NFA), then the most inliers."""
    return e.verified, -e.log_nfa, e.inliers, e.good_matches


def _with_elapsed(r: RecognitionResult, elapsed_s: float) -> RecognitionResult:
    return replace(r, elapsed_s=elapsed_s)


async def recognise_async(
    recogniser: Recogniser,
    frame: CameraFrame,
    state: EstimateState,
    executor: Executor | None = None,
) -> RecognitionResult:
    """``recogniser.process`` in ``executor`` (default: the loop's thread pool).

    The event loop keeps running meanwhile: SIFT/ORB, k-NN matching and MAGSAC++ are OpenCV
    calls that release the GIL (tests/landmark_db/test_recognise_async.py measures it).
    """
    loop = asyncio.get_running_loop()
    return await loop.run_in_executor(executor, recogniser.process, frame, state)
