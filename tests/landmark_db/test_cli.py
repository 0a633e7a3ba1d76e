"""The landmark-db command line, run in-process on real files."""

from __future__ import annotations

import csv
from pathlib import Path

import cv2
import pynmea2
import pytest

from guidance.core.geo import Origin
from hal_sim.sim_camera import SimCamera, SimCameraConfig, SimLandmark, facade
from landmark_db.cli import main
from landmark_db.store import open_db

ORIGIN = Origin(42.444, -76.5019)


def run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def _photos(folder: Path, seeds: list[int]) -> list[str]:
    folder.mkdir(parents=True, exist_ok=True)
    names = []
    for s in seeds:
        name = f"f{s}.png"
        cv2.imwrite(str(folder / name), facade(s))
        names.append(name)
    return names


def test_build_query_match_check_export_reimport(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    db = str(tmp_path / "m.sqlite")
    assert run(capsys, "init", db, "--origin", "42.444", "-76.5019")[0] == 0
    photos = tmp_path / "photos"
    names = _photos(photos, [31, 32, 33])
    code, out, _ = run(capsys, "add", db, str(photos / names[0]), "--xy", "0", "0", "--name", "A")
    assert code == 0 and "added landmark 1" in out
    lat, lon = ORIGIN.to_geodetic(100.0, 0.0)
    with (photos / "marks.csv").open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["image", "name", "lat", "lon", "x_m", "y_m", "facing_deg"])
        w.writerow([names[1], "B", lat, lon, "", "", "90"])
        w.writerow([names[2], "C", "", "", "0", "500", ""])
    code, out, _ = run(capsys, "import", db, str(photos), "--csv", str(photos / "marks.csv"))
    assert code == 0 and "imported 2 landmarks" in out
    code, out, _ = run(capsys, "list", db)
    assert code == 0 and "3 landmarks" in out and " B " in out
    code, out, _ = run(capsys, "show", db, "B", "--image-out", str(tmp_path / "b.png"))
    assert code == 0 and "facing_deg: 90.0" in out
    assert cv2.imread(str(tmp_path / "b.png")) is not None
    # query: radius, covariance, ellipse
    code, out, _ = run(capsys, "query", db, "--at", "90", "0", "--radius", "15")
    assert code == 0 and "1 candidates" in out and " B " in out
    code, out, _ = run(
        capsys, "query", db, "--at", "50", "0", "--cov", "900", "0", "1", "--range", "5"
    )
    assert code == 0 and "2 candidates" in out  # 2-sigma semi-major 60 m + 5 m reaches both
    code, out, _ = run(capsys, "query", db, "--at", "0", "250", "--ellipse", "240", "10", "90")
    assert code == 0 and "2 candidates" in out and " A " in out and " C " in out
    # match: a perturbed view of B near B, and against all
    cam = SimCamera(
        [SimLandmark(2, 100.0, 0.0, 32)], seed=1, config=SimCameraConfig(occlusion=(0, 0.1))
    )
    view = tmp_path / "view.png"
    cv2.imwrite(str(view), cam.view(facade(32), 5.0))
    code, out, _ = run(capsys, "match", db, str(view), "--at", "95", "0")
    assert code == 0 and "match: landmark 2 (B)" in out and "verified (homography)" in out
    code, out, _ = run(capsys, "match", db, str(view))
    assert code == 0 and "match: landmark 2 (B)" in out and out.count("verified") == 1
    cv2.imwrite(str(tmp_path / "other.png"), facade(99))
    code, out, _ = run(capsys, "match", db, str(tmp_path / "other.png"))
    assert code == 0 and "no match:" in out and "match: landmark" not in out
    assert run(capsys, "check", db)[1].strip().endswith("ok (3 landmarks)")
    # export and re-import give the same landmarks
    code, out, _ = run(capsys, "export", db, str(tmp_path / "out"))
    assert code == 0
    db2 = str(tmp_path / "m2.sqlite")
    assert run(capsys, "init", db2, "--origin", "42.444", "-76.5019")[0] == 0
    code, out, _ = run(capsys, "import", db2, str(tmp_path / "out"))
    assert code == 0 and "imported 3" in out
    with open_db(db) as a, open_db(db2) as b:
        for la, lb in zip(a.landmarks(), b.landmarks(), strict=True):
            assert (la.name, la.facing_deg) == (lb.name, lb.facing_deg)
            assert abs(la.x_m - lb.x_m) < 0.01 and abs(la.y_m - lb.y_m) < 0.01
            assert a.image_bytes(la.id) == b.image_bytes(lb.id)


