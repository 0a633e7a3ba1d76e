"""Pairwise verification of a camera frame against one landmark photo (SPEC section 6).

Pipeline: descriptors of both images (``landmark_db.features``); k-nearest-neighbour matching
(k = 2) from the frame to the photo, by a k-d tree over the photo's RootSIFT descriptors
(built once per photo and cached by the recogniser) or brute-force Hamming for ORB; Lowe's
ratio test; one match per photo keypoint; a homography by MAGSAC++ (``cv2.USAC_MAGSAC``).
Street facades are close to planar, which is why the homography is the model.

**Decision: an a-contrario test** (``log10_nfa``; Moisan & Stival 2004, ORSA; Moisan, Moulon
& Monasse 2012). Under the null hypothesis "wrong pair", the frame positions of the ``n``
putative matches are independent of where the homography sends their photo points, uniform
over the region the matches occupy (their convex hull in the frame). The number of false
alarms of the homography with its ``k`` best-fitting matches is
``NFA = (n - 4) C(n, k) C(k, 4) alpha_k^(k - 4)``, ``alpha_k = pi e_k^2 / area`` with
``e_k`` the k-th smallest residual: the expected number of subsets of the putative matches
that would fit *some* homography that well by chance. A pair is verified when
``log10 NFA <= MAX_LOG10_NFA``; the level was set from the wrong pairs of synthetic facades
(look-alikes) and checked on every wrong pair of the shared real photos (docs/landmarks.md,
"The decision rule").

Plausibility is judged on the *inliers' region*: the bounding box of the inlying photo
points must map to a convex, orientation-preserving quadrilateral in front of the camera.
A homography is defined up to scale, sign included: it is normalised so its corners' ``w``
are positive; only mixed signs (the region folds through the horizon) are refused.

Matching is deterministic: the k-d trees are built from a fixed seed of OpenCV's random
state (``FLANN_SEED``), so a pair's evidence does not depend on what the process matched
before (MAGSAC++ seeds itself). All heavy calls (knnMatch, findHomography) are OpenCV calls
that release the GIL.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from landmark_db.features import CV, FLOAT_KINDS, Features

FEW_MATCHES = "few_matches"
FAILED_GEOMETRY = "failed_geometry"

MIN_MATCHES_FOR_GEOMETRY = 6
"""Below this many ratio-test survivors no homography is attempted (4 define one exactly)."""

MAX_LOG10_NFA = {"rootsift": -9.5, "orb": -9.0, "xfeat": -24.0}
"""A pair verifies when log10 NFA is at most this (docs/landmarks.md, "The decision rule");
RootSIFT's from the synthetic fit (-9.29; -9.36 again for RootSIFT 2, the contrast-stretched
extractor), XFeat's from its own (-23.56), whose held-out cities exceed the claim
(docs/landmarks.md, "XFeat")."""
MIN_INLIERS = 8
"""And its homography has at least this many MAGSAC++ inliers: a floor that does not come
from the null model, so a handful of exact fits on one element never decides alone."""
RESIDUAL_FLOOR_PX = 0.5
"""Residuals below this count as this (keypoint localisation; keeps alpha away from 0)."""
FLANN_SEED = 0x5EED
"""OpenCV's random state before a photo's k-d trees are built: the same trees everywhere."""
REPROJ_PX = {"rootsift": 3.0, "orb": 4.0, "xfeat": 4.0}
"""MAGSAC++ threshold in frame pixels (frames at 440 px for RootSIFT, 1024 px for ORB, 640 px
for XFeat: about the same fraction of the frame as RootSIFT's)."""
MIN_COSINE = 0.82
"""XFeat: a mutual nearest neighbour is a putative match only above this cosine similarity
(the reference implementation's default, ``XFeat.match(min_cossim=0.82)``; not fitted here),
and only if it also passes Lowe's ratio test (``MatchConfig.ratio``, as RootSIFT): without
it, one synthetic city gave 1060 of 10,740 wrong pairs verified at log10 NFA <= -9.5, the
window grids of look-alike facades matching corner to corner (docs/landmarks.md)."""
RATIO_EXCLUSION_PX = 16.0
"""XFeat's ratio test compares the best neighbour with the best one farther than this from
it in the photo: two of the network's 8-pixel cells (``mutual_nearest``)."""


@dataclass(frozen=True, slots=True)
class MatchConfig:
    """Thresholds of the pairwise check. ``None`` takes the calibrated value for the
    database's extractor (``CALIBRATED_MIN_INLIERS``, ``REPROJ_PX``)."""

    ratio: float = 0.8
    """Lowe's ratio: best distance must be below this fraction of the second best."""
    max_log10_nfa: float | None = None
    """log10 NFA at most this to accept (``MAX_LOG10_NFA`` of the extractor when None)."""
    min_inliers: int = MIN_INLIERS
    """MAGSAC++ inliers needed to accept, besides the NFA."""
    ransac_reproj_px: float | None = None
    max_iters: int = 2000
    """MAGSAC++ iterations at most (it stops early when confident)."""
    flann_checks: int = 24
    """Leaves the k-d trees visit per query (RootSIFT): the speed/accuracy knob of kNN."""
    flann_trees: int = 4
    """Randomised k-d trees per photo index."""

    def __post_init__(self) -> None:
        if not 0.0 < self.ratio < 1.0:
            raise ValueError("ratio must be in (0, 1)")
        if self.min_inliers < 4:
            raise ValueError("min_inliers must be at least 4")

    def nfa_needed(self, kind: str) -> float:
        return self.max_log10_nfa if self.max_log10_nfa is not None else MAX_LOG10_NFA[kind]

    def accepts(self, kind: str, inliers: int, log_nfa: float) -> bool:
        """The decision rule on one pair's evidence."""
        return inliers >= self.min_inliers and log_nfa <= self.nfa_needed(kind)

    def reproj_px(self, kind: str) -> float:
        return self.ransac_reproj_px if self.ransac_reproj_px is not None else REPROJ_PX[kind]


@dataclass(frozen=True, slots=True)
class MatchEvidence:
    """What the pairwise check found for one landmark (its best photo). ``reason`` is None
    when verified; ``inliers`` is the score whether or not it passed."""

    landmark_id: int
    good_matches: int
    inliers: int
    model: str
    reason: str | None
    photo_id: int = 0
    log_nfa: float = math.inf
    """log10 of the number of false alarms (``log10_nfa``); inf without a plausible model."""

    @property
    def verified(self) -> bool:
        return self.reason is None


class PhotoIndex:
    """One photo's features with its nearest-neighbour index, built once and reused."""

    def __init__(self, photo_id: int, features: Features, checks: int = 24, trees: int = 4) -> None:
        self.photo_id = photo_id
        self.features = features
        self._desc = features.for_matching()
        self._flann: Any = None
        if features.kind == "rootsift" and len(features) >= 2:
            self._flann = CV.FlannBasedMatcher({"algorithm": 1, "trees": trees}, {"checks": checks})
            self._flann.add([self._desc])
            cv2.setRNGSeed(FLANN_SEED)  # the randomised trees: the same in every process
            self._flann.train()

    @property
    def descriptors(self) -> np.ndarray:
        """The descriptors as matched (RootSIFT, ORB bytes, or unit float vectors)."""
        return self._desc

    def knn(self, frame_desc: np.ndarray, bf: Any) -> Any:
        if self._flann is not None:
            return self._flann.knnMatch(frame_desc, k=2)
        return bf.knnMatch(frame_desc, self._desc, k=2)


class PairMatcher:
    """Verifies frame features against landmark photos. Not thread-safe (one per thread)."""

    def __init__(self, config: MatchConfig | None = None) -> None:
        self.config = config or MatchConfig()
        self._bf = CV.BFMatcher(cv2.NORM_HAMMING, crossCheck=False)

    def good_matches(
        self, frame: Features, frame_desc: np.ndarray, photo: PhotoIndex
    ) -> np.ndarray:
        """Ratio-test survivors as an M x 2 array of (frame index, photo index).

        Where several frame keypoints pick the same photo keypoint only the closest stays.
        """
        if len(frame) < 2 or len(photo.features) < 2:
            return np.zeros((0, 2), np.int64)
        if photo.features.kind in FLOAT_KINDS:
            return mutual_nearest(
                frame_desc,
                photo.descriptors,
                MIN_COSINE,
                self.config.ratio,
                photo.features.points,
                RATIO_EXCLUSION_PX,
            )
        best: dict[int, tuple[float, int]] = {}
        ratio = self.config.ratio
        for pair in photo.knn(frame_desc, self._bf):
            if len(pair) < 2:
                continue
            m, n = pair
            if m.distance < ratio * n.distance:
                prev = best.get(m.trainIdx)
                if prev is None or m.distance < prev[0]:
                    best[m.trainIdx] = (m.distance, m.queryIdx)
        if not best:
            return np.zeros((0, 2), np.int64)
        return np.array([(q, t) for t, (_d, q) in best.items()], dtype=np.int64)

    def verify(
        self, landmark_id: int, frame: Features, frame_desc: np.ndarray, photo: PhotoIndex
    ) -> MatchEvidence:
        """The full pairwise check of the frame against one photo of a landmark."""
        cfg = self.config
        kind = photo.features.kind
        pairs = self.good_matches(frame, frame_desc, photo)
        n_good = len(pairs)
        pid = photo.photo_id
        if n_good < max(MIN_MATCHES_FOR_GEOMETRY, 1):
            return MatchEvidence(landmark_id, n_good, 0, "", FEW_MATCHES, pid)
        src = photo.features.points[pairs[:, 1]].reshape(-1, 1, 2)
        dst = frame.points[pairs[:, 0]].reshape(-1, 1, 2)
        H, mask = cv2.findHomography(
            src, dst, cv2.USAC_MAGSAC, cfg.reproj_px(kind), maxIters=cfg.max_iters, confidence=0.999
        )
        if H is None or mask is None:
            return MatchEvidence(landmark_id, n_good, 0, "homography", FAILED_GEOMETRY, pid)
        inlier_pts = src.reshape(-1, 2)[mask.ravel() > 0]
        Hn = plausible_homography(H, inlier_pts)
        if Hn is None:
            return MatchEvidence(landmark_id, n_good, 0, "homography", FAILED_GEOMETRY, pid)
        inliers = len(inlier_pts)
        lnfa = pair_log10_nfa(Hn, src.reshape(-1, 2), dst.reshape(-1, 2))
        if cfg.accepts(kind, inliers, lnfa):
            reason = None
        else:
            reason = FEW_MATCHES if n_good < cfg.min_inliers else FAILED_GEOMETRY
        return MatchEvidence(landmark_id, n_good, inliers, "homography", reason, pid, lnfa)


def mutual_nearest(
    a: np.ndarray,
    b: np.ndarray,
    min_cosine: float,
    ratio: float = 1.0,
    b_points: np.ndarray | None = None,
    exclusion_px: float = 0.0,
) -> np.ndarray:
    """Pairs (row of ``a``, row of ``b``) of unit vectors that are each other's nearest
    neighbour (largest dot product) with a cosine above ``min_cosine``: M x 2 int64.

    With ``ratio`` < 1, also Lowe's ratio test on the Euclidean distances (``sqrt(2 - 2
    cos)``) to the best neighbour and to the best one *more than ``exclusion_px`` away from
    it* in ``b`` (positions ``b_points``): dense descriptors such as XFeat's are nearly equal
    for keypoints a few pixels apart (median cosine to the nearest other keypoint of a photo
    0.98), so the plain second-best is the same structure and the test would refuse
    everything; what it must refuse is another, similar structure elsewhere (a repeated
    window)."""
    if len(a) == 0 or len(b) == 0:
        return np.zeros((0, 2), np.int64)
    sim = a @ b.T
    ab = np.argmax(sim, axis=1)
    ba = np.argmax(sim, axis=0)
    i = np.arange(len(a))
    best = sim[i, ab]
    keep = (ba[ab] == i) & (best > min_cosine)
    if ratio < 1.0 and sim.shape[1] >= 2 and np.any(keep):
        rows = i[keep]
        s = sim[rows]
        if b_points is not None and exclusion_px > 0.0:
            p = b_points[ab[rows]]
            d2 = ((b_points[None, :, :] - p[:, None, :]) ** 2).sum(axis=2)
            s = np.where(d2 > exclusion_px * exclusion_px, s, -1.0)
        else:
            s = s.copy()
            s[np.arange(len(rows)), ab[rows]] = -1.0
        second = s.max(axis=1)
        d1 = np.sqrt(np.maximum(2.0 - 2.0 * best[rows], 0.0))
        d2nd = np.sqrt(np.maximum(2.0 - 2.0 * second, 0.0))
        keep[rows] = d1 < ratio * d2nd
    return np.stack([i[keep], ab[keep]], axis=1).astype(np.int64)


def plausible_homography(H: np.ndarray, points: np.ndarray) -> np.ndarray | None:
    """``H`` scaled so its ``w`` is positive over the bounding box of ``points`` (photo
    pixels, the inliers), if that box maps to a convex, orientation-preserving quadrilateral
    in front of the camera; else None.

    A homography is defined up to a scale, sign included: all four corners with ``w < 0`` is
    the same view as all with ``w > 0``. Mixed signs mean the box crosses the horizon (a
    folded, impossible view). With ``w > 0`` the Jacobian determinant is ``det(H) / w^3``,
    so ``det(H) > 0`` is "not mirrored" everywhere in the box.
    """
    if len(points) < 4 or not np.all(np.isfinite(H)):
        return None
    x0, y0 = points.min(axis=0)
    x1, y1 = points.max(axis=0)
    if x1 - x0 < 1.0 or y1 - y0 < 1.0:  # all inliers on a line or a point: no plane seen
        return None
    corners = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], np.float64)
    H = np.asarray(H, np.float64)
    w = corners @ H[2, :2] + H[2, 2]
    if np.all(w < 0.0):
        H, w = -H, -w
    scale = float(np.abs(H).max())
    if scale == 0.0 or np.any(w <= 1e-9 * scale):
        return None
    if np.linalg.det(H) <= 0.0:
        return None
    quad = cv2.perspectiveTransform(corners.reshape(-1, 1, 2), H).reshape(-1, 2)
    if not np.all(np.isfinite(quad)) or not cv2.isContourConvex(quad.astype(np.float32)):
        return None
    return H


