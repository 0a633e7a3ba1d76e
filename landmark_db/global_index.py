"""A global descriptor per photo, for the whole-database search of a lost car (issue 36).

**VLAD** (Jegou et al. 2010, with the intra-normalisation of Arandjelovic & Zisserman 2013)
over the photo's local features, as the matcher compares them (RootSIFT, XFeat's unit
vectors, ORB's bits as 0/1), each first centred and projected on its ``PROJECTED_DIMS``
principal axes (of the file's descriptors): each is assigned to the nearest of ``K`` centres,
the residuals are summed per centre, each centre's block is L2-normalised, then the whole
vector gets a signed square root and an L2 normalisation. Two photos compare by the dot
product of their vectors (cosine).

**The vocabulary** (the ``K`` centres) is found by OpenCV's k-means (k-means++ seeding from a
fixed seed, so a file rebuilt from the same photos gets the same centres) over at most
``KMEANS_SAMPLE`` descriptors drawn evenly from the file's photos. It is stored in the file
(table ``vocabulary``, schema v4) with the number of photos it was built from; each photo's
vector is stored in ``photo_global`` with the vocabulary's identity. A write that adds
photos (``add``, ``add --to``, ``import``, ``survey``, ``migrate``) encodes the new photo
with the stored vocabulary, and rebuilds the vocabulary and every vector when the file has
no vocabulary yet, was described by another extractor, or holds twice the photos the
vocabulary was built from (so the vocabulary follows the database as it grows at a total
cost of about two encodings per photo).

The search itself (a shortlist by cosine, then the pairwise check with a Bonferroni level)
is in ``landmark_db.recognise``; this module only makes and keeps the vectors.
"""

from __future__ import annotations

import hashlib
import sqlite3
from dataclasses import dataclass, replace

import cv2
import numpy as np

from landmark_db.features import ExtractorConfig, Features

CENTRES = 64
"""VLAD centres: 64 x 64 = 4096 dimensions."""
PROJECTED_DIMS = 64
"""Descriptors are projected on this many principal axes before VLAD. Chosen on simulated
facades (150 places, 50 views): the right place among the 10 most similar for 0.82 of the
views with 64 centres on the full RootSIFT (8192 dimensions) and on this projection (4096),
0.56 with 16 centres, 0.44-0.68 for a bag of 256-1024 words."""
KMEANS_SAMPLE = 20_000
"""Descriptors the vocabulary is trained on at most (k-means time grows with it)."""
KMEANS_ITERATIONS = 12
VOCABULARY_SEED = 0x5EED
REBUILD_GROWTH = 2.0
"""The vocabulary is rebuilt when the file holds this many times the photos it was built on."""


@dataclass(frozen=True, slots=True)
class Vocabulary:
    centres: np.ndarray
    """K x d float32 (in the projected space)."""
    mean: np.ndarray
    """D float32: the descriptors' mean, subtracted before the projection."""
    projection: np.ndarray
    """D x d float32: principal axes."""
    extractor: str
    """The ``ExtractorConfig.ident`` of the descriptors it was trained on."""
    photos: int
    """Photos in the file when it was built."""

    @property
    def ident(self) -> str:
        """Identity stored with every vector made from it."""
        h = hashlib.sha256(self.extractor.encode())
        for a in (self.centres, self.mean, self.projection):
            h.update(np.ascontiguousarray(a, np.float32).tobytes())
        return h.hexdigest()[:16]

    def project(self, space: np.ndarray) -> np.ndarray:
        return (space - self.mean) @ self.projection

    def encode(self, space: np.ndarray) -> np.ndarray:
        """The VLAD vector of descriptors in ``descriptor_space``."""
        return vlad(self.project(space), self.centres)

    @property
    def dims(self) -> int:
        return int(self.centres.size)


def descriptor_space(features: Features) -> np.ndarray:
    """The descriptors as float32 vectors, as the matcher compares them."""
    d = features.for_matching()
    if features.kind == "orb":
        return np.unpackbits(d, axis=1).astype(np.float32)
    return np.ascontiguousarray(d, dtype=np.float32)


def train(sample: np.ndarray, extractor: str, photos: int, k: int = CENTRES) -> Vocabulary:
    """The principal axes of a descriptor sample, then k-means (OpenCV, k-means++ from a
    fixed seed) over the projected sample."""
    sample = np.asarray(sample, np.float64)
    mean = sample.mean(axis=0)
    dims = min(PROJECTED_DIMS, sample.shape[1])
    cov = np.cov((sample - mean).T) if len(sample) > 1 else np.eye(sample.shape[1])
    _w, axes = np.linalg.eigh(np.atleast_2d(cov))
    proj = np.ascontiguousarray(axes[:, ::-1][:, :dims], np.float32)
    mean32 = mean.astype(np.float32)
    x = np.ascontiguousarray((sample.astype(np.float32) - mean32) @ proj, np.float32)
    k = max(1, min(k, len(x)))
    cv2.setRNGSeed(VOCABULARY_SEED)
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, KMEANS_ITERATIONS, 1e-4)
    _c, _labels, centres = cv2.kmeans(x, k, None, crit, 1, cv2.KMEANS_PP_CENTERS)
    return Vocabulary(np.ascontiguousarray(centres, np.float32), mean32, proj, extractor, photos)