@pytest.mark.parametrize(
    "argv, message",
    [
        (["list", "{tmp}/missing.sqlite"], "no such landmark database"),
        (["list", "{tmp}/junk.sqlite"], "not a landmark database"),
        (["init", "{tmp}/junk.sqlite", "--origin", "1", "2"], "already exists"),
        (["init", "{tmp}/new.sqlite", "--origin", "95", "2"], "latitude"),
        (["add", "{tmp}/db.sqlite", "{tmp}/junk.sqlite", "--xy", "0", "0"], "decode"),
        (["add", "{tmp}/db.sqlite", "{tmp}/nope.png", "--xy", "0", "0"], "no such image"),
        (["add", "{tmp}/db.sqlite", "{tmp}/p.png"], "give a position"),
        (["show", "{tmp}/db.sqlite", "nobody"], "no landmark"),
        (["match", "{tmp}/db.sqlite", "{tmp}/junk.sqlite"], "not a readable image"),
        (["query", "{tmp}/db.sqlite"], "give a position"),
        (["import", "{tmp}/db.sqlite", "{tmp}"], "landmarks.csv"),
        (["survey", "{tmp}/db.sqlite", "{tmp}"], "--marks"),
        (["acceptance", "{tmp}/nowhere"], "not a folder"),
    ],
)
def test_errors_are_one_line_and_exit_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], argv: list[str], message: str
) -> None:
    (tmp_path / "junk.sqlite").write_bytes(b"junk" * 100)
    cv2.imwrite(str(tmp_path / "p.png"), facade(1))
    assert main(["init", str(tmp_path / "db.sqlite"), "--origin", "0", "0"]) == 0
    capsys.readouterr()
    code, _out, err = run(capsys, *[a.format(tmp=tmp_path) for a in argv])
    assert code == 2
    assert err.count("\n") == 1 and err.startswith("landmark-db: error:"), err
    assert message in err and "Traceback" not in err


def test_check_reports_problems_and_exits_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    db = str(tmp_path / "c.sqlite")
    main(["init", db, "--origin", "0", "0"])
    cv2.imwrite(str(tmp_path / "p.png"), facade(2))
    main(["add", db, str(tmp_path / "p.png"), "--xy", "1", "2"])
    import sqlite3

    c = sqlite3.connect(db)
    c.execute("DELETE FROM landmark_index")
    c.commit()
    c.close()
    capsys.readouterr()
    code, out, err = run(capsys, "check", db)
    assert code == 2 and "without an index box: 1" in out and "1 problem(s)" in err


def _nmea_track(path: Path, n: int) -> None:
    """RMC fixes once a second, driving north at 10 m/s from the origin."""
    lines = []
    for k in range(n):
        lat, lon = ORIGIN.to_geodetic(0.0, 10.0 * k)
        la = f"{int(lat):02d}{(lat - int(lat)) * 60:07.4f}"
        lo = f"{int(-lon):03d}{(-lon - int(-lon)) * 60:07.4f}"
        msg = pynmea2.RMC(
            "GP",
            "RMC",
            (f"1200{k:02d}.00", "A", la, "N", lo, "W", "19.4", "0.0", "251126", "", ""),
        )
        lines.append(str(msg))
    lines.insert(3, "$GPRMC,garbage*00")
    path.write_text("\n".join(lines) + "\n")


def test_survey_from_video_and_gps(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    # A 2 fps video: frames show facade 40 + i.
    video = tmp_path / "drive.avi"
    w = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 2.0, (640, 480))
    for i in range(20):
        w.write(facade(40 + i))
    w.release()
    nmea = tmp_path / "gps.nmea"
    _nmea_track(nmea, 12)
    db = str(tmp_path / "s.sqlite")
    main(["init", db, "--origin", str(ORIGIN.lat_deg), str(ORIGIN.lon_deg)])
    capsys.readouterr()
    code, out, _ = run(capsys, "survey", db, str(video), "--nmea", str(nmea), "--every", "30")
    assert code == 0 and "4 landmarks saved" in out  # at 0, 30, 60, 90 m: t = 0, 3, 6, 9 s
    with open_db(db) as ro:
        lms = list(ro.landmarks())
        assert [round(lm.y_m) for lm in lms] == [0, 30, 60, 90]
        assert all(abs(lm.x_m) < 0.5 for lm in lms)
        # the saved photo is the frame at that time: frame 2 t (2 fps) shows facade 40 + 2 t
        from landmark_db.recognise import Recogniser

        rec = Recogniser(ro)
        for lm, t in zip(lms, [0, 3, 6, 9], strict=True):
            assert rec.match_image(facade(40 + 2 * t)).landmark_id == lm.id


