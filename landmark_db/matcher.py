"""Pairwise verification of a camera frame against one landmark photo (SPEC section 6).

Pipeline: descriptors of both images (``landmark_db.features``); k-nearest-neighbour matching
(k = 2) from the frame to the photo, by a k-d tree over the photo's RootSIFT descriptors
(built once per photo and cached by the recogniser) or brute-force Hamming for ORB; Lowe's
ratio test; one match per photo keypoint; a homography by MAGSAC++ (``cv2.USAC_MAGSAC``);
the inlier count is the score. Street facades are close to planar, which is why the
homography is the model.

Plausibility is judged on the *inliers' region*: the bounding box of the inlying photo
points must map to a convex, non-mirrored quadrilateral in front of the camera. (The whole
photo's outline was used before; a correct street view whose photo reaches far beyond the
matched facade had a corner mapped behind the camera and was rejected.)

The thresholds are calibrated on negatives (``landmark-db acceptance``; docs/landmarks.md):
``CALIBRATED_MIN_INLIERS`` is twice the most inliers any wrong pair reached, plus one.
All heavy calls (knnMatch, findHomography) are OpenCV calls that release the GIL.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from landmark_db.features import CV, Features

FEW_MATCHES = "few_matches"
FAILED_GEOMETRY = "failed_geometry"

MIN_MATCHES_FOR_GEOMETRY = 6
"""Below this many ratio-test survivors no homography is attempted (4 define one exactly)."""

CALIBRATED_MIN_INLIERS = {"rootsift": 12, "orb": 9}
"""Inliers needed to accept, per extractor: 2 x (most inliers of a wrong pair) + 1 on the
calibration set (docs/landmarks.md, "How the thresholds were calibrated")."""
REPROJ_PX = {"rootsift": 3.0, "orb": 4.0}
"""MAGSAC++ threshold in frame pixels (frames at 480 px for RootSIFT, 1024 px for ORB)."""


@dataclass(frozen=True, slots=True)
class MatchConfig:
    """Thresholds of the pairwise check. ``None`` takes the calibrated value for the
    database's extractor (``CALIBRATED_MIN_INLIERS``, ``REPROJ_PX``)."""

    ratio: float = 0.8
    """Lowe's ratio: best distance must be below this fraction of the second best."""
    min_inliers: int | None = None
    """MAGSAC++ inliers needed to accept (the score threshold)."""
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
        if self.min_inliers is not None and self.min_inliers < 4:
            raise ValueError("min_inliers must be at least 4")

    def inliers_needed(self, kind: str) -> int:
        return self.min_inliers if self.min_inliers is not None else CALIBRATED_MIN_INLIERS[kind]

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
        if features.kind != "orb" and len(features) >= 2:
            self._flann = CV.FlannBasedMatcher({"algorithm": 1, "trees": trees}, {"checks": checks})
            self._flann.add([self._desc])
            self._flann.train()

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
        inliers = len(inlier_pts) if plausible_homography(H, inlier_pts) else 0
        if inliers >= cfg.inliers_needed(kind):
            return MatchEvidence(landmark_id, n_good, inliers, "homography", None, pid)
        reason = FEW_MATCHES if n_good < cfg.inliers_needed(kind) else FAILED_GEOMETRY
        return MatchEvidence(landmark_id, n_good, inliers, "homography", reason, pid)


def plausible_homography(H: np.ndarray, points: np.ndarray) -> bool:
    """The bounding box of ``points`` (photo pixels, the inliers) maps to a convex,
    non-mirrored quadrilateral in front of the camera."""
    if len(points) < 4 or not np.all(np.isfinite(H)):
        return False
    if np.linalg.det(H[:2, :2]) <= 0.0:
        return False
    x0, y0 = points.min(axis=0)
    x1, y1 = points.max(axis=0)
    if x1 - x0 < 1.0 or y1 - y0 < 1.0:  # all inliers on a line or a point: no plane seen
        return False
    corners = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], np.float64)
    w = corners @ H[2, :2] + H[2, 2]
    if np.any(w <= 1e-9):  # a corner maps behind the camera: a folded, impossible view
        return False
    quad = cv2.perspectiveTransform(corners.reshape(-1, 1, 2), H).reshape(-1, 2)
    return bool(cv2.isContourConvex(quad.astype(np.float32)))