def nfa_k_grid(n: int, sample: int = 4) -> np.ndarray:
    """The subset sizes ``log10_nfa`` tries: every k up to 16, then steps of 1/8 (a minimum
    over fewer k is never below the exact one: the grid can only be more cautious)."""
    ks = set(range(sample + 1, min(n, 16) + 1))
    k = 16.0
    while k < n:
        k *= 1.125
        ks.add(min(round(k), n))
    return np.array(sorted(ks), dtype=np.int64)


def log10_nfa(
    residuals_px: np.ndarray, points_px: np.ndarray, sample: int = 4
) -> tuple[float, int]:
    """(log10 NFA, k) of the best k: ORSA's number of false alarms of a model fitted to
    ``sample`` points, given every putative match's residual and frame position.

    ``NFA(k) = (n - s) C(n, k) C(k, s) alpha_k^(k - s)``, ``alpha_k = pi e_k^2 / area_k``
    (at most 1), minimised over ``k`` (``nfa_k_grid``). The counting terms are the tests:
    which ``k`` (``n - s``), which ``k`` matches, which ``s`` of them define the model.
    ``e_k`` is the k-th smallest residual (at least ``RESIDUAL_FLOOR_PX``) and ``area_k``
    the area of the convex hull of those ``k`` points in the frame: the null model is
    "uniform over the region the matched points occupy", so a cluster of matches on one
    small patch (a sign, a repeated ornament) counts for little.
    """
    r = np.asarray(residuals_px, np.float64)
    n = len(r)
    if n <= sample:
        return math.inf, 0
    order = np.argsort(r)
    rs = r[order]
    pts = np.asarray(points_px, np.float32).reshape(-1, 2)[order]
    lf = np.concatenate(([0.0], np.cumsum(np.log10(np.arange(1, n + 1, dtype=np.float64)))))
    best, best_k = math.inf, 0
    for k in nfa_k_grid(n, sample):
        e = max(float(rs[k - 1]), RESIDUAL_FLOOR_PX)
        if not math.isfinite(e):
            break
        area = float(cv2.contourArea(cv2.convexHull(pts[:k].reshape(-1, 1, 2))))
        if not area > 0.0:
            continue
        log_alpha = min(math.log10(math.pi * e * e / area), 0.0)
        v = (
            math.log10(n - sample)
            + (lf[n] - lf[k] - lf[n - k])
            + (lf[k] - lf[sample] - lf[k - sample])
            + (k - sample) * log_alpha
        )
        if v < best:
            best, best_k = v, int(k)
    return best, best_k


