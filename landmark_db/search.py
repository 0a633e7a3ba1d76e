"""The whole-database search a lost car makes (issue 36): no gate, every place a candidate.

1. The frame's features (the recogniser's) are encoded as a VLAD vector with the file's
   vocabulary (``landmark_db.global_index``), and the ``shortlist`` places whose best photo
   is most similar (cosine) are kept.
2. Their photos (every shortlisted place's first photo, then the second photos..., at most
   ``max_photos``) go through the same pairwise check as a gated frame, the same NFA rule,
   at a level lowered by ``log10(places in the database)``: the false-alarm level per place
   compared, multiplied by the number of places that *could* have been shortlisted
   (Bonferroni over the database, not over the shortlist, because the shortlist is chosen
   by looking at the frame). With 300 places that is 2.5 decades, with 10,000 four.
3. A lost car acts on **one frame whose log10 NFA is ``SCENE_DECADES`` below that level**
   (``WholeDbSearch.scene_level``); further frames of the same scene earn no credit.

**Why one frame, and why 17 decades (RootSIFT).** Frames of one scene are not independent
evidence: a look-alike that verifies a wrong place in one frame does so again in the next
view of it far more often than chance (measured: of 6 such frames with a next frame, the next
verified the same wrong place once, against a per-frame rate of 0.028 for any wrong place), so
the second of two agreeing frames does not divide the false rate by the per-frame rate, and
the rule gives it no credit (consecutive frames counted as fully dependent). What is left is
how often the best wrong place of *one* frame reaches a level: the search's wrong pairs are
the shortlist's, the places most similar to the frame, whose tail is heavier than the random
wrong pairs the level was calibrated on. Measured on look-alike passes (``LOOKALIKE_TAIL``:
``benchmarks/search_lookalikes.py --choose --seeds 11 21 31``, 288 frames of 72 look-alikes,
a lost car's search over 24 places): the best wrong place of 74 frames (0.257) came within
6 decades of the level, and beyond that the tail falls by ``exp(-0.397)`` per decade
(maximum likelihood; 0.306 at the lower 95 % bound, used here). A pass of a look-alike gives
about 4 searched frames (a 40 m stretch in the sighting range at 10 m/s and the matcher
worker's 1 frame a second), so the rule is set for a false relocalisation per look-alike
pass of at most ``FALSE_PER_PASS`` (1e-3): ``4 * 0.257 * exp(-0.306 (D + 6)) <= 1e-3`` gives
D = 16.7, rounded up to the half decade: 17. XFeat's own look-alike tail (the same frames)
gives 46.5.
"""

from __future__ import annotations

import math
import sqlite3
import threading
from dataclasses import dataclass, replace

from landmark_db.features import ExtractorConfig, Features
from landmark_db.global_index import GlobalIndex, load_index
from landmark_db.matcher import MatchConfig, PairMatcher

SHORTLIST = 20
"""Places verified geometrically after the global ranking."""
SEARCH_MAX_PHOTOS = 20
"""Photos compared per searched frame at most (the time budget of a lost car's frame)."""
FALSE_PER_PASS = 1e-3
"""The false-relocalisation rate per look-alike passed while lost that the rule is set for."""
FRAMES_PER_PASS = 4
"""Searched frames per pass of a scene (40 m in the 20 m sighting range at 10 m/s, at the
matcher worker's frame a second): the union bound's count of chances per pass."""


@dataclass(frozen=True, slots=True)
class Tail:
    """The measured tail of the best wrong place's log10 NFA per searched frame, in decades
    past the search level ``x``: ``P(x > t) = fraction * exp(-rate (t - start))`` for
    ``t >= start`` (``rate``: the pessimistic, lower 95 % bound of the fit)."""

    start: float
    fraction: float
    rate: float


