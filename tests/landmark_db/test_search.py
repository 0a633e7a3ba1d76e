"""The whole-database search: the global index kept in the file, ``Recogniser.locate``, and a
lost car's relocalisation (one frame past the scene level, a ``relocalised`` fix), on real
OpenCV with simulated facades and their look-alikes."""

from __future__ import annotations

import math
import sqlite3
from pathlib import Path

import numpy as np
import pytest
from recognise_helpers import EASY

from guidance.core.messages import CameraFrame, Ellipse, EstimateState, reset_sigma_m
from hal_sim.sim_camera import (
    SimCamera,
    SimLandmark,
    build_sim_landmark_db,
    facade,
)
from landmark_db import global_index
from landmark_db.matcher import MAX_LOG10_NFA
from landmark_db.recognise import NO_CANDIDATE, NOT_CONSISTENT, Recogniser, RecogniserConfig
from landmark_db.search import (
    SCENE_DECADES,
    SearchConfig,
    bonferroni_decades,
    scene_decades,
)
from landmark_db.store import open_db

N_PLACES = 24


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
    look-alike matched to a third place at log10 NFA -14.2 with 9 inliers; a lost car acts
    only past the scene level, below.)"""
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


LOOKALIKE_SEEDS = (11, 43)
"""11: the seed whose look-alike of place 3 verified place 5 in two consecutive frames (log10
NFA -13.6, -13.3 at a level of -10.9) and relocalised the car under the rule before; it was
among the seeds the margin was chosen on (11, 21, 31). 43 was not."""


def _lookalike_passes(
    path: Path, lms: list[SimLandmark], config: RecogniserConfig | None, seeds: tuple[int, ...]
) -> tuple[int, int, int]:
    """A lost car passing a look-alike of every place, once per seed (4 frames 0.5 s apart,
    4-12 m, other views; the frames of ``benchmarks/search_lookalikes.py``): (passes, passes
    relocalised, frames that verified a wrong place)."""
    n = relocalised = verified = 0
    for seed in seeds:
        rec = Recogniser.from_path(path, config)
        rng = np.random.default_rng(seed)
        cam = SimCamera(lms, seed=seed + 1, config=EASY)
        t = 0.0
        for lm in lms:
            look = facade(lm.photo_seed + seed, family_seed=lm.photo_seed)
            fixes = 0
            for _k in range(4):
                t += 0.5
                r = rec.process(CameraFrame(t, cam.view(look, float(rng.uniform(4.0, 12.0)))),
                                _lost_state(t))  # fmt: skip
                fixes += r.fix is not None
                verified += r.landmark_id is not None
            n += 1
            relocalised += fixes > 0
            t += 60.0
        rec.close()
    return n, relocalised, verified


def test_lookalikes_never_relocalise_a_lost_car(city: tuple[Path, list[SimLandmark]]) -> None:
    """A lost car passing a look-alike of each place, over two seeds (48 passes, 192 frames,
    several of which verify a wrong place), is never relocalised; the rule before (two
    agreeing frames at the search level) was, on seed 11's frames: the population tells the
    two rules apart."""
    path, lms = city
    n, relocalised, verified = _lookalike_passes(path, lms, None, LOOKALIKE_SEEDS)
    assert n == 2 * N_PLACES and verified >= 2 and relocalised == 0, (relocalised, verified)
    before = RecogniserConfig(search=SearchConfig(scene_decades=12.5, pair_at_level=True))
    _n, relocalised_before, _v = _lookalike_passes(path, lms, before, (11,))
    assert relocalised_before >= 1


def test_scene_margin_follows_the_measured_tail() -> None:
    """17 decades for RootSIFT, 46.5 for XFeat: 4 frames a pass at each look-alike tail's
    lower-bound rate keep a pass under 1e-3 false (landmark_db.search's docstring)."""
    assert SCENE_DECADES == 17.0 == scene_decades("rootsift") == scene_decades("orb")
    assert scene_decades("xfeat") == 46.5


def test_lost_car_relocalises_on_one_frame_past_the_scene_level(
    city: tuple[Path, list[SimLandmark]],
) -> None:
    """While lost, the gate is not used (the estimate is 70 km away): the first frame that
    verifies the place past the scene level gives one fix (the next frames are repeats),
    marked relocalised, its sigma the sighting range plus the landmark's (``reset_sigma_m``:
    the reset's ellipse holds every point the place can be seen from)."""
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
            best = min(e.log_nfa for e in r.evidence if e.landmark_id == lm.id)
            assert best <= r.level - SCENE_DECADES
        elif r.landmark_id == lm.id:  # before: not past the scene level; after: repeats
            assert r.reason in ({"repeat", NOT_CONSISTENT} if fixes else {NOT_CONSISTENT})
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


def test_the_scene_margin_decides(city: tuple[Path, list[SimLandmark]]) -> None:
    """With no margin a single frame verified at the search level relocalises; with an
    unreachable one no frame does, however many agree."""
    path, lms = city
    lm = lms[3]
    for decades, want_first in ((0.0, True), (math.inf, False)):
        cfg = RecogniserConfig(search=SearchConfig(scene_decades=decades))
        rec = Recogniser.from_path(path, cfg)
        cam = SimCamera(lms, seed=8, config=EASY)
        got = []
        for k in range(4):
            r = rec.process(cam.frame_at(float(k), lm.x_m, lm.y_m + 5.0), _lost_state(float(k)))
            got.append((r.landmark_id, r.fix is not None))
        verified = [k for k, (lid, _f) in enumerate(got) if lid == lm.id]
        assert len(verified) >= 2, got
        assert got[verified[0]][1] is want_first
        assert any(f for _l, f in got) is want_first
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
