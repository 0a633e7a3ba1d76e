"""Every pair of labelled images through the pairwise check: the false-match rate of the
decision rule over *all* wrong pairs, and recall over the right ones.

A labelled image is a photo of a known place. Every ordered pair of two distinct files is
scored: the first as the camera frame (``features`` at the frame size), the second as a
landmark photo. A pair of two places is a *wrong pair*: its verification is a false match.
A pair of one place (and not the same pixels) is a *positive pair*. ``query_outcomes`` also
gives the per-query view: a query against every photo of every *other* place (its own place
left out, as in ``acceptance``'s leave-one-out run), where any verification is false.

``shared_images`` labels ../shared/data/images (A/B pairs, ``acceptance.SAME_PLACE``,
``acceptance.CONDITIONS``) and ../shared/data/images2 (``photos/<place>/<n>.jpg``).
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from landmark_db.acceptance import CONDITIONS, IMAGE_EXTS, SAME_PLACE
from landmark_db.features import ExtractorConfig, decode_image, extract
from landmark_db.inputs import read_photo
from landmark_db.matcher import MatchConfig, PairMatcher, PhotoIndex
from landmark_db.recognise import FRAME_FEATURES

IMAGES2_CONDITIONS = {"maupertuis_chateau": "viewpoint", "venice_rooftops": "rotation"}
"""What changes between the photos of each images2 place (its README)."""


@dataclass(frozen=True, slots=True)
class LabelledImage:
    path: Path
    place: str
    group: str
    """Which set it comes from (``images``, ``images2``)."""
    condition: str = ""


@dataclass(frozen=True, slots=True)
class PairScore:
    query: int
    photo: int
    """Indexes into the image list."""
    good_matches: int
    inliers: int
    log_nfa: float
    verified: bool
    same_pixels: bool = False


def shared_images(images: Path | None, images2: Path | None) -> list[LabelledImage]:
    """The shared sets' files with their places (either folder may be None or missing)."""
    out: list[LabelledImage] = []
    if images is not None and images.is_dir():
        for p in sorted(images.rglob("*")):
            if not (p.is_file() and p.suffix.lower() in IMAGE_EXTS):
                continue
            if p.parent.name == "opencv_box":
                place = "box"
            else:
                pair = p.stem[:-1] if p.stem[-1:] in ("A", "B") else p.stem
                place = SAME_PLACE.get(pair, pair)
            out.append(LabelledImage(p, place, "images", CONDITIONS.get(place, "")))
    if images2 is not None and (images2 / "photos").is_dir():
        for p in sorted((images2 / "photos").rglob("*")):
            if p.is_file() and p.suffix.lower() in IMAGE_EXTS:
                place = p.parent.name
                out.append(LabelledImage(p, place, "images2", IMAGES2_CONDITIONS.get(place, "")))
    return out


DEGRADATIONS = ("none", "dark3", "dark5", "blur")
"""What ``degrade`` can do to a query (the camera's frame; the photos stay as they are)."""
READ_NOISE_DN = 2.0
"""Sensor noise added to a darkened frame (grey levels, 1-sigma)."""


def degrade(image: np.ndarray, how: str, seed: int = 0) -> np.ndarray:
    """A frame as a worse camera would take it (``DEGRADATIONS``):

    * ``darkN``: underexposed by N stops, in linear light (sRGB decoded, scaled by 2^-N,
      encoded again), with ``READ_NOISE_DN`` of sensor noise and 8-bit quantisation: dusk,
      or a camera at a fixed exposure in the shade. 3 stops keep a bright facade near grey
      level 90, 5 stops near 50.
    * ``blur``: 21 px of horizontal motion blur and a 2 px Gaussian at the photo's own
      resolution (a car passing at speed with a slow shutter).
    """
    if how == "none":
        return image
    if how.startswith("dark"):
        stops = float(how[4:])
        f = image.astype(np.float64) / 255.0
        lin = np.where(f <= 0.04045, f / 12.92, ((f + 0.055) / 1.055) ** 2.4) * 2.0**-stops
        out = np.where(lin <= 0.0031308, 12.92 * lin, 1.055 * lin ** (1 / 2.4) - 0.055)
        noise = np.random.default_rng(seed).normal(0.0, READ_NOISE_DN, image.shape)
        return np.clip(np.round(out * 255.0 + noise), 0, 255).astype(np.uint8)
    if how == "blur":
        kernel = np.full((1, 21), 1.0 / 21.0)
        return cv2.GaussianBlur(cv2.filter2D(image, -1, kernel), (0, 0), 2.0)
    raise ValueError(f"unknown degradation {how!r} (one of {', '.join(DEGRADATIONS)})")


