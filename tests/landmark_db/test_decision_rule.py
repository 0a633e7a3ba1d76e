"""The pairwise decision rule and the defects of issue 22: a homography's sign, deterministic
matching, ``add --to`` verification, several acceptable landmarks in a truth CSV, and the
messages for images too small or too large."""

from __future__ import annotations

import math
import struct
import zlib
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest

from guidance.core.geo import Origin
from hal_sim.sim_camera import SimCamera, SimCameraConfig, facade
from landmark_db import matcher
from landmark_db.acceptance import evaluate_db, read_truth
from landmark_db.cli import main
from landmark_db.features import ExtractorConfig, extract
from landmark_db.limits import photo_problem
from landmark_db.matcher import (
    MatchConfig,
    PairMatcher,
    PhotoIndex,
    log10_nfa,
    plausible_homography,
)
from landmark_db.recognise import TOO_SMALL, Recogniser
from landmark_db.store import create_db, open_db

EXT = ExtractorConfig()
FRAME_EXT = EXT.for_frames(600)


def _view(seed: int, cam_seed: int = 1, distance_m: float = 6.0) -> np.ndarray:
    cam = SimCamera([], seed=cam_seed, config=SimCameraConfig(motion_blur_px=(0.0, 0.0)))
    return cam.view(facade(seed), distance_m)


def run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    cap = capsys.readouterr()
    return code, cap.out, cap.err


# --- the homography's sign -------------------------------------------------------------------


def test_a_homography_with_a_negative_overall_sign_is_the_same_view() -> None:
    pts = np.array([[10.0, 10.0], [200.0, 20.0], [190.0, 150.0], [20.0, 160.0]])
    H = np.array([[0.9, 0.05, 12.0], [-0.03, 1.1, 5.0], [1e-4, 2e-4, 1.0]])
    good = plausible_homography(H, pts)
    assert good is not None
    flipped = plausible_homography(-3.0 * H, pts)  # every corner maps with w < 0
    assert flipped is not None
    np.testing.assert_allclose(flipped / flipped[2, 2], good / good[2, 2])
    # mixed signs: the box crosses the horizon (a folded, impossible view)
    fold = H.copy()
    fold[2, :2] = (-0.01, 0.0)  # w = 1 - 0.01 x: positive at x = 10, negative at x = 200
    assert plausible_homography(fold, pts) is None
    mirror = np.diag([-1.0, 1.0, 1.0]) @ H
    assert plausible_homography(mirror, pts) is None
    assert plausible_homography(-mirror, pts) is None


