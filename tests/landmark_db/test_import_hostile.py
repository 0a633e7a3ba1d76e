"""``landmark-db import`` on hostile CSVs and images (issue 14, item 9): it never writes what
the car then refuses, stays inside its folder, is atomic and idempotent, bounds CSV fields
and images before decoding; ``export`` neutralises formula cells; ``list`` prints names
safely. Real SQLite files, real PNGs, the real CLI entry point."""

from __future__ import annotations

import csv
import sqlite3
import struct
import time
import zlib
from pathlib import Path

import cv2
import numpy as np
import pytest

from hal_sim.sim_camera import facade
from landmark_db.cli import main
from landmark_db.store import open_db


def run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def _one_error_line(code: int, err: str) -> str:
    assert code == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("landmark-db: error: "), err
    assert "Traceback" not in err
    return lines[0]


def _png(width: int, height: int) -> bytes:
    """A grey PNG of any size, written row by row (a 15000 x 15000 one is 220 kB)."""

    def chunk(kind: bytes, body: bytes) -> bytes:
        return (
            struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))
        )

    z = zlib.compressobj(9)
    row = b"\x00" * (width + 1)  # filter byte + pixels
    idat = b"".join(z.compress(row) for _ in range(height)) + z.flush()
    ihdr = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", idat) + chunk(b"IEND", b"")


