"""The contrast stretch before RootSIFT (issue 36): dark frames keep their keypoints."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import landmark_db.features as features
from landmark_db.features import (
    STRETCH_MIN_SPAN,
    ExtractorConfig,
    decode_image,
    extract,
    stretch_contrast,
)
from landmark_db.matcher import PairMatcher, PhotoIndex
from landmark_db.recognise import FRAME_FEATURES
from landmark_db.wrong_pairs import degrade

DATA = Path(__file__).resolve().parents[1] / "data" / "images"


def test_the_stretch_maps_the_tails_to_the_full_range_linearly() -> None:
    rng = np.random.default_rng(3)
    dark = rng.integers(10, 60, (240, 320)).astype(np.uint8)
    out = stretch_contrast(dark)
    assert np.percentile(out, 1) <= 3 and np.percentile(out, 99) >= 252
    # linear and order-preserving: one grey level in, one out, in the same order
    levels = np.unique(dark)
    mapped = np.array([out[dark == v][0] for v in levels])
    assert np.all(np.diff(mapped.astype(int)) >= 0)
    inner = (levels > 12) & (levels < 57)
    steps = np.diff(mapped[inner].astype(int))
    assert steps.min() >= 4 and steps.max() <= 6  # about 255 / 50 each


def test_a_few_grey_levels_are_not_blown_up_into_a_picture() -> None:
    """At most 255 / STRETCH_MIN_SPAN of gain: four levels of noise stay four faint levels."""
    rng = np.random.default_rng(4)
    faint = (100 + rng.integers(0, 4, (64, 64))).astype(np.uint8)
    out = stretch_contrast(faint)
    assert int(out.max()) - int(out.min()) <= 3 * 255 // STRETCH_MIN_SPAN + 1
    flat = np.full((64, 64), 7, np.uint8)
    assert np.unique(stretch_contrast(flat)).size == 1
    full = np.tile(np.arange(256, dtype=np.uint8), (4, 1))
    assert np.abs(stretch_contrast(full).astype(int) - full).max() <= 3


def test_rootsift_is_version_2_and_stretched() -> None:
    assert ExtractorConfig().ident == "rootsift/2:1000@640"
    assert "rootsift" in features.STRETCHED_KINDS


@pytest.mark.parametrize("stops", [3, 5, 6])
def test_a_real_frame_underexposed_still_verifies(stops: int) -> None:
    """The OpenCV box scene underexposed by 3-6 stops (``wrong_pairs.degrade``: linear light,
    sensor noise) verifies against the box photo by the shipped rule, with most of its
    keypoints; that is the stretch's doing (below)."""
    photo = decode_image((DATA / "box.png").read_bytes())
    scene = decode_image((DATA / "box_in_scene.png").read_bytes())
    ext = ExtractorConfig()
    index = PhotoIndex(1, extract(photo, ext))
    for seed in range(2):
        f = extract(degrade(scene, f"dark{stops}", seed), ext.for_frames(FRAME_FEATURES))
        e = PairMatcher().verify(1, f, f.for_matching(), index)
        assert len(f) >= 0.9 * FRAME_FEATURES and e.verified, (seed, len(f), e)


def test_without_the_stretch_a_frame_five_stops_under_loses_its_keypoints(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Why the stretch: SIFT's contrast threshold is absolute, so the same dark frame without
    it keeps about a tenth of its keypoints and verifies nothing."""
    monkeypatch.setattr(features, "STRETCHED_KINDS", frozenset())
    photo = decode_image((DATA / "box.png").read_bytes())
    scene = decode_image((DATA / "box_in_scene.png").read_bytes())
    ext = ExtractorConfig()
    index = PhotoIndex(1, extract(photo, ext))
    for seed in range(2):
        f = extract(degrade(scene, "dark5", seed), ext.for_frames(FRAME_FEATURES))
        e = PairMatcher().verify(1, f, f.for_matching(), index)
        assert len(f) < 0.2 * FRAME_FEATURES and not e.verified, (seed, len(f), e)
