"""``landmark-db migrate`` of legacy files holding rows the old software accepted (issue 23,
item 4): the limits of ``import`` apply, bad rows are refused (or quarantined) with a line
each, a failing migration leaves the file as it was, and ``remove`` / ``edit`` mend one
landmark. Real v2 SQLite files, real photos, the real CLI entry point."""

from __future__ import annotations

import csv
import hashlib
import sqlite3
from pathlib import Path

import pytest

from guidance.core.geo import Origin
from hal_sim.sim_camera import facade
from landmark_db.cli import main
from landmark_db.features import OrbConfig, encode_image, extract
from landmark_db.schema import V1, V2
from landmark_db.store import LandmarkDbError, create_db, open_db

ORIGIN = Origin(42.444, -76.5019)

# (name, x_m, sigma_m): what the previous release wrote without a murmur
ROWS = [
    ("good-1", 50.0, 3.0),
    ("huge-sigma", 100.0, 1e200),
    ("negative-sigma", 150.0, -1.0),
    ("far-1e39", 1e39, 3.0),
    ("far-4e7", 4e7, 3.0),
    ("good-2", 200.0, 3.0),
]
BAD = {2, 3, 4, 5}


def run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def _v2_file(path: Path) -> None:
    """A version-2 file (one photo per landmark in ``images``) holding ``ROWS``."""
    c = sqlite3.connect(path)
    c.executescript(f"BEGIN; {V1} {V2} COMMIT;")
    with c:
        c.executemany(
            "INSERT INTO metadata VALUES (?, ?)",
            [("origin_lat_deg", "42.444"), ("origin_lon_deg", "-76.5019"), ("origin_alt_m", "0.0"),
             ("orb_n_features", "300"), ("orb_max_side_px", "1024"), ("created_utc", "x")],
        )  # fmt: skip
        for i, (name, x, sigma) in enumerate(ROWS, start=1):
            lat, lon = ORIGIN.to_geodetic(x, 0.0) if abs(x) < 1e6 else (42.444, -76.5019)
            c.execute(
                "INSERT INTO landmarks VALUES (?, ?, ?, ?, ?, 0, NULL, ?, 'x', 's')",
                (i, name, lat, lon, x, sigma),
            )
            photo = facade(100 + i)
            data = encode_image(photo)
            c.execute(
                "INSERT INTO images VALUES (?, 'png', 640, 480, ?, ?)",
                (i, hashlib.sha256(data).hexdigest(), data),
            )
            f = extract(photo, OrbConfig(n_features=300))
            c.execute(
                "INSERT INTO features VALUES (?, ?, ?, ?, ?, ?)",
                (i, len(f), f.width, f.height, f.keypoint_blob(), f.descriptor_blob()),
            )
            c.execute("INSERT INTO landmark_index VALUES (?, ?, ?, 0, 0)", (i, x, x))
    c.close()


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _version(path: Path) -> int:
    with sqlite3.connect(path) as c:
        return int(c.execute("SELECT version FROM schema_version").fetchone()[0])


