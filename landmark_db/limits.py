"""What a landmark file may hold: one definition, used when the tools write (``add``,
``import``, ``survey``), when the car opens a file read-only, and by ``landmark-db check``.

The limits keep every value a landmark fix can carry inside what the estimator accepts
(``guidance.core.localize.gates``: a fix sigma of 0.01-1000 m, coordinates within 1e7 m;
``tests/landmark_db/test_limits.py`` checks that they agree), and every photo small enough
to decode in bounded memory.
"""

from __future__ import annotations

import math
import struct

MAX_COORDINATE_M = 30_000.0
"""Local east/north metres from the origin, per axis. The local frame is a tangent plane
(height dropped): beyond about 40 km from the origin x/y and lat/lon no longer agree within
``POSITION_AGREEMENT_M`` (12 m at 100 km), and the R*Tree's float32 boxes lose the
centimetre beyond 131 km. A city fits; 1e39 (beyond float32) or 4e7 do not."""

POSITION_AGREEMENT_M = 1.0
"""x/y and lat/lon (through the origin) must agree this well."""

MIN_POSITION_SIGMA_M = 0.0
"""0: an exact position (simulated cities). The fix adds the sighting disc (r / 2)."""
MAX_POSITION_SIGMA_M = 500.0
"""A surveyed position known to half a kilometre is no landmark; with the sighting range
added, a fix stays under the estimator's 1000 m for sighting ranges up to 1.7 km."""

MAX_NAME_CHARS = 200
MAX_TEXT_CHARS = 1000
"""conditions, source."""

MIN_PHOTO_SIDE_PX = 32
MAX_PHOTO_SIDE_PX = 16_384
MAX_PHOTO_PIXELS = 40_000_000
"""40 MP: 120 MB decoded (BGR); read from the header before any decoding."""
MAX_PHOTO_ASPECT = 8.0
MAX_PHOTO_BYTES = 64 * 1024 * 1024
MIN_PHOTO_FEATURES = 12
"""A photo with fewer keypoints can hardly be verified (``matcher.MIN_INLIERS`` is 8 and
the NFA level needs more than that in practice): it is refused at import and reported by
``check``."""
MIN_FRAME_SIDE_PX = 64
"""A camera frame or query image smaller than this on a side is unusable (``too_small``):
SIFT's coarsest octaves need it, and the simulated camera's frames are never smaller."""

MAX_CSV_BYTES = 16 * 1024 * 1024
MAX_CSV_FIELD_CHARS = 4096
MAX_CSV_ROWS = 100_000


def position_problem(x_m: float, y_m: float) -> str | None:
    """Why a local position cannot be a landmark's, or None."""
    if not (math.isfinite(x_m) and math.isfinite(y_m)):
        return f"position ({x_m!r}, {y_m!r}) is not finite"
    if max(abs(x_m), abs(y_m)) > MAX_COORDINATE_M:
        return (
            f"position ({x_m:.6g}, {y_m:.6g}) m is more than {MAX_COORDINATE_M:.0f} m"
            " from the database's origin"
        )
    return None


def sigma_problem(sigma_m: float) -> str | None:
    """Why a position sigma cannot be a landmark's, or None."""
    if not (math.isfinite(sigma_m) and MIN_POSITION_SIGMA_M <= sigma_m <= MAX_POSITION_SIGMA_M):
        return (
            f"position sigma {sigma_m!r} m is outside"
            f" {MIN_POSITION_SIGMA_M:g}-{MAX_POSITION_SIGMA_M:g} m"
        )
    return None


def agreement_problem(dx_m: float, dy_m: float) -> str | None:
    """Why x/y and lat/lon that differ by (dx, dy) metres do not describe one place, or None."""
    d = math.hypot(dx_m, dy_m)
    if not d <= POSITION_AGREEMENT_M:
        return f"x/y disagree with lat/lon by {d:.1f} m"
    return None


def image_size(data: bytes) -> tuple[int, int]:
    """(width, height) of PNG or JPEG bytes from their header, without decoding the pixels.
    Raises ValueError for another format or a header that does not say."""
    if data[:8] == b"\x89PNG\r\n\x1a\n":
        if len(data) < 24 or data[12:16] != b"IHDR":
            raise ValueError("PNG without its IHDR header")
        w, h = struct.unpack(">II", data[16:24])
        return int(w), int(h)
    if data[:2] == b"\xff\xd8":
        return _jpeg_size(data)
    raise ValueError("not a PNG or JPEG image")


_SOF = frozenset(range(0xC0, 0xD0)) - {0xC4, 0xC8, 0xCC}
"""JPEG start-of-frame markers (the ones holding the size)."""


def _jpeg_size(data: bytes) -> tuple[int, int]:
    i = 2
    while i + 4 <= len(data):
        if data[i] != 0xFF:
            raise ValueError("damaged JPEG header")
        marker = data[i + 1]
        if marker == 0xFF:  # fill byte
            i += 1
            continue
        if marker in (0x01, *range(0xD0, 0xD8)):  # no length
            i += 2
            continue
        (length,) = struct.unpack(">H", data[i + 2 : i + 4])
        if marker in _SOF:
            if i + 9 > len(data):
                break
            h, w = struct.unpack(">HH", data[i + 5 : i + 9])
            return int(w), int(h)
        if marker == 0xDA or length < 2:  # image data before any frame header
            break
        i += 2 + length
    raise ValueError("JPEG without a frame header")


def photo_problem(width: int, height: int) -> str | None:
    """Why a photo of this size is refused, or None. Saying which limit, and the size that
    would pass when downscaling would do."""
    if min(width, height) < MIN_PHOTO_SIDE_PX:
        return f"{width}x{height} px is smaller than {MIN_PHOTO_SIDE_PX} px on a side"
    if max(width, height) > MAX_PHOTO_ASPECT * min(width, height):
        return f"{width}x{height} px is narrower than 1:{MAX_PHOTO_ASPECT:g}"
    s = min(MAX_PHOTO_SIDE_PX / max(width, height), math.sqrt(MAX_PHOTO_PIXELS / (width * height)))
    if s < 1.0:
        fit = f"{math.floor(width * s)}x{math.floor(height * s)}"
        if max(width, height) > MAX_PHOTO_SIDE_PX:
            what = f"is larger than the {MAX_PHOTO_SIDE_PX} px limit on a side"
        else:
            what = (
                f"({width * height / 1e6:.1f} megapixels) is larger than the"
                f" {MAX_PHOTO_PIXELS / 1e6:.0f} megapixel limit"
            )
        return f"{width}x{height} px {what}: downscaling it to {fit} px or less would do"
    return None


def frame_problem(width: int, height: int) -> str | None:
    """Why an image is unusable as a query or camera frame, or None."""
    if min(width, height) < MIN_FRAME_SIDE_PX:
        return (
            f"{width}x{height} px is too small to match (at least {MIN_FRAME_SIDE_PX} px on a side)"
        )
    return None
