"""The whole-database search: the global index kept in the file, ``Recogniser.locate``, and a
lost car's relocalisation (two agreeing frames, a ``relocalised`` fix), on real OpenCV with
simulated facades and their look-alikes."""

from __future__ import annotations

import math
import sqlite3
from pathlib import Path

import numpy as np
import pytest

from guidance.core.messages import CameraFrame, Ellipse, EstimateState, reset_sigma_m
from hal_sim.sim_camera import (
    SimCamera,
    SimCameraConfig,
    SimLandmark,
    build_sim_landmark_db,
    facade,
)
from landmark_db import global_index
from landmark_db.matcher import MAX_LOG10_NFA
from landmark_db.recognise import NO_CANDIDATE, NOT_CONSISTENT, Recogniser, RecogniserConfig
from landmark_db.search import SINGLE_FRAME_DECADES, SearchConfig, bonferroni_decades
from landmark_db.store import open_db

N_PLACES = 24
EASY = SimCameraConfig(
    perspective=0.08, occlusion=(0.0, 0.1), blur_sigma_px=(0.0, 0.8), motion_blur_px=(0.0, 1.0)
)


@pytest.fixture(scope="module")
def city(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[SimLandmark]]:
    """24 places 200 m apart (built photo by photo, as `add` does)."""
    path = tmp_path_factory.mktemp("search") / "city.sqlite"
    xy = np.array([[200.0 * (i % 6), 200.0 * (i // 6)] for i in range(N_PLACES)])
    db, lms = build_sim_landmark_db(path, xy, seed=41)
    db.close()
    return path, lms


def _lost_state(t: float) -> EstimateState:
    """A lost car: its estimate far from every landmark, with a huge covariance."""
    big = 1e8
    c = ((big, 0.0, 0.0), (0.0, big, 0.0), (0.0, 0.0, 3.0))
    return EstimateState(t, 5e4, -5e4, 0.0, c, Ellipse(2e4, 2e4, 0.0, 180.0), True, False)


def test_global_index_is_stored_and_follows_the_file(
    city: tuple[Path, list[SimLandmark]], tmp_path: Path
) -> None:
    """Every photo has a vector from the stored vocabulary; adding photos encodes them and
    rebuilds the vocabulary when the file has doubled."""
    path, _lms = city
    with sqlite3.connect(path) as c:
        voc = global_index.load_vocabulary(c)
        assert voc is not None and voc.photos >= N_PLACES / 2
        ids = {r[0] for r in c.execute("SELECT vocabulary FROM photo_global")}
        n = c.execute("SELECT count(*) FROM photo_global").fetchone()[0]
        assert ids == {voc.ident} and n == N_PLACES
    copy = tmp_path / "copy.sqlite"
    copy.write_bytes(path.read_bytes())
    with open_db(copy, readonly=False) as db:
        lid = db.add("extra", facade(991), x_m=5000.0, y_m=0.0)
        assert len(db.photos(lid)) == 1
    with sqlite3.connect(copy) as c:
        n = c.execute("SELECT count(*) FROM photo_global").fetchone()[0]
        assert n == N_PLACES + 1


def test_locate_finds_places_and_seldom_lookalikes(city: tuple[Path, list[SimLandmark]]) -> None:
    """Every place seen by a gentle camera is located among 24 at the Bonferroni level, never
    as another place; a look-alike of each place (same style and window grid, other details)
    locates another place at most once in 24 single images. (The shortlist picks the most
    similar places, so its wrong pairs are harder than random ones: this seed gives one, a
    look-alike matched to a third place at log10 NFA -14.2 with 9 inliers; the car acts on
    two agreeing frames, below.)"""
    path, lms = city
    rec = Recogniser.from_path(path)
    cam = SimCamera(lms, seed=5, config=EASY)
    rng = np.random.default_rng(9)
    found = wrong = false_lookalike = 0
    for lm in lms:
        d = float(rng.uniform(4.0, 12.0))
        r = rec.locate(cam.view(facade(lm.photo_seed), d))
        assert r.level == pytest.approx(MAX_LOG10_NFA["rootsift"] - math.log10(N_PLACES))
        assert r.shortlist and len(r.shortlist) <= SearchConfig().shortlist
        found += r.landmark_id == lm.id
        wrong += r.landmark_id is not None and r.landmark_id != lm.id
        look = rec.locate(cam.view(facade(lm.photo_seed + 7, family_seed=lm.photo_seed), d))
        false_lookalike += look.landmark_id is not None
    rec.close()
    assert wrong == 0 and false_lookalike <= 1
    assert found >= 0.75 * len(lms), found


@pytest.mark.xfail(
    strict=True,
    reason="issue 36, second round: with RootSIFT 2 (the contrast stretch) the look-alike of "
    "place 3 verifies place 5 in two consecutive frames (log10 NFA -13.6, -13.3; level -10.9) "
    "and relocalises the car. Over 3 seeds x 24 look-alikes x 4 frames, RootSIFT 2 verified a "
    "wrong place in 8 of 288 lost frames (1 relocalisation in 72 passes), RootSIFT 1 in 7 of "
    "288 (0): consecutive frames of one scene are not independent evidence. Open: a rule for "
    "the lost search's confirmation (docs/landmarks.md, 'The whole-database search').",
)
def test_lookalikes_never_relocalise_a_lost_car(city: tuple[Path, list[SimLandmark]]) -> None:
    """A lost car passing a look-alike of each place (4 frames each, 0.5 s apart, other
    views) is never relocalised."""
    path, lms = city
    rec = Recogniser.from_path(path)
    rng = np.random.default_rng(11)
    cam = SimCamera(lms, seed=12, config=EASY)
    fixes = 0
    t = 0.0
    for lm in lms:
        look = facade(lm.photo_seed + 11, family_seed=lm.photo_seed)
        for _k in range(4):
            t += 0.5
            image = cam.view(look, float(rng.uniform(4.0, 12.0)))
            fixes += rec.process(CameraFrame(t, image), _lost_state(t)).fix is not None
        t += 60.0
    rec.close()
    assert fixes == 0


def test_lost_car_relocalises_on_two_agreeing_frames(city: tuple[Path, list[SimLandmark]]) -> None:
    """While lost, the gate is not used (the estimate is 70 km away): two frames of one place
    give one fix, marked relocalised, its sigma the sighting range plus the landmark's
    (``reset_sigma_m``: the reset's ellipse holds every point the place can be seen from)."""
    path, lms = city
    rec = Recogniser.from_path(path)
    cam = SimCamera(lms, seed=6, config=EASY)
    lm = lms[7]
    fixes = []
    for k in range(6):
        t = 10.0 + 0.5 * k
        r = rec.process(cam.frame_at(t, lm.x_m + 6.0, lm.y_m), _lost_state(t))
        if r.fix is not None:
            fixes.append(r.fix)
            if not fixes[1:] and k == 0:  # one frame alone: only far past the level
                best = min(e.log_nfa for e in r.evidence if e.landmark_id == lm.id)
                assert best <= r.level - SINGLE_FRAME_DECADES
        elif k == 0:
            assert r.reason in (NOT_CONSISTENT, "failed_geometry", "few_matches")
    assert len(fixes) == 1, fixes
    f = fixes[0]
    want = reset_sigma_m(rec.config.sighting_range_m, 0.0)  # the city's places are exact
    assert f.relocalised and f.landmark_id == lm.id and f.sigma_m == pytest.approx(want)
    s = rec.stats()
    assert s["relocalisations"] == 1 and s["fixes"] == 1 and s["searched"] == 6
    # not lost: the same frames go through the gate, which (70 km away) holds nothing
    r = rec.process(cam.frame_at(60.0, lm.x_m + 6.0, lm.y_m), _lost_state(60.0).__class__(
        60.0, 5e4, -5e4, 0.0, ((100.0, 0, 0), (0, 100.0, 0), (0, 0, 0.1)),
        Ellipse(20.0, 20.0, 0.0, 5.0), False, True))  # fmt: skip
    assert r.reason == NO_CANDIDATE
    rec.close()


def test_one_frame_far_past_the_level_is_enough(city: tuple[Path, list[SimLandmark]]) -> None:
    """With no extra margin a single verified frame relocalises; with an unreachable margin
    it never does on one frame."""
    path, lms = city
    lm = lms[3]
    for decades, want_first in ((0.0, True), (math.inf, False)):
        cfg = RecogniserConfig(search=SearchConfig(single_frame_decades=decades))
        rec = Recogniser.from_path(path, cfg)
        cam = SimCamera(lms, seed=8, config=EASY)
        r = None
        for k in range(4):
            r = rec.process(cam.frame_at(float(k), lm.x_m, lm.y_m + 5.0), _lost_state(float(k)))
            if r.landmark_id == lm.id:
                break
        assert r is not None and r.landmark_id == lm.id
        assert (r.fix is not None) is want_first
        rec.close()


def test_bonferroni_decades() -> None:
    assert bonferroni_decades(1) == 0.0
    assert bonferroni_decades(300) == pytest.approx(2.477, abs=1e-3)
    assert bonferroni_decades(10_000) == pytest.approx(4.0)


def test_frame_errors_while_lost(city: tuple[Path, list[SimLandmark]]) -> None:
    path, _lms = city
    rec = Recogniser.from_path(path)
    bad = CameraFrame(1.0, np.zeros((0, 0), np.uint8))
    assert rec.process(bad, _lost_state(1.0)).reason == "bad_input"
    tiny = CameraFrame(1.0, np.zeros((20, 20), np.uint8))
    assert rec.process(tiny, _lost_state(1.0)).reason == "too_small"
    rec.close()


def test_locate_command(
    city: tuple[Path, list[SimLandmark]], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """`landmark-db locate DB IMAGE... --json`: one object per image with image, landmark
    (name or null), id; a damaged image is its own error record and the exit status is 2."""
    import json

    import cv2

    from landmark_db.cli import main

    path, lms = city
    cam = SimCamera(lms, seed=21, config=EASY)
    seen, other, broken = tmp_path / "seen.png", tmp_path / "other.png", tmp_path / "cut.png"
    cv2.imwrite(str(seen), cam.view(facade(lms[4].photo_seed), 6.0))
    # a real photo of something else (the false-locate rate is the population tests' and the
    # benchmark's business; a sharp unrelated facade does verify now and then: docs)
    other.write_bytes((Path(__file__).parents[1] / "data" / "images" / "box.png").read_bytes())
    broken.write_bytes(seen.read_bytes()[:500])
    assert main(["locate", str(path), str(seen), str(other), "--json"]) == 0
    recs = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert [r["image"] for r in recs] == [str(seen), str(other)]
    assert recs[0]["id"] == lms[4].id and recs[0]["landmark"] == "sim-00004"
    assert recs[1]["id"] is None and recs[1]["landmark"] is None and recs[1]["evidence"]
    assert main(["locate", str(path), str(seen), str(broken), "--json"]) == 2
    recs = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert recs[0]["id"] == lms[4].id and "error" in recs[1]
    assert main(["locate", str(path), str(seen)]) == 0
    assert capsys.readouterr().out.startswith(f"{seen}: landmark {lms[4].id} (sim-00004)")