def vlad(desc: np.ndarray, centres: np.ndarray) -> np.ndarray:
    """The VLAD vector (float32, unit length; zeros for no descriptor) of N x D descriptors."""
    k, dim = centres.shape
    out = np.zeros((k, dim), np.float32)
    if len(desc):
        # squared distances without the |x|^2 term (constant per row)
        d2 = (centres * centres).sum(axis=1)[None, :] - 2.0 * desc @ centres.T
        nearest = np.argmin(d2, axis=1)
        assign = np.zeros((k, len(desc)), np.float32)
        assign[nearest, np.arange(len(desc))] = 1.0
        out = assign @ desc - assign.sum(axis=1)[:, None] * centres
    norms = np.linalg.norm(out, axis=1, keepdims=True)
    out = np.divide(out, norms, out=np.zeros_like(out), where=norms > 0)
    v = out.ravel()
    v = np.sign(v) * np.sqrt(np.abs(v))
    n = float(np.linalg.norm(v))
    return (v / n if n > 0 else v).astype(np.float32)


# --- storage -----------------------------------------------------------------------------------


def _vocabulary_row(conn: sqlite3.Connection) -> Vocabulary | None:
    r = conn.execute(
        "SELECT extractor, photos, k, dims, centres, mean, projection FROM vocabulary"
    ).fetchone()
    if r is None:
        return None
    extractor, photos, k, dims, blob, mblob, pblob = r
    try:  # a damaged row is no vocabulary: the search then builds one in memory
        centres = np.frombuffer(blob, "<f4").reshape(k, dims)
        mean = np.frombuffer(mblob, "<f4")
        proj = np.frombuffer(pblob, "<f4").reshape(len(mean), dims)
        n_photos = int(photos)
    except (TypeError, ValueError, OverflowError):
        return None
    if not all(np.all(np.isfinite(a)) for a in (centres, mean, proj)) or min(k, dims) < 1:
        return None
    return Vocabulary(
        centres.astype(np.float32), mean.astype(np.float32), proj.astype(np.float32),
        str(extractor), n_photos,
    )  # fmt: skip


def load_vocabulary(conn: sqlite3.Connection) -> Vocabulary | None:
    """The stored vocabulary, or None (none built yet, or a damaged row)."""
    return _vocabulary_row(conn)


def _photo_count(conn: sqlite3.Connection) -> int:
    return int(conn.execute("SELECT count(*) FROM photos").fetchone()[0])


def _store_vector(conn: sqlite3.Connection, pid: int, voc: Vocabulary, v: np.ndarray) -> None:
    conn.execute(
        "INSERT OR REPLACE INTO photo_global VALUES (?, ?, ?)",
        (pid, voc.ident, v.astype("<f2").tobytes()),
    )


def needs_rebuild(conn: sqlite3.Connection, extractor: ExtractorConfig) -> bool:
    voc = _vocabulary_row(conn)
    return (
        voc is None
        or voc.extractor != extractor.ident
        or _photo_count(conn) >= REBUILD_GROWTH * max(voc.photos, 1)
    )


def photo_added(
    conn: sqlite3.Connection, pid: int, features: Features, extractor: ExtractorConfig
) -> None:
    """Keep the global index up to date after photo ``pid`` got ``features`` (in the
    caller's transaction): encode it, or rebuild everything when the vocabulary is due."""
    if needs_rebuild(conn, extractor):
        rebuild(conn, extractor)
        return
    voc = _vocabulary_row(conn)
    assert voc is not None
    _store_vector(conn, pid, voc, voc.encode(descriptor_space(features)))


def _all_features(
    conn: sqlite3.Connection, extractor: ExtractorConfig
) -> list[tuple[int, Features]]:
    rows = conn.execute(
        "SELECT f.photo_id, f.width, f.height, f.keypoints, f.descriptors FROM photo_features f"
        " WHERE f.extractor = ? ORDER BY f.photo_id",
        (extractor.ident,),
    ).fetchall()
    out = []
    for pid, w, h, kp, desc in rows:
        try:
            out.append((int(pid), Features.from_blobs(kp, desc, w, h, extractor.kind)))
        except (TypeError, ValueError):
            continue  # a damaged blob: `check` reports it; the search just lacks that photo
    return out


