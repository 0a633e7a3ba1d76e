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
3. The recogniser acts on two frames that verify the same place within its
   ``confirm_window_s``, or on one frame whose log10 NFA is a further
   ``SINGLE_FRAME_DECADES`` below that level (``single_frame_level``).

**Why 12.5 decades for one frame.** A second agreeing frame would divide the false-alarm
rate by about the per-frame rate (1e-3) if consecutive frames were independent. The wrong
pairs' measured tail falls by a factor ``exp(-0.56)`` per decade of NFA at its pessimistic
bound (docs/landmarks.md, "The decision rule": 0.56 is the lower bound of the fitted rate),
so dividing the rate by 1000 takes ``ln(1000) / 0.56 = 12.3`` decades; rounded up.
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
TAIL_RATE_PER_DECADE = {"rootsift": 0.56, "orb": 0.56, "xfeat": 0.30}
"""The wrong pairs' tail, ``P(-log10 NFA > t) ~ exp(-rate t)``: the pessimistic fitted rate
of each calibration (docs/landmarks.md; ORB takes RootSIFT's, its own fit was not kept).
RootSIFT 2 (contrast-stretched) fitted 0.57: the 0.56 of the first fit is kept, the more
cautious of the two."""
PER_FRAME_FALSE = 1e-3
"""The false-match rate per frame the rule is set for (docs/landmarks.md)."""


def single_frame_decades(kind: str) -> float:
    """How far below the search level one frame alone confirms a search:
    ``ln(1 / PER_FRAME_FALSE) / rate``, rounded up to the half decade (RootSIFT 12.5,
    XFeat 23.5; module docstring)."""
    d = math.log(1.0 / PER_FRAME_FALSE) / TAIL_RATE_PER_DECADE[kind]
    return math.ceil(2.0 * d) / 2.0


SINGLE_FRAME_DECADES = single_frame_decades("rootsift")


@dataclass(frozen=True, slots=True)
class SearchConfig:
    shortlist: int = SHORTLIST
    max_photos: int = SEARCH_MAX_PHOTOS
    single_frame_decades: float | None = None
    """None: ``single_frame_decades`` of the file's extractor."""

    def __post_init__(self) -> None:
        if self.shortlist < 1 or self.max_photos < 1:
            raise ValueError("shortlist and max_photos must be >= 1")
        if self.single_frame_decades is not None and not self.single_frame_decades >= 0.0:
            raise ValueError("single_frame_decades must be >= 0")


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

    def single_frame_level(self) -> float:
        """The log10 NFA at or below which one frame alone confirms a search."""
        self.index()
        margin = self.config.single_frame_decades
        if margin is None:
            margin = single_frame_decades(self.extractor.kind)
        return self.level - margin
