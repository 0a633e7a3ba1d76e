"""The SQLite store: round trips, read-only opening, validation, migrations, integrity check."""

from __future__ import annotations

import sqlite3
from pathlib import Path

import numpy as np
import pytest

from guidance.core.geo import Origin
from hal_sim.sim_camera import facade
from landmark_db.features import Features, OrbConfig, decode_image, encode_image
from landmark_db.store import (
    SCHEMA_VERSION,
    LandmarkDb,
    LandmarkDbError,
    create_db,
    open_db,
    query_radius,
)

ORIGIN = Origin(42.444, -76.5019)


def _db(tmp_path: Path, n: int = 3) -> LandmarkDb:
    db = create_db(tmp_path / "t.sqlite", ORIGIN, OrbConfig(n_features=300))
    for i in range(n):
        db.add(f"lm{i}", facade(100 + i), x_m=50.0 * i, y_m=-20.0 * i, facing_deg=90.0 * i)
    return db


def test_round_trip_positions_photo_and_features(tmp_path: Path) -> None:
    db = _db(tmp_path)
    lat, lon = ORIGIN.to_geodetic(120.0, -80.0)
    photo = encode_image(facade(7), ".jpg")
    lid = db.add("corner", photo, lat_deg=lat, lon_deg=lon, position_sigma_m=4.0)
    db.close()
    with open_db(tmp_path / "t.sqlite") as ro:
        assert len(ro) == 4
        lm = ro.get(lid)
        assert lm is not None and lm.name == "corner" and lm.position_sigma_m == 4.0
        assert lm.x_m == pytest.approx(120.0, abs=0.01) and lm.y_m == pytest.approx(-80.0, abs=0.01)
        fmt, data = ro.image_bytes(lid) or ("", b"")
        assert fmt == "jpeg" and data == photo
        f = ro.features(lid)
        assert f is not None and 50 < len(f) <= 300
        assert f.descriptors.dtype == np.uint8 and f.descriptors.shape[1] == 32
        assert ro.find("corner") == lm and ro.find(str(lid)) == lm
        assert [x.name for x in ro.landmarks()] == ["lm0", "lm1", "lm2", "corner"]
        assert ro.get(2) is not None and ro.get(2).facing_deg == 90.0  # type: ignore[union-attr]
        assert ro.check().ok


def test_find_reads_only_ascii_digits_as_an_id(tmp_path: Path) -> None:
    """Issue 40 (noticed): ``find("٣")`` returned landmark 3, since ``int`` reads Arabic-Indic
    (and full-width) digits; only ASCII digits are an id, and an id beyond SQLite's integers is
    no landmark (not an OverflowError)."""
    db = _db(tmp_path, n=4)
    third = db.get(3)
    assert third is not None and db.find("3") == third and db.find("lm2") == third
    # 3 in Arabic-Indic, Persian, full-width and Devanagari digits
    for key in ("\u0663", "\u06f3", "\uff13", "\u0969"):
        assert db.find(key) is None, key
    assert db.find("9" * 30) is None and db.find("0" * 18 + "3") is None
    db.close()


def test_local_frame_matches_pymap3d_over_a_city(tmp_path: Path) -> None:
    for x, y in [(0.0, 0.0), (5000.0, 0.0), (0.0, -5000.0), (7000.0, 7000.0)]:
        lat, lon = ORIGIN.to_geodetic(x, y)
        bx, by = ORIGIN.to_local(lat, lon)
        # lat/lon drop the height of the tangent plane (2 m at 5 km): round trip within 1 cm
        assert abs(bx - x) < 0.01 and abs(by - y) < 0.01
    # 1 degree of latitude is about 111 km
    _, north = ORIGIN.to_local(ORIGIN.lat_deg + 0.01, ORIGIN.lon_deg)
    assert north == pytest.approx(1111.0, rel=0.01)


def test_read_only_open_refuses_writes(tmp_path: Path) -> None:
    _db(tmp_path).close()
    with open_db(tmp_path / "t.sqlite") as ro:
        with pytest.raises(LandmarkDbError, match="read-only"):
            ro.add("x", facade(1), x_m=0.0, y_m=0.0)
        with pytest.raises(sqlite3.OperationalError, match="readonly"):
            ro._conn.execute("DELETE FROM landmarks")


