"""landmark-db: several photos per landmark, batch matching, acceptance on a truth CSV,
broken pipes and damaged images."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from guidance.core.geo import Origin
from hal_sim.sim_camera import SimCamera, SimCameraConfig, facade
from landmark_db.cli import main
from landmark_db.features import encode_image, extract
from landmark_db.store import create_db, open_db

REPO = Path(__file__).resolve().parents[2]
CAM = SimCameraConfig(occlusion=(0.0, 0.1))


def run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def _view(seed: int, cam_seed: int = 1) -> np.ndarray:
    return SimCamera([], seed=cam_seed, config=CAM).view(facade(seed), 6.0)


def _write(folder: Path, name: str, image: np.ndarray) -> str:
    folder.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(folder / name), image)
    return name


def test_import_groups_rows_into_landmarks_and_add_to(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    db = str(tmp_path / "m.sqlite")
    assert run(capsys, "init", db, "--origin", "0", "0")[0] == 0
    ph = tmp_path / "photos"
    for s in (41, 42, 43, 44, 45):
        _write(ph, f"f{s}.png", facade(s))
    (ph / "landmarks.csv").write_text(
        "image,id,name,x_m,y_m,conditions\n"
        "f41.png,,tower,0,0,day\n"
        "f42.png,,tower,0,0,night\n"  # same name: another photo of the tower
        "f43.png,7,hall,50,0,\n"
        "f44.png,7,,50,0,west side\n"  # same id value: another photo of the hall
        "f45.png,L9,,90,0,\n"  # no name: named by its id value
    )
    code, out, _ = run(capsys, "import", db, str(ph))
    assert code == 0 and "imported 3 landmarks (5 photos)" in out
    hall = _write(ph, "hall_view.png", _view(43))  # another photo of the hall: it verifies
    code, out, _ = run(capsys, "add", db, str(ph / hall), "--to", "hall", "--facing", "90")
    assert code == 0 and "added photo 6 to landmark 2 (hall)" in out
    code, out, _ = run(capsys, "list", db)
    assert code == 0 and "3 landmarks, 6 photos" in out
    with open_db(db) as ro:
        assert [len(ro.photos(lm.id)) for lm in ro.landmarks()] == [2, 3, 1]
        assert ro.find("L9") is not None
        assert [p.conditions for p in ro.photos(1)] == ["day", "night"]
    code, out, _ = run(capsys, "show", db, "hall")
    assert code == 0 and out.count("photo ") >= 3 and "west side" in out
    # export writes a row per photo; re-import gives the same grouping
    assert run(capsys, "export", db, str(tmp_path / "out"))[0] == 0
    db2 = str(tmp_path / "m2.sqlite")
    assert run(capsys, "init", db2, "--origin", "0", "0")[0] == 0
    code, out, _ = run(capsys, "import", db2, str(tmp_path / "out"))
    assert code == 0 and "imported 3 landmarks (6 photos)" in out
    code, _, err = run(capsys, "add", db, str(ph / "f45.png"), "--to", "nowhere")
    assert code == 2 and "no landmark 'nowhere'" in err


def test_match_many_images_in_one_process_with_json(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    db = create_db(tmp_path / "m.sqlite", Origin(0.0, 0.0))
    db.add("a", facade(51), x_m=0.0, y_m=0.0)
    db.add("b", facade(52), x_m=100.0, y_m=0.0)
    db.close()
    q = tmp_path / "q"
    names = [_write(q, "va.png", _view(51)), _write(q, "vb.png", _view(52))]
    names.append(_write(q, "other.png", facade(59)))
    jpeg = encode_image(_view(51), ".jpg")
    (q / "cut.jpg").write_bytes(jpeg[: len(jpeg) // 2])
    args = [str(q / n) for n in [*names, "cut.jpg"]]
    code, out, err = run(capsys, "match", str(db.path), *args, "--json")
    recs = [json.loads(line) for line in out.splitlines()]
    assert code == 2 and err == ""  # the damaged image is reported in its record
    assert [r.get("name") for r in recs[:3]] == ["a", "b", None]
    assert recs[2]["reason"] in ("few_matches", "failed_geometry")
    assert recs[0]["evidence"][0]["result"] == "verified" and recs[0]["evidence"][0]["inliers"] > 12
    assert "truncated JPEG" in recs[3]["error"] and recs[3]["query"].endswith("cut.jpg")
    # text output: the damaged one in one line on stderr, the others still matched
    code, out, err = run(capsys, "match", str(db.path), *args)
    assert code == 2 and out.count("match: landmark") == 2
    assert err.count("\n") == 1 and "cut.jpg" in err and "truncated JPEG" in err


def test_a_damaged_image_is_one_line_without_opencv_warnings(
    tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    db = create_db(tmp_path / "m.sqlite", Origin(0.0, 0.0))
    db.add("a", facade(51), x_m=0.0, y_m=0.0)
    db.close()
    jpeg = encode_image(_view(51), ".jpg")
    (tmp_path / "cut.jpg").write_bytes(jpeg[: len(jpeg) - 300])
    capfd.readouterr()
    code = main(["match", str(db.path), str(tmp_path / "cut.jpg")])
    _out, err = capfd.readouterr()  # file-descriptor level: OpenCV's own stderr too
    assert code == 2 and err.count("\n") == 1 and "WARN" not in err
    assert "truncated JPEG" in err


def test_list_into_a_closed_pipe_exits_quietly(tmp_path: Path) -> None:
    db = create_db(tmp_path / "big.sqlite", Origin(0.0, 0.0))
    feats = extract(facade(1), db.extractor)
    db.add_many_precomputed(
        [(f"l{i}", float(i), 0.0) for i in range(3000)], feats, encode_image(facade(1))
    )
    db.close()
    cmd = [sys.executable, "-c", "import sys; from landmark_db.cli import main; sys.exit(main())"]
    proc = subprocess.Popen(
        [*cmd, "list", str(db.path)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=REPO
    )
    assert proc.stdout is not None and proc.stderr is not None
    first = proc.stdout.readline()  # like `| head -1`: read one line and leave
    proc.stdout.close()
    err = proc.stderr.read()
    proc.stderr.close()
    assert proc.wait(timeout=60) == 0 and b"id" in first
    assert err == b"", err


def test_acceptance_on_a_truth_csv_with_negatives(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    db = create_db(tmp_path / "m.sqlite", Origin(0.0, 0.0))
    for i, s in enumerate((61, 62, 63)):
        db.add(f"p{s}", facade(s), x_m=10.0 * i, y_m=0.0)
    db.close()
    q = tmp_path / "q"
    for s in (61, 62, 63):
        _write(q, f"v{s}.png", _view(s))
    _write(q, "neg.png", facade(69))
    (q / "truth.csv").write_text(
        "query,expected,condition\nv61.png,p61,near\nv62.png,p62,near\nv63.png,3,far\nneg.png,,\n"
    )
    code, out, _ = run(
        capsys, "acceptance", "--db", str(db.path), "--truth", str(q / "truth.csv"), "--quiet"
    )
    assert code == 0
    assert "positive queries 3; negative queries 1; leave-one-out runs 3" in out
    assert "false matches 0; precision 1.000; recall 1.000" in out
    assert "recall by condition: far 1/1, near 2/2" in out
    assert "wrong pairs 15;" in out and "margin of the rule over the wrong pairs" in out
    (q / "bad.csv").write_text("query,expected\nv61.png,nosuch\n")
    code, _, err = run(capsys, "acceptance", "--db", str(db.path), "--truth", str(q / "bad.csv"))
    assert code == 2 and "no landmark 'nosuch'" in err


def test_migrate_switches_the_extractor(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    db = str(tmp_path / "m.sqlite")
    assert run(capsys, "init", db, "--origin", "0", "0", "--extractor", "orb")[0] == 0
    _write(tmp_path, "a.png", facade(71))
    assert run(capsys, "add", db, str(tmp_path / "a.png"), "--xy", "0", "0")[0] == 0
    code, out, _ = run(capsys, "migrate", db, "--extractor", "rootsift", "--features", "500")
    assert code == 0 and "features rootsift/2:500@640 (1 photo(s) recomputed)" in out
    code, out, _ = run(capsys, "migrate", db)
    assert code == 0 and "(0 photo(s) recomputed)" in out
    with open_db(db) as ro:
        f = ro.features(1)
        assert f is not None and f.kind == "rootsift" and ro.check().ok


def test_survey_keeps_several_frames_per_mark_and_joins_passes(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from hal_sim.sim_camera import SimCamera, SimCameraConfig

    frames = tmp_path / "frames"
    # the second pass (frames 6-8) sees the bridge (facade 82, the first pass's mark frame)
    # again from other distances: it must pass the same-place check (issue 36)
    cam = SimCamera([], 4, SimCameraConfig(perspective=0.08, occlusion=(0.0, 0.1)))
    for i in range(10):  # 2 fps: t = 0, 0.5, ... 4.5 s
        image = cam.view(facade(82), 6.0 + i) if 6 <= i <= 8 else facade(80 + i)
        _write(frames, f"{i:02d}.png", image)
    marks = tmp_path / "marks.csv"
    marks.write_text("t_s,name,x_m,y_m\n1.0,bridge,10,20\n3.5,bridge,10,20\n")
    db = str(tmp_path / "s.sqlite")
    main(["init", db, "--origin", "0", "0"])
    capsys.readouterr()
    code, out, _ = run(capsys, "survey", db, str(frames), "--marks", str(marks), "--fps", "2")
    assert code == 0 and "2 landmarks saved" in out, out  # two passes, one place
    with open_db(db) as ro:
        assert len(ro) == 1
        srcs = [p.source for p in ro.photos(1)]
    assert srcs == [
        "survey t=1.00",
        "survey t=1.00 frame t=0.50",
        "survey t=1.00 frame t=1.50",
        "survey t=3.50 frame t=3.50",
        "survey t=3.50 frame t=3.00",
        "survey t=3.50 frame t=4.00",
    ]


def test_survey_refuses_a_truncated_frame_in_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    frames = tmp_path / "frames"
    _write(frames, "00.png", facade(90))
    jpeg = encode_image(facade(91), ".jpg")
    (frames / "01.jpg").write_bytes(jpeg[: len(jpeg) // 2])
    (tmp_path / "marks.csv").write_text("t_s,name,x_m,y_m\n1.0,a,0,0\n")
    db = str(tmp_path / "s.sqlite")
    main(["init", db, "--origin", "0", "0"])
    capsys.readouterr()
    code, _, err = run(capsys, "survey", db, str(frames), "--marks", str(tmp_path / "marks.csv"))
    assert code == 2 and err.count("\n") == 1 and "01.jpg" in err and "truncated JPEG" in err


def test_survey_leaves_out_a_pass_that_shows_other_buildings(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A mark naming an existing landmark whose frames show other buildings (a wrong name,
    a wrong time) adds none of them: each is left out with a note (issue 36)."""
    frames = tmp_path / "frames"
    for i in range(10):
        _write(frames, f"{i:02d}.png", facade(80 + i))
    marks = tmp_path / "marks.csv"
    marks.write_text("t_s,name,x_m,y_m\n1.0,bridge,10,20\n3.5,bridge,10,20\n")
    db = str(tmp_path / "s.sqlite")
    main(["init", db, "--origin", "0", "0"])
    capsys.readouterr()
    code, out, _ = run(capsys, "survey", db, str(frames), "--marks", str(marks), "--fps", "2")
    assert code == 0 and "1 landmarks saved" in out
    assert out.count("does not match landmark 1's photos (near it") == 3
    with open_db(db) as ro:
        assert len(ro.photos(1)) == 3