def pair_log10_nfa(H: np.ndarray, src: np.ndarray, dst: np.ndarray) -> float:
    """log10 NFA of homography ``H`` (photo -> frame) over all putative matches ``src`` ->
    ``dst`` (N x 2), residuals in frame pixels (``log10_nfa``)."""
    proj = cv2.perspectiveTransform(src.reshape(-1, 1, 2).astype(np.float64), H).reshape(-1, 2)
    res = np.linalg.norm(proj - dst.astype(np.float64), axis=1)
    res[~np.isfinite(res)] = np.inf
    return log10_nfa(res, dst)[0]


SAME_PLACE_RADIUS_M = 40.0
"""A photo taken this close to a landmark (twice the sighting range) may join it on the
weaker visual check ``SAME_PLACE_LOG10_NFA`` (docs/landmarks.md, "Several photos per
place")."""
SAME_PLACE_LOG10_NFA = {"rootsift": -4.0, "orb": -4.0}
"""The weaker check for a photo whose position agrees with the landmark's: wrong pairs beyond
log10 NFA -4 were 3.0e-3 (fit cities) and 3.9e-3 (held-out cities) of the synthetic wrong
pairs for RootSIFT 2 (2.6e-3 / 3.4e-3 before the contrast stretch), 1.2e-3 / 2.4e-3 for
ORB. XFeat has no weaker level (its synthetic tail is far heavier): its photos need the full
rule."""