@pytest.mark.parametrize(
    "content",
    [b"", b"this is not a database at all" * 100, b"SQLite format 3\x00" + b"\x00" * 80],
)
def test_bad_files_give_one_clear_error(tmp_path: Path, content: bytes) -> None:
    p = tmp_path / "bad.sqlite"
    p.write_bytes(content)
    with pytest.raises(LandmarkDbError, match=r"bad\.sqlite"):
        open_db(p)
    with pytest.raises(LandmarkDbError, match="no such"):
        open_db(tmp_path / "missing.sqlite")


def test_other_sqlite_database_is_rejected(tmp_path: Path) -> None:
    p = tmp_path / "other.sqlite"
    c = sqlite3.connect(p)
    c.execute("CREATE TABLE t (a)")
    c.commit()
    c.close()
    with pytest.raises(LandmarkDbError, match="not a landmark database"):
        open_db(p)


def test_truncated_file_is_reported(tmp_path: Path) -> None:
    _db(tmp_path, 4).close()
    p = tmp_path / "t.sqlite"
    data = p.read_bytes()
    p.write_bytes(data[: len(data) // 2])
    with pytest.raises(LandmarkDbError):
        db = open_db(p)
        report = db.check()
        db.close()
        if not report.ok:
            raise LandmarkDbError("; ".join(report.problems))


def test_check_finds_inconsistencies(tmp_path: Path) -> None:
    db = _db(tmp_path)
    assert db.check().ok
    c = db._conn
    with c:
        c.execute("DELETE FROM landmark_index WHERE id = 1")
        c.execute("UPDATE photos SET data = x'00' WHERE landmark_id = 2")
        c.execute("DELETE FROM photo_features WHERE photo_id = 3")
        c.execute("INSERT INTO landmark_index VALUES (99, 1, 1, 1, 1)")
    report = db.check()
    text = "\n".join(report.problems)
    assert not report.ok
    assert "without an index box: 1" in text
    assert "landmark 2 photo 2: checksum mismatch" in text
    assert "with a photo without features: 3" in text
    assert "index box for no landmark: 99" in text
    db.close()


def test_remove_keeps_the_file_consistent(tmp_path: Path) -> None:
    db = _db(tmp_path)
    assert db.remove(2) and not db.remove(2)
    assert len(db) == 2 and db.check().ok
    assert [c.id for c in query_radius(db, 50.0, -20.0, 5.0)] == []
    db.close()


def _v2_file(path: Path, n: int = 3) -> list[np.ndarray]:
    """A version-2 file as the previous release wrote it: one photo per landmark in
    ``images``, its ORB features in ``features``."""
    from landmark_db.features import extract
    from landmark_db.schema import V1, V2

    photos = [facade(100 + i) for i in range(n)]
    c = sqlite3.connect(path)
    c.executescript(f"BEGIN; {V1} {V2} COMMIT;")
    with c:
        c.executemany(
            "INSERT INTO metadata VALUES (?, ?)",
            [("origin_lat_deg", "42.444"), ("origin_lon_deg", "-76.5019"), ("origin_alt_m", "0.0"),
             ("orb_n_features", "300"), ("orb_max_side_px", "1024"), ("created_utc", "x")],
        )  # fmt: skip
        for i, photo in enumerate(photos, start=1):
            lat, lon = ORIGIN.to_geodetic(50.0 * i, 0.0)
            c.execute(
                "INSERT INTO landmarks VALUES (?, ?, ?, ?, ?, 0, NULL, 3.0, 'x', 's')",
                (i, f"lm{i}", lat, lon, 50.0 * i),
            )
            data = encode_image(photo)
            c.execute(
                "INSERT INTO images VALUES (?, 'png', 640, 480, ?, ?)",
                (i, __import__("hashlib").sha256(data).hexdigest(), data),
            )
            f = extract(photo, OrbConfig(n_features=300))
            c.execute(
                "INSERT INTO features VALUES (?, ?, ?, ?, ?, ?)",
                (i, len(f), f.width, f.height, f.keypoint_blob(), f.descriptor_blob()),
            )
            c.execute("INSERT INTO landmark_index VALUES (?, ?, ?, 0, 0)", (i, 50.0 * i, 50.0 * i))
    c.close()
    return photos


def test_migration_from_v2_keeps_photos_and_features(tmp_path: Path) -> None:
    p = tmp_path / "t.sqlite"
    photos = _v2_file(p)
    with pytest.raises(LandmarkDbError, match="older than"):
        open_db(p)  # the car never writes: it asks for a migration
    open_db(p, readonly=False).close()
    with open_db(p) as ro:
        v = ro._conn.execute("SELECT version FROM schema_version").fetchone()[0]
        assert v == SCHEMA_VERSION and len(ro) == 3 and ro.check().ok
        assert ro.extractor.ident == "orb/1:300@1024"  # the file keeps its extractor
        assert [ph.id for ph in ro.photos(2)] == [2]
        f = ro.features(2)
        assert f is not None and f.kind == "orb" and f.descriptors.shape[1] == 32
        from landmark_db.recognise import Recogniser

        assert Recogniser(ro).match_image(photos[1]).landmark_id == 2


def test_refresh_features_recomputes_for_a_new_extractor_or_version(tmp_path: Path) -> None:
    from landmark_db.features import ExtractorConfig

    p = tmp_path / "t.sqlite"
    _v2_file(p)
    with open_db(p, readonly=False) as db:
        assert db.refresh_features() == 0  # nothing stale
        assert db.refresh_features(ExtractorConfig("rootsift", 500, 640)) == 3
    with open_db(p) as ro:
        f = ro.features(1)
        assert ro.extractor.ident == "rootsift/2:500@640" and ro.check().ok
        assert f is not None and f.kind == "rootsift" and f.descriptors.shape[1] == 128
    with sqlite3.connect(p) as c:  # as if written by an older version of the extractor
        c.execute("UPDATE photo_features SET extractor = 'rootsift/0:500@640' WHERE photo_id = 2")
    c.close()
    with pytest.raises(LandmarkDbError, match="landmark-db migrate"):
        open_db(p)
    with open_db(p, readonly=False) as db:
        assert "features from rootsift/0" in " ".join(db.check().problems)
        assert db.refresh_features() == 1
    open_db(p).close()


def test_newer_schema_is_refused(tmp_path: Path) -> None:
    db = _db(tmp_path, 0)
    with db._conn as c:
        c.execute("UPDATE schema_version SET version = 99")
    db.close()
    with pytest.raises(LandmarkDbError, match="newer"):
        open_db(tmp_path / "t.sqlite", readonly=False)


def test_add_rejects_bad_input(tmp_path: Path) -> None:
    db = _db(tmp_path, 0)
    with pytest.raises(LandmarkDbError, match="position"):
        db.add("x", facade(1))
    with pytest.raises(LandmarkDbError, match="out of range"):
        db.add("x", facade(1), lat_deg=95.0, lon_deg=0.0)
    with pytest.raises(LandmarkDbError, match="finite"):
        db.add("x", facade(1), x_m=float("nan"), y_m=0.0)
    with pytest.raises(LandmarkDbError, match="decode"):
        db.add("x", b"not an image", x_m=0.0, y_m=0.0)
    assert len(db) == 0
    db.close()
    with pytest.raises(LandmarkDbError, match="exists"):
        create_db(tmp_path / "t.sqlite", ORIGIN)


def test_feature_blobs_round_trip_and_reject_garbage() -> None:
    img = facade(3)
    from landmark_db.features import extract

    f = extract(img, OrbConfig(n_features=200))
    g = Features.from_blobs(f.keypoint_blob(), f.descriptor_blob(), f.width, f.height)
    assert np.array_equal(f.keypoints, g.keypoints) and np.array_equal(f.descriptors, g.descriptors)
    with pytest.raises(ValueError):
        Features.from_blobs(f.keypoint_blob()[:-4], f.descriptor_blob(), f.width, f.height)
    assert decode_image(encode_image(img)).shape == img.shape


def test_a_new_file_is_open_as_open_db_opens_one_foreign_keys_on(tmp_path: Path) -> None:
    """create_db and open_db give the same connection: the schema's ON DELETE CASCADE holds
    from the first write, not only after the file is reopened."""
    from guidance.core.geo import Origin
    from landmark_db.store import create_db

    with create_db(tmp_path / "new.sqlite", Origin(42.444, -76.5019)) as db:
        assert db._conn.execute("PRAGMA foreign_keys").fetchone()[0] == 1