def score_pairs(
    images: Sequence[LabelledImage],
    match: MatchConfig | None = None,
    extractor: ExtractorConfig | None = None,
    frames_as: str = "none",
) -> list[PairScore]:
    """Every ordered pair of distinct files, scored by the shipped pairwise check; the
    queries (frames) taken as ``degrade(frames_as)`` makes them, the photos as they are."""
    ext = extractor or ExtractorConfig()
    frame_ext = ext.for_frames(FRAME_FEATURES)
    det, frame_det = ext.create(), frame_ext.create()
    cfg = match or MatchConfig()
    photos, frames, pixels = [], [], []
    for i, im in enumerate(images):
        img = decode_image(read_photo(im.path))
        pixels.append(hashlib.sha256(np.ascontiguousarray(img).tobytes()).hexdigest())
        photos.append(PhotoIndex(i, extract(img, ext, det), cfg.flann_checks, cfg.flann_trees))
        frames.append(extract(degrade(img, frames_as, i), frame_ext, frame_det))
    matcher = PairMatcher(cfg)
    out = []
    for q, feats in enumerate(frames):
        desc = feats.for_matching()
        for p, photo in enumerate(photos):
            if p == q:
                continue
            e = matcher.verify(p, feats, desc, photo)
            out.append(
                PairScore(
                    q, p, e.good_matches, e.inliers, e.log_nfa, e.verified, pixels[q] == pixels[p]
                )
            )
    return out


def wrong(images: Sequence[LabelledImage], scores: Iterable[PairScore]) -> list[PairScore]:
    return [s for s in scores if images[s.query].place != images[s.photo].place]


def positive(images: Sequence[LabelledImage], scores: Iterable[PairScore]) -> list[PairScore]:
    """Pairs of one place that are not pixel copies of each other."""
    return [
        s for s in scores if images[s.query].place == images[s.photo].place and not s.same_pixels
    ]


def query_false_matches(
    images: Sequence[LabelledImage], scores: Iterable[PairScore]
) -> dict[int, bool]:
    """Query -> whether it verified any photo of another place (its own place left out)."""
    out = {i: False for i in range(len(images))}
    for s in wrong(images, scores):
        out[s.query] = out[s.query] or s.verified
    return out


def wilson(k: int, n: int, z: float = 1.96) -> tuple[float, float]:
    """Wilson score interval of a proportion k / n (95 % at z = 1.96)."""
    if n == 0:
        return 0.0, 1.0
    p = k / n
    d = 1.0 + z * z / n
    c = (p + z * z / (2 * n)) / d
    h = z * math.sqrt(p * (1.0 - p) / n + z * z / (4 * n * n)) / d
    return max(0.0, c - h), min(1.0, c + h)


@dataclass(frozen=True, slots=True)
class QueryDecision:
    query: int
    matched: str | None
    """The place the recogniser's rule picks (None: nothing verified, or ambiguous)."""
    leave_one_out: bool
    """The query's own place was left out: any match is false."""

    def correct(self, images: Sequence[LabelledImage]) -> bool:
        return not self.leave_one_out and self.matched == images[self.query].place

    def false(self, images: Sequence[LabelledImage]) -> bool:
        return self.matched is not None and (
            self.leave_one_out or self.matched != images[self.query].place
        )


def decide_queries(
    images: Sequence[LabelledImage],
    scores: Iterable[PairScore],
    several: bool,
    ambiguity_ratio: float = 1.5,
) -> list[QueryDecision]:
    """Every image as a query against a database of the places, from the pair scores.

    One photo per place (``several`` False): a place's photo is its first file; its other
    files are queries. Several: every file of a place is a photo of it, except the query
    itself and its pixel copies (never the query's own photo). Each query is decided by the
    recogniser's rule (a place scores its best photo: verified first, then the smallest NFA;
    two verified places within ``ambiguity_ratio`` of each other's inliers: no match), once
    with every place and once with its own place left out.
    """
    first: dict[str, int] = {}
    for i, im in enumerate(images):
        first.setdefault(im.place, i)
    by_query: dict[int, list[PairScore]] = {}
    for s in scores:
        by_query.setdefault(s.query, []).append(s)
    out = []
    for q, im in enumerate(images):
        if not several and first[im.place] == q:
            continue  # this file is its place's photo
        best: dict[str, PairScore] = {}
        for s in by_query.get(q, []):
            if s.same_pixels or (not several and first[images[s.photo].place] != s.photo):
                continue
            place = images[s.photo].place
            b = best.get(place)
            if b is None or (s.verified, -s.log_nfa, s.inliers) > (
                b.verified,
                -b.log_nfa,
                b.inliers,
            ):
                best[place] = s
        if im.place not in best:
            continue  # no photo of its place is left to find (a pixel copy only)
        for loo in (False, True):
            ok = sorted(
                (
                    (s.inliers, p)
                    for p, s in best.items()
                    if s.verified and not (loo and p == im.place)
                ),
                reverse=True,
            )
            pick = None
            if ok and not (len(ok) > 1 and ok[0][0] < ambiguity_ratio * ok[1][0]):
                pick = ok[0][1]
            out.append(QueryDecision(q, pick, loo))
    return out