def test_survey_from_folder_and_manual_marks(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    frames = tmp_path / "frames"
    _photos(frames, [70, 71, 72, 73, 74])  # f70..f74 at t = 0..4 s (1 fps)
    marks = tmp_path / "marks.csv"
    marks.write_text("t_s,name,x_m,y_m\n1.2,first,10,20\n3.9,second,30,40\n9.0,late,0,0\n")
    db = str(tmp_path / "s.sqlite")
    main(["init", db, "--origin", "0", "0"])
    capsys.readouterr()
    code, out, _ = run(capsys, "survey", db, str(frames), "--marks", str(marks))
    assert code == 0 and "2 landmarks saved, 1 marks skipped" in out
    with open_db(db) as ro:
        got = {lm.name: (lm.x_m, lm.y_m) for lm in ro.landmarks()}
        assert got == {"first": (10.0, 20.0), "second": (30.0, 40.0)}
        from landmark_db.recognise import Recogniser

        rec = Recogniser(ro)
        assert rec.match_image(facade(71)).landmark_id == ro.find("first").id  # type: ignore[union-attr]
        assert rec.match_image(facade(74)).landmark_id == ro.find("second").id  # type: ignore[union-attr]


def test_bad_nmea_and_marks_are_one_line_errors(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    frames = tmp_path / "frames"
    _photos(frames, [1])
    (tmp_path / "bad.nmea").write_text("$GPRMC,junk\nhello\n")
    (tmp_path / "bad.csv").write_text("t_s,x_m\nabc,1\n")
    db = str(tmp_path / "s.sqlite")
    main(["init", db, "--origin", "0", "0"])
    capsys.readouterr()
    code, _, err = run(capsys, "survey", db, str(frames), "--nmea", str(tmp_path / "bad.nmea"))
    assert code == 2 and "no valid GPS fixes" in err
    code, _, err = run(capsys, "survey", db, str(frames), "--marks", str(tmp_path / "bad.csv"))
    assert code == 2 and "bad mark" in err


def test_add_refuses_a_second_landmark_under_an_existing_name(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Names are spoken ("Passing the bakery") and used by --to: a second "bakery" elsewhere
    is refused with the way out, unless asked for."""
    db = str(tmp_path / "m.sqlite")
    assert run(capsys, "init", db, "--origin", "42.444", "-76.5019")[0] == 0
    photos = tmp_path / "photos"
    a, b = _photos(photos, [41, 42])
    assert run(capsys, "add", db, str(photos / a), "--xy", "0", "0", "--name", "bakery")[0] == 0
    code, _, err = run(capsys, "add", db, str(photos / b), "--xy", "300", "0", "--name", "bakery")
    assert code != 0 and "a landmark named 'bakery' exists (id 1)" in err and "--to 1" in err
    with open_db(db) as store:
        assert len(list(store.landmarks())) == 1  # nothing written
    view = photos / "bakery_view.png"  # another photo of the bakery: it verifies
    cv2.imwrite(str(view), SimCamera([], seed=3).view(facade(41), 5.0))
    code, out, _ = run(capsys, "add", db, str(view), "--to", "bakery")
    assert code == 0 and "added photo" in out
    code, out, _ = run(
        capsys, "add", db, str(photos / b), "--xy", "300", "0", "--name", "bakery", "--same-name"
    )
    assert code == 0 and "added landmark 2" in out


def test_a_survey_is_one_transaction_a_bad_mark_leaves_the_file_as_it_was(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The second mark's position is beyond any city: the survey stops with one line and the
    first mark, already saved in the transaction, is rolled back with it (no half survey)."""
    frames = tmp_path / "frames"
    _photos(frames, [80, 81, 82, 83])
    marks = tmp_path / "marks.csv"
    marks.write_text("t_s,name,x_m,y_m\n1.0,first,10,20\n2.5,far,1e9,0\n")
    db = str(tmp_path / "s.sqlite")
    main(["init", db, "--origin", "0", "0"])
    capsys.readouterr()
    code, _, err = run(capsys, "survey", db, str(frames), "--marks", str(marks))
    assert code != 0 and "landmark-db: error:" in err and "Traceback" not in err
    with open_db(db) as ro:
        assert list(ro.landmarks()) == []
