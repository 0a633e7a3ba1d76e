"""Several photos per landmark, the extractor, the inliers' plausibility and damaged images."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from guidance.core.geo import Origin
from hal_sim.sim_camera import SimCamera, SimCameraConfig, facade
from landmark_db.features import ExtractorConfig, decode_image, encode_image
from landmark_db.matcher import plausible_homography
from landmark_db.recognise import AMBIGUOUS, Recogniser, RecogniserConfig
from landmark_db.store import LandmarkDb, LandmarkDbError, create_db

ORIGIN = Origin(42.444, -76.5019)
CAM = SimCameraConfig(occlusion=(0.0, 0.1))


def _view(seed: int, cam_seed: int = 1, distance_m: float = 6.0) -> np.ndarray:
    return SimCamera([], seed=cam_seed, config=CAM).view(facade(seed), distance_m)


@pytest.fixture
def two_places(tmp_path: Path) -> LandmarkDb:
    """Landmark 1 with two photos of two sides of a place (facades 11 and 12); landmark 2
    with one (facade 13)."""
    db = create_db(tmp_path / "p.sqlite", ORIGIN)
    a = db.add("corner", facade(11), x_m=0.0, y_m=0.0)
    db.add_photo(a, facade(12), facing_deg=180.0, conditions="from the south")
    db.add("church", facade(13), x_m=5.0, y_m=0.0)
    return db


def test_every_photo_of_a_landmark_is_matched_as_that_place(two_places: LandmarkDb) -> None:
    db = two_places
    assert [p.id for p in db.photos(1)] == [1, 2] and db.photo_counts() == {1: 2, 2: 1}
    assert db.photos(1)[1].facing_deg == 180.0 and db.photos(1)[1].conditions == "from the south"
    rec = Recogniser(db)
    res = rec.match_image(_view(12))  # the second photo's side
    assert res.reason is None and res.landmark_id == 1
    ev = {e.landmark_id: e for e in res.evidence}
    assert ev[1].photo_id == 2 and ev[1].verified and not ev[2].verified
    assert rec.match_image(_view(11)).landmark_id == 1
    assert rec.match_image(_view(13)).landmark_id == 2
    assert db.check().ok


def test_photos_of_one_place_are_never_ambiguous(tmp_path: Path) -> None:
    db = create_db(tmp_path / "p.sqlite", ORIGIN)
    lid = db.add("twice", facade(21), x_m=0.0, y_m=0.0)
    db.add_photo(lid, _view(21, cam_seed=5, distance_m=3.0))  # the same facade again
    db.add("other", facade(22), x_m=3.0, y_m=0.0)
    rec = Recogniser(db)
    res = rec.match_image(_view(21))
    assert res.reason is None and res.landmark_id == lid  # one place, not AMBIGUOUS
    # two different landmarks that both verify with similar scores are still ambiguous
    db.add("copy", facade(21), x_m=6.0, y_m=0.0)
    assert Recogniser(db).match_image(_view(21)).reason == AMBIGUOUS


def test_the_photo_budget_reaches_every_candidate_first(tmp_path: Path) -> None:
    db = create_db(tmp_path / "p.sqlite", ORIGIN)
    for i in range(3):
        lid = db.add(f"l{i}", facade(30 + i), x_m=float(i), y_m=0.0)
        for k in range(2):
            db.add_photo(lid, _view(30 + i, cam_seed=k))
    rec = Recogniser(db, RecogniserConfig(max_photos=3))
    from guidance.core.messages import CameraFrame

    res = rec.process_xy(CameraFrame(0.0, _view(32)), (1.0, 0.0), ((1.0, 0.0), (0.0, 1.0)))
    # 3 photos: the first photo of each of the 3 candidates (not 3 photos of the nearest)
    assert sorted(e.landmark_id for e in res.evidence) == [1, 2, 3]
    assert res.landmark_id == 3


def test_add_photo_to_a_missing_landmark_or_read_only_file_fails(two_places: LandmarkDb) -> None:
    with pytest.raises(LandmarkDbError, match="no landmark 9"):
        two_places.add_photo(9, facade(1))
    two_places.close()
    from landmark_db.store import open_db

    with open_db(two_places.path) as ro, pytest.raises(LandmarkDbError, match="read-only"):
        ro.add_photo(1, facade(1))


def test_plausibility_is_judged_on_the_inliers_region() -> None:
    # A strong perspective: photo points beyond x = 500 px map behind the camera (w <= 0).
    H = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [-0.002, 0.0, 1.0]])
    inliers = np.array([[10.0, 10.0], [300.0, 20.0], [280.0, 400.0], [20.0, 380.0]])
    assert plausible_homography(H, inliers) is not None  # the matched facade, in front
    wide = np.vstack([inliers, [[640.0, 470.0]]])
    assert plausible_homography(H, wide) is None  # the whole photo's outline is rejected
    mirror = np.diag([-1.0, 1.0, 1.0])
    assert plausible_homography(mirror, inliers) is None
    line = np.array([[0.0, 5.0], [10.0, 5.0], [20.0, 5.0], [30.0, 5.0]])
    assert plausible_homography(np.eye(3), line) is None  # collinear inliers see no plane


def test_extractor_identity_round_trips_and_is_stored() -> None:
    ext = ExtractorConfig("rootsift", 800, 512)
    assert ext.ident == "rootsift/2:800@512" and ExtractorConfig.parse(ext.ident) == ext
    with pytest.raises(ValueError):
        ExtractorConfig.parse("surf/1:1000@640")
    with pytest.raises(ValueError):
        ExtractorConfig.parse("rootsift")
    assert ExtractorConfig().for_frames(600).max_side_px < ExtractorConfig().max_side_px


def test_truncated_photos_are_refused_in_one_line(tmp_path: Path) -> None:
    jpeg = encode_image(facade(3), ".jpg")
    png = encode_image(facade(3), ".png")
    assert decode_image(jpeg).shape == (480, 640, 3)
    for cut in (jpeg[: len(jpeg) // 2], png[: len(png) // 2]):
        with pytest.raises(ValueError, match="damaged image: truncated"):
            decode_image(cut)
    db = create_db(tmp_path / "d.sqlite", ORIGIN)
    with pytest.raises(LandmarkDbError, match="truncated JPEG") as exc:
        db.add("half", jpeg[: len(jpeg) // 2], x_m=0.0, y_m=0.0)
    assert "\n" not in str(exc.value) and len(db) == 0