def test_migrate_refuses_rows_the_car_would_refuse_with_a_line_each_and_changes_nothing(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    db = tmp_path / "old.sqlite"
    _v2_file(db)
    before = _digest(db)
    code, _, err = run(capsys, "migrate", str(db))
    assert code == 2 and "Traceback" not in err
    lines = err.strip().splitlines()
    for lid in BAD:  # a line each, naming the landmark and why
        assert any(f"landmark {lid}:" in ln for ln in lines), err
    assert any("sigma 1e+200" in ln for ln in lines) and any("-1.0" in ln for ln in lines)
    assert lines[-1].startswith("landmark-db: error: ") and "unchanged" in lines[-1]
    assert _digest(db) == before and _version(db) == 2  # not converted
    assert sorted(p.name for p in tmp_path.iterdir()) == ["old.sqlite"]  # no copy left


def test_migrate_with_quarantine_moves_the_bad_rows_out_and_the_car_opens_the_rest(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    db, q = tmp_path / "old.sqlite", tmp_path / "quarantine"
    _v2_file(db)
    db.chmod(0o640)
    code, out, err = run(capsys, "migrate", str(db), "--quarantine", str(q))
    assert code == 0, err
    assert sum("(quarantined)" in ln for ln in err.splitlines()) == len(BAD)
    assert f"{len(BAD)} row(s) moved to {q}" in out
    assert (db.stat().st_mode & 0o777) == 0o640  # the file keeps its mode
    with open_db(db) as ro:  # the car's read-only open
        assert [lm.name for lm in ro.landmarks()] == ["good-1", "good-2"] and ro.check().ok
    with (q / "landmarks.csv").open(newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert sorted(int(r["id"]) for r in rows) == sorted(BAD)
    assert all(r["problem"] and (q / r["image"]).is_file() for r in rows)
    for r in rows:  # the user mends them in the CSV and imports them again
        r["sigma_m"] = "3.0"
        r["lat"], r["lon"] = (f"{v:.9f}" for v in ORIGIN.to_geodetic(300.0 + int(r["id"]), 0.0))
        r["x_m"] = r["y_m"] = ""
    with (q / "landmarks.csv").open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    code, out, err = run(capsys, "import", str(db), str(q))
    assert code == 0, err
    with open_db(db) as ro:
        assert len(ro) == len(ROWS) and ro.check().ok


def test_a_migration_whose_result_the_car_refuses_leaves_the_file_untouched(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    db = tmp_path / "t.sqlite"
    with create_db(db, ORIGIN, OrbConfig(n_features=300)) as w:
        w.add("a", facade(7), x_m=10.0, y_m=0.0)
    with sqlite3.connect(db) as c:  # an index box beyond float32 (the row itself is fine)
        c.execute("UPDATE landmark_index SET min_x = 1e39, max_x = 1e39 WHERE id = 1")
    c.close()
    with pytest.raises(LandmarkDbError):
        open_db(db).close()
    before = _digest(db)
    code, _, err = run(capsys, "migrate", str(db))
    assert code == 2 and "unchanged" in err and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1
    assert _digest(db) == before


def test_remove_and_edit_mend_one_landmark_each(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    db = tmp_path / "old.sqlite"
    _v2_file(db)
    d = str(db)
    assert run(capsys, "edit", d, "2", "--sigma", "4")[0] == 0
    code, _, err = run(capsys, "edit", d, "negative-sigma", "--sigma", "1e9")
    assert code == 2 and "not changed" in err and "500" in err and len(err.splitlines()) == 1
    assert run(capsys, "edit", d, "negative-sigma", "--sigma", "2.5")[0] == 0
    code, _, err = run(capsys, "edit", d, "4", "--sigma", "3")  # still 1e39 m out
    assert code == 2 and "30000 m" in err and len(err.splitlines()) == 1
    code, out, _ = run(capsys, "edit", d, "4", "--xy", "120", "-5", "--name", "moved")
    assert code == 0 and "x 120.00 m" in out
    code, out, _ = run(capsys, "remove", d, "5")
    assert code == 0 and "removed landmark 5" in out
    code, _, err = run(capsys, "remove", d, "5")
    assert code == 2 and "no landmark '5'" in err
    code, _, err = run(capsys, "edit", d, "1", "--name", "bad\x1b[31m")
    assert code == 2 and "control characters" in err
    assert run(capsys, "migrate", d)[0] == 0  # nothing left to refuse
    with open_db(db) as ro:
        lms = {lm.id: lm for lm in ro.landmarks()}
        assert sorted(lms) == [1, 2, 3, 4, 6] and ro.check().ok
        assert lms[2].position_sigma_m == 4.0 and lms[3].position_sigma_m == 2.5
        assert lms[4].name == "moved" and lms[4].x_m == pytest.approx(120.0)
        assert lms[2].source == lms[3].source == "s"  # an edit keeps what it was not asked


def test_migrate_follows_a_symlink_and_refuses_a_read_only_file(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    real = tmp_path / "data" / "old.sqlite"
    real.parent.mkdir()
    _v2_file(real)
    link = tmp_path / "city.sqlite"
    link.symlink_to(real)
    real.chmod(0o444)
    before = _digest(real)
    code, _, err = run(capsys, "migrate", str(link), "--quarantine", str(tmp_path / "q"))
    assert code == 2 and "read-only (mode 0444)" in err and len(err.splitlines()) == 1
    assert _digest(real) == before
    real.chmod(0o644)
    code, _, err = run(capsys, "migrate", str(link), "--quarantine", str(tmp_path / "q"))
    assert code == 0, err
    assert link.is_symlink() and _version(real) == 4  # the link stays, its file is migrated
    assert sorted(p.name for p in real.parent.iterdir()) == ["old.sqlite"]


def test_remove_and_edit_never_take_a_name_for_an_id_or_a_huge_id_for_a_crash(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Issue 40, defects 9 and 10: ``edit --name 1`` was accepted, after which ``remove DB 1``
    deleted landmark id 1 (another place); duplicate names were accepted by ``edit``; a 30-digit
    id printed a raw traceback (an integer beyond SQLite's)."""
    db = tmp_path / "old.sqlite"
    _v2_file(db)
    d = str(db)
    def names_now() -> dict[int, str]:
        with sqlite3.connect(db) as conn:
            return dict(conn.execute("SELECT id, name FROM landmarks").fetchall())

    names = names_now()
    code, _, err = run(capsys, "edit", d, "2", "--sigma", "4", "--name", "1")
    assert code == 2 and "all digits" in err and len(err.splitlines()) == 1
    code, _, err = run(capsys, "edit", d, "2", "--sigma", "4", "--name", names[1])
    assert code == 2 and "exists (id 1)" in err
    for huge in ("9" * 30, "1" + "0" * 19):
        for cmd in (("remove", d, huge), ("edit", d, huge, "--sigma", "3")):
            code, _, err = run(capsys, *cmd)
            assert code == 2 and "no landmark" in err and "Traceback" not in err, err
    code, _, err = run(capsys, "remove", d, "\u0662")  # an Arabic-Indic two is no id
    assert code == 2 and "no landmark" in err
    for argv, said in (
        (("--xy", "1", "2", "--latlon", "1", "2"), "not allowed with argument"),
        (("--facing", "1e308"), "invalid number in [-360, 360] value"),  # was stored as 296
        (("--sigma", "6_00"), "invalid number value"),
    ):
        with pytest.raises(SystemExit) as exit_:
            main(["edit", d, "2", *argv])
        assert exit_.value.code == 2 and said in capsys.readouterr().err
    assert names_now() == names  # nothing changed