@pytest.fixture
def db(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> str:
    path = str(tmp_path / "m.sqlite")
    assert run(capsys, "init", path, "--origin", "48.85", "2.35")[0] == 0
    return path


@pytest.fixture
def photos(tmp_path: Path) -> Path:
    folder = tmp_path / "photos"
    folder.mkdir()
    for s in (1, 2, 3):
        cv2.imwrite(str(folder / f"f{s}.png"), facade(s))
    return folder


def _csv(folder: Path, *rows: str) -> Path:
    path = folder / "landmarks.csv"
    path.write_text("image,name,x_m,y_m,sigma_m\n" + "".join(r + "\n" for r in rows))
    return path


def _counts(path: str) -> tuple[int, int]:
    conn = sqlite3.connect(path)
    try:
        n = conn.execute("SELECT count(*) FROM landmarks").fetchone()[0]
        p = conn.execute("SELECT count(*) FROM photos").fetchone()[0]
        return int(n), int(p)
    finally:
        conn.close()


@pytest.mark.parametrize(
    ("row", "says"),
    [
        ("f2.png,far,1e39,0,3", "from the database's origin"),
        ("f2.png,far,4e7,0,3", "from the database's origin"),
        ("f2.png,far,0,-35000,3", "from the database's origin"),
        ("f2.png,vague,10,0,1e200", "position sigma"),
        ("f2.png,neg,10,0,-1", "position sigma"),
        ("f2.png,nan,nan,0,3", "not a number"),
        ("f2.png,under,1_0_0,0,3", "not a number"),
    ],
)
def test_import_refuses_what_the_car_would_refuse_and_imports_nothing(
    db: str, photos: Path, capsys: pytest.CaptureFixture[str], row: str, says: str
) -> None:
    _csv(photos, "f1.png,good,0,0,3", row)
    line = _one_error_line(*run(capsys, "import", db, str(photos))[::2])
    assert says in line and "landmarks.csv:3" in line and "nothing imported" in line
    assert _counts(db) == (0, 0)  # atomic: the good first row went too
    with open_db(db) as car:  # the car's read-only open
        assert len(car) == 0
    assert run(capsys, "check", db)[0] == 0


def test_a_featureless_photo_is_refused_at_import(
    db: str, photos: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    cv2.imwrite(str(photos / "grey.png"), np.full((480, 640, 3), 128, np.uint8))
    _csv(photos, "grey.png,wall,0,0,3")
    line = _one_error_line(*run(capsys, "import", db, str(photos))[::2])
    assert "features" in line
    assert _counts(db) == (0, 0)


def test_the_read_only_open_refuses_a_landmark_beyond_the_limits_naming_it(
    db: str, photos: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    _csv(photos, "f1.png,good,0,0,3")
    assert run(capsys, "import", db, str(photos))[0] == 0
    conn = sqlite3.connect(db)
    with conn:
        conn.execute("UPDATE landmarks SET position_sigma_m = 1e200")
    conn.close()
    with pytest.raises(Exception, match=r"landmark 1 \('good'\): position sigma"):
        open_db(db)
    assert run(capsys, "check", db)[0] == 2


@pytest.mark.parametrize("kind", ["dotdot", "absolute", "symlink"])
def test_import_is_contained_to_its_folder(
    tmp_path: Path, db: str, photos: Path, capsys: pytest.CaptureFixture[str], kind: str
) -> None:
    outside = tmp_path / "secret.png"
    cv2.imwrite(str(outside), facade(9))
    if kind == "dotdot":
        value = "../secret.png"
    elif kind == "absolute":
        value = str(outside)
    else:
        (photos / "link.png").symlink_to(outside)
        value = "link.png"
    _csv(photos, f"{value},x,0,0,3")
    line = _one_error_line(*run(capsys, "import", db, str(photos))[::2])
    assert "outside the folder" in line and "--allow-outside" in line
    assert _counts(db) == (0, 0)
    code, _, err = run(capsys, "import", db, str(photos), "--allow-outside")
    assert code == 0, err
    assert _counts(db) == (1, 1)


@pytest.mark.parametrize("allow_outside", [False, True])
def test_a_symlink_loop_in_the_csv_is_one_line(
    db: str, photos: Path, capsys: pytest.CaptureFixture[str], allow_outside: bool
) -> None:
    (photos / "a.png").symlink_to(photos / "b.png")
    (photos / "b.png").symlink_to(photos / "a.png")
    _csv(photos, "f1.png,good,0,0,3", "a.png,loop,10,0,3")
    argv = ["import", db, str(photos)] + (["--allow-outside"] if allow_outside else [])
    line = _one_error_line(*run(capsys, *argv)[::2])
    assert "landmarks.csv:3" in line and "a loop of symbolic links" in line
    assert _counts(db) == (0, 0)  # nothing imported


def test_import_twice_updates_and_never_duplicates(
    db: str, photos: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    _csv(photos, "f1.png,tower,0,0,3", "f2.png,tower,0,0,3", "f3.png,hall,50,0,3")
    assert run(capsys, "import", db, str(photos))[0] == 0
    assert _counts(db) == (2, 3)
    code, out, _ = run(capsys, "import", db, str(photos))
    assert code == 0 and "2 already there, updated" in out
    assert _counts(db) == (2, 3)
    _csv(photos, "f3.png,hall,60,5,2")  # moved: the landmark is updated, index box too
    assert run(capsys, "import", db, str(photos))[0] == 0
    assert _counts(db) == (2, 3)
    with open_db(db) as car:
        hall = car.by_name("hall")
        assert hall is not None and (hall.x_m, hall.y_m, hall.position_sigma_m) == (60, 5, 2)
        ids, _ = car.in_box(59, 61, 4, 6)
        assert ids.tolist() == [hall.id]
    assert run(capsys, "check", db)[0] == 0


def test_export_neutralises_formula_cells_and_reimports_the_same_names(
    tmp_path: Path, db: str, photos: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    names = ['=HYPERLINK("http://x")', "+cmd", "-2+3", "@SUM(A1)", "plain"]
    rows = [
        f'f{1 + i % 3}.png,"{n.replace(chr(34), 2 * chr(34))}",{10 * i},0,3'
        for i, n in enumerate(names)
    ]
    _csv(photos, *rows)
    assert run(capsys, "import", db, str(photos))[0] == 0
    dest = tmp_path / "out"
    assert run(capsys, "export", db, str(dest))[0] == 0
    with (dest / "landmarks.csv").open(newline="") as fh:
        cells = [c for r in csv.reader(fh) for c in r]
    assert not [c for c in cells if c[:1] in ("=", "+", "@")]
    assert "'-2+3" in cells and '\'=HYPERLINK("http://x")' in cells
    db2 = str(tmp_path / "again.sqlite")
    assert run(capsys, "init", db2, "--origin", "48.85", "2.35")[0] == 0
    assert run(capsys, "import", db2, str(dest))[0] == 0
    with open_db(db2) as again:
        assert sorted(lm.name for lm in again.landmarks()) == sorted(names)


def test_list_and_show_print_names_safely(
    db: str, photos: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    _csv(photos, "f1.png,tower,0,0,3")
    assert run(capsys, "import", db, str(photos))[0] == 0
    evil = "\x1b]0;pwned\x07\x1b[2J\rX\u202e"
    conn = sqlite3.connect(db)  # a file written by something else than our tools
    with conn:
        conn.execute("UPDATE landmarks SET name = ?, source = ?", (evil, evil))
    conn.close()
    for argv in (("list", db), ("show", db, "1")):
        code, out, _ = run(capsys, *argv)
        assert code == 0
        assert not any(ord(ch) < 32 and ch != "\n" for ch in out) and "\u202e" not in out
        assert "\\x1b" in out
    # and our own tools never write such a name
    _csv(photos, 'f2.png,"a\x1b[31mb",0,0,3')
    line = _one_error_line(*run(capsys, "import", db, str(photos))[::2])
    assert "control characters" in line and "\x1b" not in line


@pytest.mark.parametrize(
    ("size", "says"),
    [((1, 1), "smaller than"), ((20000, 2), "smaller than"), ((15000, 15000), "larger than")],
)
def test_image_sizes_are_bounded_before_decoding(
    db: str, photos: Path, capsys: pytest.CaptureFixture[str], size: tuple[int, int], says: str
) -> None:
    (photos / "odd.png").write_bytes(_png(*size))
    _csv(photos, "odd.png,odd,0,0,3")
    t0 = time.monotonic()
    line = _one_error_line(*run(capsys, "import", db, str(photos))[::2])
    assert says in line and f"{size[0]}x{size[1]}" in line
    assert time.monotonic() - t0 < 3.0  # refused from the header: 15000^2 never decoded


def test_a_huge_csv_field_is_one_line(
    db: str, photos: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    for n in (5000, 128 * 1024, 200 * 1024):
        _csv(photos, f"f1.png,{'n' * n},0,0,3")
        line = _one_error_line(*run(capsys, "import", db, str(photos))[::2])
        assert "field" in line
    (photos / "landmarks.csv").write_bytes(b"image,name,x_m,y_m\n\xff\xfe,x,0,0\n")
    assert "UTF-8" in _one_error_line(*run(capsys, "import", db, str(photos))[::2])
    assert _counts(db) == (0, 0)