def build(
    features: list[tuple[int, Features]], extractor: ExtractorConfig, k: int = CENTRES
) -> tuple[Vocabulary, np.ndarray]:
    """A vocabulary from these photos' features, and every photo's vector (rows in order)."""
    spaces = [descriptor_space(f) for _pid, f in features]
    total = sum(len(s) for s in spaces)
    rng = np.random.default_rng(VOCABULARY_SEED)
    if total > KMEANS_SAMPLE:
        keep = np.sort(rng.choice(total, KMEANS_SAMPLE, replace=False))
        sample = np.concatenate(spaces)[keep]
    else:
        sample = np.concatenate(spaces) if spaces else np.zeros((0, 1), np.float32)
    if len(sample) == 0:
        raise ValueError("no descriptors to build a vocabulary from")
    voc = train(sample, extractor.ident, len(features), k)
    memo: dict[bytes, np.ndarray] = {}  # photos that share features (bulk inserts) once
    vecs = []
    for sp in spaces:
        key = hashlib.sha256(sp.tobytes()).digest()
        if key not in memo:
            memo[key] = voc.encode(sp)
        vecs.append(memo[key])
    return voc, np.stack(vecs).astype(np.float32)


def rebuild(conn: sqlite3.Connection, extractor: ExtractorConfig) -> int:
    """Train the vocabulary on the file's photos and encode every photo (in the caller's
    transaction); returns the photos encoded (0 and no vocabulary for an empty file)."""
    feats = _all_features(conn, extractor)
    conn.execute("DELETE FROM vocabulary")
    conn.execute("DELETE FROM photo_global")
    if not feats:
        return 0
    voc, vecs = build(feats, extractor)
    voc = replace(voc, photos=_photo_count(conn))
    conn.execute(
        "INSERT INTO vocabulary VALUES (?, ?, ?, ?, ?, ?, ?)",
        (voc.extractor, voc.photos, voc.centres.shape[0], voc.centres.shape[1],
         voc.centres.astype("<f4").tobytes(), voc.mean.astype("<f4").tobytes(),
         voc.projection.astype("<f4").tobytes()),
    )  # fmt: skip
    for (pid, _f), v in zip(feats, vecs, strict=True):
        _store_vector(conn, pid, voc, v)
    return len(feats)


@dataclass(frozen=True, slots=True)
class GlobalIndex:
    """Every photo's vector in memory, for the search: ``matrix`` rows are photos."""

    vocabulary: Vocabulary
    photo_ids: np.ndarray
    landmark_ids: np.ndarray
    matrix: np.ndarray
    """P x dims float32, unit rows."""
    computed: int = 0
    """Vectors that were missing or stale in the file and were computed at load."""

    def places(self) -> int:
        return len(np.unique(self.landmark_ids))

    def shortlist(self, query: np.ndarray, places: int) -> list[tuple[int, float]]:
        """The ``places`` landmarks whose best photo is most similar: (landmark id, cosine)."""
        if len(self.matrix) == 0:
            return []
        sims = self.matrix @ query.astype(np.float32)
        order = np.argsort(-sims)
        out: list[tuple[int, float]] = []
        seen: set[int] = set()
        for i in order:
            lid = int(self.landmark_ids[i])
            if lid in seen:
                continue
            seen.add(lid)
            out.append((lid, float(sims[i])))
            if len(out) >= places:
                break
        return out

    def encode(self, features: Features) -> np.ndarray:
        return self.vocabulary.encode(descriptor_space(features))


def load_index(conn: sqlite3.Connection, extractor: ExtractorConfig) -> GlobalIndex | None:
    """The file's global index (read-only: vectors that are missing or were made by another
    vocabulary are computed in memory, and a file without a vocabulary gets one in memory);
    None for a file without photos."""
    voc = _vocabulary_row(conn)
    if voc is not None and voc.extractor != extractor.ident:
        voc = None
    rows = conn.execute(
        "SELECT p.id, p.landmark_id, g.vocabulary, g.vector FROM photos p"
        " LEFT JOIN photo_global g ON g.photo_id = p.id ORDER BY p.id"
    ).fetchall()
    if not rows:
        return None
    if voc is None:
        feats = _all_features(conn, extractor)
        if not feats:
            return None
        voc, built = build(feats, extractor)
        by_pid = {pid: v for (pid, _f), v in zip(feats, built, strict=True)}
        lid_of = {int(r[0]): int(r[1]) for r in rows}
        have = [p for p in by_pid if p in lid_of]
        return GlobalIndex(
            voc,
            np.array(have, np.int64),
            np.array([lid_of[p] for p in have], np.int64),
            np.stack([by_pid[p] for p in have]),
            len(have),
        )
    ident = voc.ident
    pids, lids, vecs, missing = [], [], [], []
    for pid, lid, vid, blob in rows:
        v = None
        if vid == ident and isinstance(blob, bytes) and len(blob) == 2 * voc.dims:
            v = np.frombuffer(blob, "<f2").astype(np.float32)
        if v is None or not np.all(np.isfinite(v)):
            missing.append(int(pid))
            v = np.zeros(voc.dims, np.float32)
        pids.append(int(pid))
        lids.append(int(lid))
        vecs.append(v)
    matrix = np.stack(vecs)
    if missing:
        want = set(missing)
        pos = {p: i for i, p in enumerate(pids)}
        for pid, f in _all_features(conn, extractor):
            if pid in want:
                matrix[pos[pid]] = voc.encode(descriptor_space(f))
    return GlobalIndex(voc, np.array(pids), np.array(lids), matrix, len(missing))