def test_a_pair_whose_homography_comes_back_negated_still_verifies(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    photo = PhotoIndex(1, extract(facade(31), EXT))
    frame = extract(_view(31), FRAME_EXT)
    m = PairMatcher()
    plain = m.verify(1, frame, frame.for_matching(), photo)
    assert plain.verified and plain.inliers >= 20
    real = cv2.findHomography

    def negated(*args: Any, **kwargs: Any) -> Any:
        H, mask = real(*args, **kwargs)
        return -H, mask

    monkeypatch.setattr(matcher.cv2, "findHomography", negated)
    neg = m.verify(1, frame, frame.for_matching(), photo)
    assert neg.verified
    assert (neg.inliers, neg.good_matches) == (plain.inliers, plain.good_matches)
    assert neg.log_nfa == pytest.approx(plain.log_nfa)


# --- the a-contrario score -------------------------------------------------------------------


def test_nfa_counts_chance_fits_as_meaningless_and_exact_fits_as_meaningful() -> None:
    rng = np.random.default_rng(5)
    pts = rng.uniform(0.0, 400.0, (60, 2))
    # 60 putative matches, 30 of them within half a pixel of the model: decisive
    res = np.concatenate([rng.uniform(0.0, 0.5, 30), rng.uniform(20.0, 300.0, 30)])
    lnfa, k = log10_nfa(res, pts)
    assert lnfa < -30 and 26 <= k <= 30  # k on nfa_k_grid
    # residuals of points spread uniformly (the null): nothing meaningful
    chance = np.hypot(*rng.uniform(-200.0, 200.0, (2, 60)))
    assert log10_nfa(chance, pts)[0] > 0.0
    # a cluster on one small patch counts for little, however well it fits
    patch = rng.uniform(0.0, 6.0, (60, 2))
    assert log10_nfa(res, patch)[0] > log10_nfa(res, pts)[0] + 20
    assert log10_nfa(res[:4], pts[:4]) == (math.inf, 0)


# --- determinism -----------------------------------------------------------------------------


def test_a_pairs_score_does_not_depend_on_what_the_process_did_before(tmp_path: Path) -> None:
    db = create_db(tmp_path / "m.sqlite", Origin(0.0, 0.0))
    ids = [db.add(f"f{s}", facade(s), x_m=100.0 * i, y_m=0.0) for i, s in enumerate((11, 12, 13))]
    query = _view(12, cam_seed=4, distance_m=14.0)
    runs = []
    for rng_state, order in ((1, ids), (2, ids[::-1]), (3, ids[1:] + ids[:1])):
        cv2.setRNGSeed(rng_state)
        cv2.randu(np.zeros(100), 0.0, 1.0)  # other work drew from OpenCV's random state
        rec = Recogniser(db)
        rec.match_image(_view(13, cam_seed=9), [ids[2]])  # something else matched first
        res = rec.match_image(query, order)
        runs.append({e.landmark_id: (e.good_matches, e.inliers, e.log_nfa) for e in res.evidence})
    assert runs[0] == runs[1] == runs[2]
    db.close()


def test_photo_index_trees_are_seeded() -> None:
    feats = extract(facade(21), EXT)
    frame = extract(_view(21), FRAME_EXT)
    out = []
    for state in (1, 2):
        cv2.setRNGSeed(state)
        idx = PhotoIndex(1, feats, checks=8, trees=4)
        out.append([(p[0].trainIdx, p[1].trainIdx) for p in idx.knn(frame.for_matching(), None)])
    assert out[0] == out[1]


# --- add --to ---------------------------------------------------------------------------------


def test_add_to_refuses_a_photo_that_does_not_match_the_landmark(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    db = str(tmp_path / "m.sqlite")
    assert run(capsys, "init", db, "--origin", "0", "0")[0] == 0
    for name, img in (("hall.png", facade(43)), ("view.png", _view(43)), ("other.png", _view(44))):
        cv2.imwrite(str(tmp_path / name), img)
    assert run(capsys, "add", db, str(tmp_path / "hall.png"), "--xy", "0", "0")[0] == 0
    code, _, err = run(capsys, "add", db, str(tmp_path / "other.png"), "--to", "hall")
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1
    assert "does not match the photos of landmark 1 (hall)" in lines[0]
    assert "log10 NFA" in lines[0] and "inliers" in lines[0]
    with open_db(db) as ro:
        assert len(ro.photos(1)) == 1  # nothing written
    code, out, _ = run(capsys, "add", db, str(tmp_path / "view.png"), "--to", "hall")
    assert code == 0 and "added photo 2 to landmark 1 (hall)" in out


# --- several acceptable landmarks in a truth CSV ---------------------------------------------


def test_a_truth_row_may_name_several_acceptable_landmarks(tmp_path: Path) -> None:
    db = create_db(tmp_path / "m.sqlite", Origin(0.0, 0.0))
    for i, s in enumerate((61, 62, 63)):
        db.add(f"p{s}", facade(s), x_m=10.0 * i, y_m=0.0)
    cv2.imwrite(str(tmp_path / "v62.png"), _view(62))
    (tmp_path / "one.csv").write_text("query,expected\nv62.png,p61\n")
    (tmp_path / "two.csv").write_text("query,expected\nv62.png,p61|p62\n")
    rows = read_truth(tmp_path / "two.csv")
    assert rows[0].expected == "p61" and rows[0].also == ("p62",)
    one = evaluate_db(db, read_truth(tmp_path / "one.csv"))
    # p62 is not what the row says it shows: false in the full run and in leave-one-out
    assert [m for _o, m in one.false_matches()] == ["p62", "p62"]
    two = evaluate_db(db, read_truth(tmp_path / "two.csv"))
    assert two.false_matches() == [] and two.true_matches() == 1
    loo = [o for o in two.outcomes if o.leave_one_out]
    assert len(loo) == 1 and set(loo[0].scores) == {"p63"}  # both acceptable ones left out
    db.close()


# --- image sizes -----------------------------------------------------------------------------


def _png_header(w: int, h: int) -> bytes:
    ihdr = struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0)
    chunk = b"IHDR" + ihdr
    crc = struct.pack(">I", zlib.crc32(chunk))
    head = b"\x89PNG\r\n\x1a\n" + struct.pack(">I", 13) + chunk + crc
    return head + b"\0" * 16 + b"IEND\xaeB`\x82"


def test_a_too_large_photo_says_which_limit_and_that_downscaling_would_do(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    why = photo_problem(8000, 6000)
    assert why is not None and "48.0 megapixels" in why and "40 megapixel limit" in why
    assert "downscaling it to 7302x5477 px or less would do" in why
    assert photo_problem(7302, 5477) is None
    side = photo_problem(20000, 2500)
    assert side is not None and "16384 px limit on a side" in side and "16384x2048" in side
    both = photo_problem(20000, 3000)  # over both limits: the size given passes both
    assert both is not None and "16329x2449 px or less" in both
    assert photo_problem(16329, 2449) is None
    db = str(tmp_path / "m.sqlite")
    assert run(capsys, "init", db, "--origin", "0", "0")[0] == 0
    (tmp_path / "big.png").write_bytes(_png_header(8000, 6000))
    code, _, err = run(capsys, "add", db, str(tmp_path / "big.png"), "--xy", "0", "0")
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert "megapixel limit" in err and "downscaling it to" in err


def test_a_tiny_image_reads_as_too_small_not_as_few_matches(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    db = create_db(tmp_path / "m.sqlite", Origin(0.0, 0.0))
    db.add("a", facade(51), x_m=0.0, y_m=0.0)
    tiny = cv2.resize(facade(51), (32, 32), interpolation=cv2.INTER_AREA)
    rec = Recogniser(db)
    assert rec.match_image(tiny).reason == TOO_SMALL
    db.close()
    cv2.imwrite(str(tmp_path / "tiny.png"), tiny)
    code, out, _ = run(capsys, "match", str(tmp_path / "m.sqlite"), str(tmp_path / "tiny.png"))
    assert code == 0
    assert "no match: too_small (32x32 px is too small to match (at least 64 px" in out
    code, out, _ = run(
        capsys, "match", str(tmp_path / "m.sqlite"), str(tmp_path / "tiny.png"), "--json"
    )
    assert '"reason": "too_small"' in out and '"detail": "32x32 px is too small' in out


def test_config_rejects_nonsense() -> None:
    with pytest.raises(ValueError):
        MatchConfig(min_inliers=3)


def test_match_gives_the_same_evidence_in_every_process_and_order(tmp_path: Path) -> None:
    """Two ``landmark-db match --json`` processes, the images in opposite orders (so each
    query's photos are indexed after different work): the same evidence for every query."""
    import json
    import subprocess
    import sys

    db = create_db(tmp_path / "m.sqlite", Origin(0.0, 0.0))
    for i, s in enumerate((71, 72, 73)):
        db.add(f"f{s}", facade(s), x_m=100.0 * i, y_m=0.0)
    db.close()
    names = []
    for i, (s, d) in enumerate(((71, 15.0), (72, 12.0), (73, 18.0), (74, 10.0))):
        name = str(tmp_path / f"q{i}.png")
        cv2.imwrite(name, _view(s, cam_seed=7 + i, distance_m=d))
        names.append(name)

    def evidence(order: list[str]) -> dict[str, object]:
        proc = subprocess.run(
            [sys.executable, "-m", "landmark_db.cli", "match", str(tmp_path / "m.sqlite"),
             *order, "--json"],
            capture_output=True, text=True, timeout=120, check=True,
        )  # fmt: skip
        recs = [json.loads(line) for line in proc.stdout.splitlines()]
        return {r["query"]: (r["landmark_id"], r["evidence"]) for r in recs}

    assert evidence(names) == evidence(names[::-1])


def test_a_new_landmark_a_match_cannot_tell_from_a_near_one_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    db = str(tmp_path / "m.sqlite")
    assert run(capsys, "init", db, "--origin", "0", "0")[0] == 0
    for name, img in (("hall.png", facade(43)), ("view.png", _view(43)), ("other.png", _view(44))):
        cv2.imwrite(str(tmp_path / name), img)
    assert run(capsys, "add", db, str(tmp_path / "hall.png"), "--xy", "0", "0")[0] == 0
    code, _, err = run(capsys, "add", db, str(tmp_path / "view.png"), "--xy", "12", "0")
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert "shows landmark 1 (hall) 12 m away" in err and "--to 1" in err
    # another building next door, or the same photo far away: landmarks of their own
    assert run(capsys, "add", db, str(tmp_path / "other.png"), "--xy", "12", "0")[0] == 0
    assert run(capsys, "add", db, str(tmp_path / "view.png"), "--xy", "500", "0")[0] == 0
