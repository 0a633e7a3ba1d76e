"""A killed ``landmark-db import`` leaves a hot journal (issue 14, item 7): the car's
read-only open and ``landmark-db check`` roll it back and work, or, when it cannot be rolled
back, say so in one true line. Real SQLite files, a real ``landmark-db import`` process
killed with SIGKILL mid-transaction."""

from __future__ import annotations

import os
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import cv2
import pytest

from guidance.core.geo import Origin
from hal_sim.sim_camera import facade
from landmark_db.cli import main
from landmark_db.schema import LandmarkDbError
from landmark_db.store import create_db, open_db

PHOTOS = 40


@pytest.fixture
def base(tmp_path: Path) -> Path:
    """A database with one landmark, and a folder of 40 photos to import into it."""
    path = tmp_path / "m.sqlite"
    with create_db(path, Origin(48.85, 2.35)) as db:
        db.add("first", facade(1), x_m=0.0, y_m=0.0)
    folder = tmp_path / "photos"
    folder.mkdir()
    rows = ["image,name,x_m,y_m"]
    for i in range(PHOTOS):
        cv2.imwrite(str(folder / f"p{i}.png"), facade(100 + i))
        rows.append(f"p{i}.png,lm{i},{10.0 * i},5")
    (folder / "landmarks.csv").write_text("\n".join(rows) + "\n")
    return path


def _kill_import_mid_write(path: Path) -> Path:
    """Run ``landmark-db import`` and SIGKILL it while its journal exists."""
    journal = path.with_name(path.name + "-journal")
    proc = subprocess.Popen(
        [sys.executable, "-m", "landmark_db.cli", "import", str(path), str(path.parent / "photos")],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    deadline = time.monotonic() + 60
    size0 = path.stat().st_size
    try:
        # Killed once pages of the transaction have reached the file (before that the journal
        # is not hot: the file is intact and a read-only open rightly reads it as it was).
        while not (journal.exists() and journal.stat().st_size > 0 and path.stat().st_size > size0):
            assert proc.poll() is None, "the import ended before it was killed"
            assert time.monotonic() < deadline
            time.sleep(0.005)
        os.kill(proc.pid, signal.SIGKILL)
    finally:
        proc.wait(10)
    assert proc.returncode == -signal.SIGKILL
    assert journal.exists()
    return journal


_WRITER = """
import os, signal, sqlite3, sys
conn = sqlite3.connect(sys.argv[1])
conn.execute("PRAGMA cache_size = 2")  # pages reach the file before the commit
conn.execute("BEGIN")
conn.execute("INSERT INTO landmarks SELECT id + 1000, name || '2', lat_deg, lon_deg, x_m, y_m,"
             " facing_deg, position_sigma_m, added_utc, source FROM landmarks")
conn.execute("UPDATE photos SET data = data || zeroblob(100000)")
os.kill(os.getpid(), signal.SIGKILL)
"""


def _kill_writer_mid_commit(path: Path) -> Path:
    """Any writer killed inside its transaction (before the import was one transaction, a
    kill inside one row's commit did the same)."""
    proc = subprocess.run([sys.executable, "-c", _WRITER, str(path)], timeout=60)
    assert proc.returncode == -signal.SIGKILL
    journal = path.with_name(path.name + "-journal")
    assert journal.exists()
    return journal


@pytest.mark.parametrize("kill", [_kill_import_mid_write, _kill_writer_mid_commit])
def test_a_killed_import_is_rolled_back_by_the_read_only_open(base: Path, kill: Any) -> None:
    journal = kill(base)
    uri = f"{base.resolve().as_uri()}?mode=ro"
    raw = sqlite3.connect(uri, uri=True)
    with pytest.raises(sqlite3.OperationalError, match="readonly"):  # what the car hit
        raw.execute("SELECT count(*) FROM landmarks").fetchone()
    raw.close()
    with open_db(base) as car:  # the car's read-only open
        assert [lm.name for lm in car.landmarks()] == ["first"]  # the import is all gone
    assert not journal.exists()


def test_landmark_db_check_after_a_killed_import(
    base: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    _kill_writer_mid_commit(base)
    assert main(["check", str(base)]) == 0
    assert "ok (1 landmarks)" in capsys.readouterr().out


def test_a_journal_that_cannot_be_rolled_back_is_named_in_one_line(base: Path) -> None:
    """A writer still inside its transaction (it holds the file): the open waits, then says
    what is there and what to run, instead of "not a landmark database"."""
    writer = sqlite3.connect(base, check_same_thread=False)
    writer.execute("PRAGMA cache_size = 2")
    writer.execute("BEGIN EXCLUSIVE")
    writer.execute("UPDATE photos SET data = data || x'00'")
    try:
        with pytest.raises(LandmarkDbError) as info:
            open_db(base)
    finally:
        writer.rollback()
        writer.close()
    msg = str(info.value)
    assert "\n" not in msg
    assert "m.sqlite-journal" in msg and "landmark-db check" in msg
    assert "not a landmark database" not in msg