LOOKALIKE_TAIL = {
    "rootsift": Tail(start=-6.0, fraction=74 / 288, rate=0.306),
    "xfeat": Tail(start=-6.0, fraction=31 / 288, rate=0.116),
}
"""Fitted on look-alike passes of a lost car (module docstring; seeds 11, 21, 31 of
``benchmarks/search_lookalikes.py --choose [--extractor xfeat]``). XFeat's log NFA spreads
wider: fewer wrong frames come near its level (31 of 288), but its tail is long (wrong places
20.8 and 25.3 decades past the level; rate 0.179 by maximum likelihood, 0.116 at the bound)."""


def scene_decades(kind: str) -> float:
    """How far below the search level one frame relocalises a lost car: the margin ``D`` at
    which ``FRAMES_PER_PASS * P(x > D) <= FALSE_PER_PASS`` under the kind's look-alike tail,
    rounded up to the half decade (RootSIFT 17, XFeat 46.5). ORB's tail is not measured: it
    takes RootSIFT's."""
    tail = LOOKALIKE_TAIL.get(kind, LOOKALIKE_TAIL["rootsift"])
    d = tail.start + math.log(FRAMES_PER_PASS * tail.fraction / FALSE_PER_PASS) / tail.rate
    return math.ceil(2.0 * d) / 2.0


SCENE_DECADES = scene_decades("rootsift")


@dataclass(frozen=True, slots=True)
class SearchConfig:
    shortlist: int = SHORTLIST
    max_photos: int = SEARCH_MAX_PHOTOS
    scene_decades: float | None = None
    """None: ``scene_decades`` of the file's extractor."""
    pair_at_level: bool = False
    """The rule before ``scene_decades``: two agreeing frames within the recogniser's
    ``confirm_window_s`` at the search level also relocalise (consecutive frames taken as
    independent). Off; kept so ``benchmarks/search_lookalikes.py`` can show both rules on
    the same frames."""

    def __post_init__(self) -> None:
        if self.shortlist < 1 or self.max_photos < 1:
            raise ValueError("shortlist and max_photos must be >= 1")
        if self.scene_decades is not None and not self.scene_decades >= 0.0:
            raise ValueError("scene_decades must be >= 0")


def bonferroni_decades(places: int) -> float:
    """How many decades a search over ``places`` places lowers the NFA level."""
    return math.log10(max(places, 1))


class WholeDbSearch:
    """The global index of one open database (loaded on first use) and the matcher at the
    search's level. Thread-safe loading; the matcher itself belongs to the caller's lock."""

    def __init__(
        self,
        conn: sqlite3.Connection,
        db_lock: threading.RLock,
        extractor: ExtractorConfig,
        match: MatchConfig,
        config: SearchConfig | None = None,
    ) -> None:
        self._conn, self._db_lock = conn, db_lock
        self.extractor = extractor
        self.config = config or SearchConfig()
        self._base_match = match
        self._index: GlobalIndex | None = None
        self._loaded = False
        self.matcher: PairMatcher | None = None
        self.level = -math.inf

    def index(self) -> GlobalIndex | None:
        """The global index (None for a database without photos)."""
        if not self._loaded:
            with self._db_lock:
                self._index = load_index(self._conn, self.extractor)
            self._loaded = True
            places = self._index.places() if self._index is not None else 1
            self.level = self._base_match.nfa_needed(self.extractor.kind) - bonferroni_decades(
                places
            )
            self.matcher = PairMatcher(replace(self._base_match, max_log10_nfa=self.level))
        return self._index

    def shortlist(self, features: Features) -> list[tuple[int, float]]:
        """(landmark id, cosine) of the most similar places, best first."""
        idx = self.index()
        if idx is None:
            return []
        return idx.shortlist(idx.encode(features), self.config.shortlist)

    def places(self) -> int:
        idx = self.index()
        return 0 if idx is None else idx.places()

    def scene_level(self) -> float:
        """The log10 NFA at or below which one frame relocalises a lost car."""
        self.index()
        margin = self.config.scene_decades
        if margin is None:
            margin = scene_decades(self.extractor.kind)
        return self.level - margin
