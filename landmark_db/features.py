"""ORB features: extraction at a bounded image size, and their storage as blobs.

OpenCV is wrapped here and in ``matcher``; nothing else in the package calls cv2 for features.
Images are converted to grey and downscaled so their longer side is at most ``max_side_px``
before detection: ORB's cost grows with the pixel count, and a 1232x1616 camera frame at
full size costs 25 ms to describe on the reference laptop against 10 ms at 1024 px
(docs/landmarks.md). Keypoint coordinates are stored in the downscaled image's pixels;
the homography check is indifferent to the scale.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

CV: Any = cv2
"""cv2 untyped: the stubs shipped with OpenCV 5.0 lack the features2d module (ORB, BFMatcher)."""

KEYPOINT_FIELDS = 6
"""Stored per keypoint (float32): x, y, size, angle, response, octave."""
DESCRIPTOR_BYTES = 32
"""ORB descriptors are 256 bits."""


@dataclass(frozen=True, slots=True)
class OrbConfig:
    """ORB parameters. ``max_side_px`` bounds the longer image side before detection."""

    n_features: int = 1000
    max_side_px: int = 1024
    scale_factor: float = 1.2
    n_levels: int = 8
    fast_threshold: int = 20

    def __post_init__(self) -> None:
        if self.n_features < 10:
            raise ValueError("n_features must be at least 10")
        if self.max_side_px < 64:
            raise ValueError("max_side_px must be at least 64")

    def create(self) -> Any:
        """A new ``cv2.ORB`` detector with these parameters."""
        return CV.ORB_create(
            nfeatures=self.n_features,
            scaleFactor=self.scale_factor,
            nlevels=self.n_levels,
            fastThreshold=self.fast_threshold,
        )


@dataclass(frozen=True, slots=True, eq=False)
class Features:
    """Keypoints (N x 6 float32) and descriptors (N x 32 uint8) of one image.

    ``width``/``height`` are the pixel size of the (downscaled) image they were found in.
    """

    keypoints: np.ndarray
    descriptors: np.ndarray
    width: int
    height: int

    def __len__(self) -> int:
        return int(self.descriptors.shape[0])

    @property
    def points(self) -> np.ndarray:
        """Keypoint positions, N x 2 float32."""
        return self.keypoints[:, :2]

    def keypoint_blob(self) -> bytes:
        return np.ascontiguousarray(self.keypoints, dtype="<f4").tobytes()

    def descriptor_blob(self) -> bytes:
        return np.ascontiguousarray(self.descriptors, dtype=np.uint8).tobytes()

    @classmethod
    def from_blobs(cls, kp_blob: bytes, desc_blob: bytes, width: int, height: int) -> Features:
        """Inverse of the two ``*_blob`` methods; raises ValueError on inconsistent blobs."""
        kp = np.frombuffer(kp_blob, dtype="<f4")
        desc = np.frombuffer(desc_blob, dtype=np.uint8)
        if kp.size % KEYPOINT_FIELDS or desc.size % DESCRIPTOR_BYTES:
            raise ValueError("feature blob length is not a whole number of entries")
        kp = kp.reshape(-1, KEYPOINT_FIELDS).astype(np.float32)
        desc = desc.reshape(-1, DESCRIPTOR_BYTES)
        if kp.shape[0] != desc.shape[0]:
            raise ValueError(f"{kp.shape[0]} keypoints but {desc.shape[0]} descriptors")
        return cls(kp, desc, width, height)


def to_grey(image: np.ndarray) -> np.ndarray:
    """BGR, BGRA or grey uint8 image -> grey uint8. Raises ValueError for anything else."""
    if not isinstance(image, np.ndarray) or image.size == 0:
        raise ValueError("not an image (empty or not an array)")
    if image.dtype != np.uint8:
        raise ValueError(f"image must be 8-bit, not {image.dtype}")
    if image.ndim == 2:
        return image
    if image.ndim == 3 and image.shape[2] == 3:
        return cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    if image.ndim == 3 and image.shape[2] == 4:
        return cv2.cvtColor(image, cv2.COLOR_BGRA2GRAY)
    if image.ndim == 3 and image.shape[2] == 1:
        return image[:, :, 0]
    raise ValueError(f"unsupported image shape {image.shape}")


def downscale(grey: np.ndarray, max_side_px: int) -> np.ndarray:
    """Shrink (never enlarge) so the longer side is at most ``max_side_px``.

    Halvings by ``pyrDown`` (Gaussian, so no aliasing) while the factor is below 1/2, then
    one bilinear step: 0.7 ms for a 1232x1616 frame where INTER_AREA takes 7.7 ms.
    """
    h, w = grey.shape[:2]
    while max(h, w) > 2 * max_side_px:
        grey = cv2.pyrDown(grey)
        h, w = grey.shape[:2]
    s = max_side_px / max(h, w)
    if s >= 1.0:
        return grey
    size = (max(1, round(w * s)), max(1, round(h * s)))
    return cv2.resize(grey, size, interpolation=cv2.INTER_LINEAR)


def extract(image: np.ndarray, config: OrbConfig, orb: Any = None) -> Features:
    """ORB keypoints and descriptors of an image (grey, downscaled per ``config``)."""
    grey = downscale(to_grey(image), config.max_side_px)
    detector = orb if orb is not None else config.create()
    kps, desc = detector.detectAndCompute(grey, None)
    h, w = grey.shape[:2]
    if desc is None or not kps:
        return Features(
            np.zeros((0, KEYPOINT_FIELDS), np.float32),
            np.zeros((0, DESCRIPTOR_BYTES), np.uint8),
            w,
            h,
        )
    kp = np.array(
        [(k.pt[0], k.pt[1], k.size, k.angle, k.response, k.octave) for k in kps],
        dtype=np.float32,
    )
    return Features(kp, np.ascontiguousarray(desc, dtype=np.uint8), w, h)


def decode_image(data: bytes) -> np.ndarray:
    """Encoded image bytes (PNG, JPEG, ...) -> BGR array. Raises ValueError if undecodable."""
    buf = np.frombuffer(data, dtype=np.uint8)
    image = cv2.imdecode(buf, cv2.IMREAD_COLOR) if buf.size else None
    if image is None:
        raise ValueError("cannot decode image data")
    return image


def encode_image(image: np.ndarray, ext: str = ".png") -> bytes:
    """BGR or grey array -> encoded bytes (``.png`` lossless by default, or ``.jpg``)."""
    ok, buf = cv2.imencode(ext, image)
    if not ok:
        raise ValueError(f"cannot encode image as {ext}")
    return bytes(buf.tobytes())
