"""Pairwise verification of a camera frame against one landmark photo (SPEC section 6).

Pipeline: ORB descriptors of both images; brute-force Hamming k-nearest-neighbour matching
(k = 2) from the frame to the photo; Lowe's ratio test; one match per photo keypoint;
RANSAC homography between the matched positions; a minimum inlier count and inlier share;
a sanity check of the homography (the photo's outline must map to a convex, non-mirrored,
non-degenerate quadrilateral). Street facades are close to planar, which is why the
homography is the model; the fundamental matrix is an opt-in fallback for strongly 3-D
scenes (it is a weaker test: a point-to-line constraint admits more chance agreements).

All heavy calls (knnMatch, findHomography) are OpenCV calls that release the GIL.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from landmark_db.features import CV, Features

FEW_MATCHES = "few_matches"
FAILED_GEOMETRY = "failed_geometry"


@dataclass(frozen=True, slots=True)
class MatchConfig:
    """Thresholds of the pairwise check. Defaults are tuned on docs/landmarks.md's data."""

    ratio: float = 0.75
    """Lowe's ratio: best distance must be below this fraction of the second best."""
    min_good_matches: int = 15
    """Fewer ratio-test survivors than this: ``few_matches``, no geometry attempted."""
    min_inliers: int = 12
    """RANSAC inliers needed to accept."""
    min_inlier_ratio: float = 0.25
    """Inliers as a share of the good matches needed to accept."""
    ransac_reproj_px: float = 5.0
    """RANSAC reprojection threshold, pixels of the (downscaled) feature images."""
    fundamental_fallback: bool = False
    """Try a fundamental matrix when the homography fails (needs 2x the inliers)."""

    def __post_init__(self) -> None:
        if not 0.0 < self.ratio < 1.0:
            raise ValueError("ratio must be in (0, 1)")
        if self.min_inliers < 4 or self.min_good_matches < self.min_inliers:
            raise ValueError("need min_good_matches >= min_inliers >= 4")


@dataclass(frozen=True, slots=True)
class MatchEvidence:
    """What the pairwise check found for one landmark. ``reason`` is None when verified."""

    landmark_id: int
    good_matches: int
    inliers: int
    model: str
    reason: str | None

    @property
    def verified(self) -> bool:
        return self.reason is None


class PairMatcher:
    """Verifies frame features against landmark features. Not thread-safe (one per thread)."""

    def __init__(self, config: MatchConfig | None = None) -> None:
        self.config = config or MatchConfig()
        self._bf = CV.BFMatcher(cv2.NORM_HAMMING, crossCheck=False)

    def good_matches(self, frame: Features, photo: Features) -> np.ndarray:
        """Ratio-test survivors as an M x 2 array of (frame index, photo index).

        Where several frame keypoints pick the same photo keypoint only the closest stays.
        """
        if len(frame) < 2 or len(photo) < 2:
            return np.zeros((0, 2), np.int64)
        knn = self._bf.knnMatch(frame.descriptors, photo.descriptors, k=2)
        best: dict[int, tuple[float, int]] = {}
        ratio = self.config.ratio
        for pair in knn:
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

    def verify(self, landmark_id: int, frame: Features, photo: Features) -> MatchEvidence:
        """The full pairwise check for one landmark."""
        cfg = self.config
        pairs = self.good_matches(frame, photo)
        n_good = len(pairs)
        if n_good < cfg.min_good_matches:
            return MatchEvidence(landmark_id, n_good, 0, "", FEW_MATCHES)
        src = photo.points[pairs[:, 1]].reshape(-1, 1, 2)
        dst = frame.points[pairs[:, 0]].reshape(-1, 1, 2)
        H, mask = cv2.findHomography(src, dst, cv2.RANSAC, cfg.ransac_reproj_px)
        inliers = int(mask.sum()) if mask is not None else 0
        if (
            H is not None
            and inliers >= cfg.min_inliers
            and inliers >= cfg.min_inlier_ratio * n_good
            and plausible_homography(H, photo.width, photo.height)
        ):
            return MatchEvidence(landmark_id, n_good, inliers, "homography", None)
        if cfg.fundamental_fallback and n_good >= 2 * cfg.min_inliers:
            F, fmask = cv2.findFundamentalMat(src, dst, cv2.FM_RANSAC, cfg.ransac_reproj_px, 0.99)
            f_in = int(fmask.sum()) if F is not None and fmask is not None else 0
            if f_in >= 2 * cfg.min_inliers and f_in >= 2 * cfg.min_inlier_ratio * n_good:
                return MatchEvidence(landmark_id, n_good, f_in, "fundamental", None)
        return MatchEvidence(landmark_id, n_good, inliers, "homography", FAILED_GEOMETRY)


def plausible_homography(H: np.ndarray, width: int, height: int) -> bool:
    """The photo's outline maps to a convex, non-mirrored quad with finite corners."""
    if not np.all(np.isfinite(H)):
        return False
    a = H[:2, :2]
    if np.linalg.det(a) <= 0.0:
        return False
    corners = np.array([[0, 0], [width, 0], [width, height], [0, height]], np.float64)
    w = corners @ H[2, :2] + H[2, 2]
    if np.any(w <= 1e-9):  # a corner maps behind the camera: a folded, impossible view
        return False
    quad = cv2.perspectiveTransform(corners.reshape(-1, 1, 2), H).reshape(-1, 2)
    return bool(cv2.isContourConvex(quad.astype(np.float32)))
