"""Recognition on the real pipeline: gate, ORB + ratio test, RANSAC, temporal confirmation."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from recognise_helpers import EASY, state_at

from guidance.app.ports import NullRecogniser
from guidance.app.ports import Recogniser as RecogniserPort
from guidance.core.localize.estimator import PoseEstimator
from guidance.core.messages import CameraFrame, WheelOdometry
from hal_sim.sim_camera import SimCamera, SimCameraConfig, SimLandmark
from landmark_db.recognise import (
    AMBIGUOUS,
    BAD_INPUT,
    FAILED_GEOMETRY,
    FEW_MATCHES,
    NO_CANDIDATE,
    NOT_CONSISTENT,
    REPEAT,
    Recogniser,
    RecogniserConfig,
    fix_sigma_m,
)
from landmark_db.store import LandmarkDb


@pytest.fixture
def lms(sim_db_path: tuple[Path, list[SimLandmark]]) -> list[SimLandmark]:
    return sim_db_path[1]


def test_protocols_are_implemented(sim_db: LandmarkDb) -> None:
    assert isinstance(Recogniser(sim_db), RecogniserPort)
    assert isinstance(NullRecogniser(), RecogniserPort)


def test_confirmed_over_two_frames_then_one_fix_per_pass(
    sim_db: LandmarkDb, lms: list[SimLandmark]
) -> None:
    cam = SimCamera(lms, seed=3, config=EASY)
    rec = Recogniser(sim_db)
    lm = lms[2]
    x, y = lm.x_m + 8.0, lm.y_m - 5.0
    r1 = rec.process(cam.frame_at(10.0, x, y), state_at(x, y))
    assert r1.reason == NOT_CONSISTENT and r1.landmark_id == lm.id and r1.fix is None
    r2 = rec.process(cam.frame_at(10.5, x, y), state_at(x, y))
    assert r2.fix is not None and r2.reason is None
    assert r2.fix.landmark_id == lm.id
    assert (r2.fix.x_m, r2.fix.y_m) == pytest.approx((lm.x_m, lm.y_m), abs=0.01)
    assert r2.fix.sigma_m == pytest.approx(10.0)  # exact sim positions: range / 2
    assert r2.fix.t_s == 10.5
    ev = {e.landmark_id: e for e in r2.evidence}
    assert ev[lm.id].verified and ev[lm.id].inliers >= 12
    r3 = rec.process(cam.frame_at(11.0, x, y), state_at(x, y))
    assert r3.reason == REPEAT and r3.fix is None
    s = rec.stats()
    assert s["frames"] == 3 and s["fixes"] == 1 and s[NOT_CONSISTENT] == 1 and s[REPEAT] == 1


def test_streak_breaks_on_a_gap_or_a_failed_frame(
    sim_db: LandmarkDb, lms: list[SimLandmark]
) -> None:
    cam = SimCamera(lms, seed=4, config=EASY)
    rec = Recogniser(sim_db, RecogniserConfig(confirm_frames=2, confirm_window_s=2.0))
    lm = lms[0]
    st = state_at(lm.x_m, lm.y_m)
    assert rec.process(cam.frame_at(0.0, lm.x_m, lm.y_m), st).reason == NOT_CONSISTENT
    # too late: a new streak
    assert rec.process(cam.frame_at(5.0, lm.x_m, lm.y_m), st).reason == NOT_CONSISTENT
    blank = CameraFrame(5.5, np.full((480, 640, 3), 128, np.uint8))
    assert rec.process(blank, st).reason == FEW_MATCHES
    assert rec.process(cam.frame_at(6.0, lm.x_m, lm.y_m), st).reason == NOT_CONSISTENT
    assert rec.process(cam.frame_at(6.5, lm.x_m, lm.y_m), st).fix is not None


def test_no_candidate_means_no_image_work(sim_db: LandmarkDb, lms: list[SimLandmark]) -> None:
    cam = SimCamera(lms, seed=5, config=EASY)
    rec = Recogniser(sim_db)
    lm = lms[1]
    # The camera sees the landmark, but the estimate is 200 m off with a 30 m ellipse.
    r = rec.process(cam.frame_at(1.0, lm.x_m, lm.y_m), state_at(lm.x_m - 200.0, lm.y_m))
    assert r.reason == NO_CANDIDATE and r.frame_features == 0 and not r.evidence
    # A large ellipse reaches it: then it is compared.
    big = ((150.0**2, 0.0), (0.0, 20.0**2))
    r = rec.process(cam.frame_at(1.5, lm.x_m, lm.y_m), state_at(lm.x_m - 200.0, lm.y_m, big))
    assert lm.id in [c.id for c in r.candidates] and r.landmark_id == lm.id


def test_lookalikes_and_other_scenes_are_rejected(
    sim_db: LandmarkDb, lms: list[SimLandmark]
) -> None:
    cfg = SimCameraConfig(lookalike_prob=1.0)
    cam = SimCamera(lms, seed=6, config=cfg)
    rec = Recogniser(sim_db, RecogniserConfig(confirm_frames=1))
    reasons = []
    for k, lm in enumerate(lms * 4):
        # The car is out of sight of lm; the estimate says it is at lm; the camera sees kin.
        frame = cam.frame_at(float(k), lm.x_m + 70.0, lm.y_m)
        assert cam.last_truth == ("lookalike", lm.id)
        r = rec.process(frame, state_at(lm.x_m, lm.y_m))
        assert r.fix is None and r.landmark_id is None
        reasons.append(r.reason)
    assert set(reasons) <= {FEW_MATCHES, FAILED_GEOMETRY, AMBIGUOUS}


def test_bad_inputs_are_counted_not_raised(sim_db: LandmarkDb, lms: list[SimLandmark]) -> None:
    rec = Recogniser(sim_db)
    lm = lms[0]
    ok = np.zeros((100, 100, 3), np.uint8)
    for frame, state in [
        (CameraFrame(0.0, None), state_at(lm.x_m, lm.y_m)),
        (CameraFrame(0.0, np.zeros((0, 0), np.uint8)), state_at(lm.x_m, lm.y_m)),
        (CameraFrame(0.0, np.zeros((50, 50), np.float32)), state_at(lm.x_m, lm.y_m)),
        (CameraFrame(0.0, ok), state_at(math.nan, 0.0)),
        (CameraFrame(0.0, ok), state_at(lm.x_m, lm.y_m, ((math.inf, 0.0), (0.0, 1.0)))),
        (CameraFrame(0.0, ok), state_at(lm.x_m, lm.y_m, ((-5.0, 0.0), (0.0, 1.0)))),
    ]:
        assert rec.process(frame, state).reason == BAD_INPUT
    assert rec.stats()[BAD_INPUT] == 6


def test_fix_is_accepted_by_the_real_estimator(sim_db: LandmarkDb, lms: list[SimLandmark]) -> None:
    """End to end: drive east 300 m on odometry only, see landmark 1, the ellipse shrinks."""
    lm = lms[1]  # at (300, 0)
    est = PoseEstimator(x_m=0.0, y_m=0.0, heading_rad=0.0)
    for k in range(300):
        est.process(WheelOdometry(0.1 * (k + 1), 1.0, 1.0))
    before = est.state()
    cam = SimCamera(lms, seed=8, config=EASY)
    rec = Recogniser(sim_db)
    fix = None
    for k in range(4):
        t = 30.1 + 0.5 * k
        res = rec.process(cam.frame_at(t, lm.x_m - 6.0, lm.y_m + 2.0), est.state())
        fix = fix or res.fix
    assert fix is not None and fix.landmark_id == lm.id
    step = est.process(fix)
    assert step.accepted
    assert est.state().ellipse.major_axis_m < before.ellipse.major_axis_m
    assert est.state().ellipse.major_axis_m <= 4.0 * fix.sigma_m + 1e-6


def test_fix_sigma_documented_value() -> None:
    assert fix_sigma_m(20.0, 0.0) == 10.0
    assert fix_sigma_m(20.0, 3.0) == pytest.approx(math.hypot(10.0, 3.0))


def test_null_recogniser() -> None:
    n = NullRecogniser()
    assert n.process(CameraFrame(0.0, None), state_at(0.0, 0.0)).fix is None
    assert n.process(CameraFrame(1.0, None), state_at(0.0, 0.0)).reason == NO_CANDIDATE
    assert n.stats()["frames"] == 2 and n.stats()["fixes"] == 0
