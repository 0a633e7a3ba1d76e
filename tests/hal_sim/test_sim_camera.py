"""Simulated camera: distinct seeded photos, a real database, and the real matcher's figures."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from guidance.core.messages import CameraFrame
from hal_sim.sim_camera import (
    SimCamera,
    SimCameraConfig,
    build_sim_landmark_db,
    facade,
    measure_detection,
    sim_landmarks_from_db,
)
from landmark_db.store import open_db


def test_photos_are_deterministic_and_distinct() -> None:
    a, b = facade(1), facade(1)
    assert a.shape == (480, 640, 3) and a.dtype == np.uint8
    assert np.array_equal(a, b)
    assert np.mean(np.abs(facade(2).astype(int) - a.astype(int))) > 10
    kin = facade(2, family_seed=1)
    assert not np.array_equal(kin, a)


def test_synthetic_database_for_a_city(tmp_path: Path) -> None:
    xy = np.array([[0.0, 0.0], [120.0, -40.0], [500.0, 800.0]])
    db, lms = build_sim_landmark_db(tmp_path / "c.sqlite", xy, seed=3)
    db.close()
    with open_db(tmp_path / "c.sqlite") as ro:
        assert ro.check().ok and len(ro) == 3
        assert sim_landmarks_from_db(ro) == lms
        for lm, (x, y) in zip(ro.landmarks(), xy, strict=True):
            assert (lm.x_m, lm.y_m) == pytest.approx((x, y), abs=1e-6)
            assert lm.position_sigma_m == 0.0
    assert len({lm.photo_seed for lm in lms}) == 3
    # another city seed gives other photos
    _, other = build_sim_landmark_db(tmp_path / "d.sqlite", xy, seed=4)
    assert {lm.photo_seed for lm in other}.isdisjoint({lm.photo_seed for lm in lms})


def test_frames_show_the_landmark_in_range_and_other_scenes_elsewhere(tmp_path: Path) -> None:
    xy = np.array([[0.0, 0.0], [300.0, 0.0]])
    db, lms = build_sim_landmark_db(tmp_path / "c.sqlite", xy, seed=5)
    db.close()
    cam = SimCamera(lms, seed=1, config=SimCameraConfig(lookalike_prob=0.5))
    f = cam.frame_at(1.0, 10.0, 5.0)
    assert isinstance(f, CameraFrame) and f.t_s == 1.0
    assert f.image.shape == (480, 640, 3)  # type: ignore[attr-defined]
    assert cam.last_truth == ("landmark", lms[0].id)
    kinds = []
    for k in range(40):
        cam.frame_at(2.0 + k, 150.0, 0.0)
        kinds.append(cam.last_truth[0])
    assert 5 < kinds.count("lookalike") < 35 and "scene" in kinds
    s = cam.stats()
    assert s["frames"] == 41 and s["landmark"] == 1


def test_detection_rate_comes_from_the_real_matcher(tmp_path: Path) -> None:
    """A reduced run of ``python -m hal_sim.sim_camera`` (200 passes: 0.755 confirmed)."""
    figs = measure_detection(n_sightings=20, n_landmarks=6, seed=2, workdir=tmp_path)
    assert 0.4 <= figs["confirmed_rate"] <= 1.0
    assert 0.4 <= figs["frame_verify_rate"] < 1.0  # the perturbations do cost detections
    assert figs["false_fixes"] == 0 and figs["lookalike_verified_frames"] == 0