def agreement_config(kind: str, position_agrees: bool) -> MatchConfig:
    """The check a photo added to a landmark must pass: the decision rule, or, when its
    position is within ``SAME_PLACE_RADIUS_M`` of the landmark, the weaker level."""
    if position_agrees and kind in SAME_PLACE_LOG10_NFA:
        return MatchConfig(max_log10_nfa=SAME_PLACE_LOG10_NFA[kind])
    return MatchConfig()


def photo_agreement(
    landmark_id: int,
    new: Features,
    existing: list[tuple[int, Features]],
    config: MatchConfig | None = None,
) -> MatchEvidence | None:
    """The strongest evidence that photo features ``new`` show the place the ``existing``
    photos of a landmark show, by the decision rule (``new`` as the frame); None when the
    landmark has no photo. A photo added to a landmark must verify against one of them, or
    one stray photo could make the place match what that photo alone shows."""
    matcher = PairMatcher(config)
    desc = new.for_matching()
    best: MatchEvidence | None = None
    for pid, feats in existing:
        e = matcher.verify(landmark_id, new, desc, PhotoIndex(pid, feats))
        if best is None or (e.verified, -e.log_nfa, e.inliers) > (
            best.verified,
            -best.log_nfa,
            best.inliers,
        ):
            best = e
    return best
