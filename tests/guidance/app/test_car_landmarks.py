"""Landmarks in ``guidance run``: a database built with ``landmark-db import``, opened read-only
by the car, its names in the prompts, and ``--check`` saying what cannot work (issue 13)."""

from __future__ import annotations

import csv
import io
import math
import re
from contextlib import redirect_stderr, redirect_stdout
from dataclasses import replace
from pathlib import Path

import cv2
import pytest

from guidance.app.config import load_config
from guidance.app.landmarks import landmark_warnings, open_landmarks
from guidance.core.messages import Ellipse, EstimateState
from guidance.errors import UserError
from guidance.tools.cli import main
from hal_sim.sim_camera import SimCamera, SimLandmark, facade, photo_seed
from landmark_db.cli import main as landmark_db

PLACES = [("the town hall", 40.0, 0.0), ("the bakery", 160.0, 0.0), ("the red church", 40.0, 120.0)]
SEED = 5
ELLIPSE = Ellipse(10.0, 10.0, 0.0, 20.0)

CAR = """
[vehicle]
id = "lm1"
track_m = 1.62

[start]
x_m = 0.0
y_m = 0.0
heading_deg = 90.0

[goal]
x_m = 400.0
y_m = 0.0

[odometry]
backend = "can"
interface = "virtual"
channel = "lm-test"
profile = "toyota"

[compass]
enabled = false

[estimator]
compass_two_sigma_deg = false

[camera]
enabled = {camera}

[landmarks]
database = "db/city.sqlite"
sighting_range_m = 25.0
"""


@pytest.fixture(scope="module")
def city(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A landmark database made the way a user makes one: photos + CSV + landmark-db import."""
    root = tmp_path_factory.mktemp("city")
    photos = root / "photos"
    photos.mkdir()
    with (photos / "landmarks.csv").open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["image", "name", "x_m", "y_m", "sigma_m"])
        for i, (name, x, y) in enumerate(PLACES):
            cv2.imwrite(str(photos / f"p{i}.png"), facade(photo_seed(SEED, i)))
            w.writerow([f"p{i}.png", name, x, y, 1.0])
    (root / "db").mkdir()
    db = root / "db" / "city.sqlite"
    with redirect_stdout(io.StringIO()):
        assert landmark_db(["init", str(db), "--origin", "42.444", "-76.5019"]) in (0, None)
        assert landmark_db(["import", str(db), str(photos)]) in (0, None)
    return root


def _config(city: Path, camera: bool) -> Path:
    cfg = city / f"car-{camera}.toml"
    cfg.write_text(CAR.replace("{camera}", "true" if camera else "false"))
    return cfg


def test_the_car_opens_the_database_and_its_real_recogniser_gives_a_named_fix(city: Path) -> None:
    cfg = load_config(_config(city, camera=True))
    assert cfg.landmark_db is not None
    assert cfg.landmark_db.database == str(city / "db" / "city.sqlite")  # relative to the TOML
    recogniser, landmarks = open_landmarks(cfg.landmark_db, cfg.origin_lat_lon_deg)
    assert sorted(lm.name for lm in landmarks) == sorted(p[0] for p in PLACES)
    hall = next(lm for lm in landmarks if lm.name == "the town hall")
    assert (hall.x_m, hall.y_m) == pytest.approx((40.0, 0.0), abs=1e-6)
    camera = SimCamera([SimLandmark(hall.id, hall.x_m, hall.y_m, photo_seed(SEED, 0))], SEED)
    cov = ((25.0, 0.0, 0.0), (0.0, 25.0, 0.0), (0.0, 0.0, 0.01))
    fixes = []
    for k in range(4):  # driving past it: the recogniser confirms over consecutive frames
        t = 10.0 + 0.5 * k
        state = EstimateState(t, 30.0 + 2 * k, 0.0, 0.0, cov, ELLIPSE, False, True)
        result = recogniser.process(camera.frame_at(t, 30.0 + 2 * k, 0.0), state)
        fix = getattr(result, "fix", result)
        if fix is not None:
            fixes.append(fix)
    recogniser.close()
    assert fixes and fixes[0].landmark_id == hall.id


def test_check_says_what_cannot_work(city: Path, capsys: pytest.CaptureFixture[str]) -> None:
    no_camera = load_config(_config(city, camera=False))
    assert any("no [camera]" in w for w in landmark_warnings(no_camera))
    assert main(["run", "--config", str(_config(city, camera=False)), "--check"]) == 0
    assert "no landmark will ever be sighted" in capsys.readouterr().err
    bare = city / "camera-only.toml"
    bare.write_text(CAR.replace("{camera}", "true").split("[landmarks]")[0])
    assert any("no [landmarks] database" in w for w in landmark_warnings(load_config(bare)))


def test_a_missing_or_damaged_database_is_one_clear_line(city: Path) -> None:
    bad = city / "db" / "broken.sqlite"
    bad.write_bytes(b"SQLite format 3\x00" + b"\x00" * 100)
    for db in ("db/nothing.sqlite", "db/broken.sqlite"):
        cfg = city / "bad.toml"
        cfg.write_text(CAR.replace("{camera}", "true").replace("db/city.sqlite", db))
        with pytest.raises(UserError, match=r"\[landmarks\] database"):
            landmark_warnings(load_config(cfg))
        err = io.StringIO()
        with redirect_stderr(err):
            assert main(["run", "--config", str(cfg), "--check"]) == 2
        assert "Traceback" not in err.getvalue()


@pytest.mark.parametrize(
    ("table", "why"),
    [
        ('database = ""', "database"),
        ('database = "x.sqlite"\nsighting_range_m = 0', "sighting_range_m"),
        ('database = "x.sqlite"\nconfirm_frames = 0', "confirm_frames"),
        ('database = "x.sqlite"\nfoo = 1', "unknown"),
    ],
)
def test_bad_landmarks_tables_are_rejected(tmp_path: Path, table: str, why: str) -> None:
    cfg = tmp_path / "car.toml"
    cfg.write_text(
        CAR.replace("{camera}", "true").split("[landmarks]")[0] + "[landmarks]\n" + table
    )
    with pytest.raises(UserError, match=why):
        load_config(cfg)


def test_guidance_run_on_the_simulated_devices_reaches_its_goal_with_a_landmark_fix(
    sim_landmarks_home: Path,
) -> None:
    """The shipped config: the car process on the simulated devices (virtual CAN, compass pty,
    simulated camera, a database built with landmark-db import on first use, shared with the
    other tests of that config through ``sim_landmarks_home``); the --json summary is the last
    line."""
    import json
    import subprocess
    import sys

    r = subprocess.run(
        [sys.executable, "-m", "guidance.tools.cli", "run", "--config",
         "config/sim-landmarks.toml", "--json"],
        cwd=sim_landmarks_home, capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert r.returncode == 0, r.stderr[-2000:]
    summary = json.loads(r.stdout.splitlines()[-1])
    assert summary["outcome"] == "arrived"
    assert summary["landmark_updates"] >= 1 and summary["prompts"] >= 1
    assert "Passing the " in r.stdout  # the landmark's name, never its id
    assert "Traceback" not in r.stderr
    # what docs/app.md says of this drive
    doc = (Path(__file__).resolve().parents[3] / "docs" / "app.md").read_text()
    said = re.search(r"seed 3: arrived after ([\d.]+) km with (\d+) landmark fixes, in (\d+) "
                     r"simulated seconds", " ".join(doc.split()))  # fmt: skip
    assert said, "docs/app.md no longer says how the seed 3 drive goes"
    assert said.groups() == (f"{summary['driven_km']:.2f}", str(summary["landmark_updates"]),
                             f"{summary['sim_s']:.0f}"), summary  # fmt: skip


def _anywhere(city: Path, start: str, camera: bool = True) -> Path:
    cfg = city / "anywhere.toml"
    text = CAR.replace("{camera}", "true" if camera else "false")
    text = text.replace("x_m = 0.0\ny_m = 0.0\nheading_deg = 90.0", start)
    cfg.write_text(text.replace("sighting_range_m = 25.0", "sighting_range_m = 20.0"))
    return cfg


def test_a_car_that_starts_anywhere_finds_itself_at_a_landmark_then_guides(city: Path) -> None:
    """Issue 36, "start anywhere": ``[start]`` with no position. The car starts lost, says so,
    withholds advice, and the real recogniser searches the whole database (``state.lost``);
    its find resets the position around the place, said by name, and guidance begins."""
    from guidance.core.messages import HeadingFix, IntersectionScene, WheelOdometry
    from guidance.core.pipeline import Pipeline

    cfg = load_config(_anywhere(city, "unknown = true\nheading_deg = 90.0"))
    assert cfg.pipeline.start_unknown and cfg.pipeline.relocalise
    assert cfg.pipeline.start_xy_m == cfg.pipeline.goal_xy_m  # where it waits, city-wide
    recogniser, landmarks = open_landmarks(cfg.landmark_db, cfg.origin_lat_lon_deg)
    pipeline = Pipeline(replace(cfg.pipeline, landmarks=tuple(landmarks)))
    said = []
    out = pipeline.feed(WheelOdometry(0.1, 0.5, 0.5))
    said += [p.text for p in out.prompts]
    assert said == ["Position unknown. Drive on; looking for a known place"]
    out = pipeline.feed(IntersectionScene(0.2, (0.0, math.pi / 2), 50.0))
    assert not out.prompts and not out.decisions  # kept, undecided and unsaid
    hall = next(lm for lm in landmarks if lm.name == "the town hall")
    camera = SimCamera([SimLandmark(hall.id, hall.x_m, hall.y_m, photo_seed(SEED, 0))], SEED)
    t, x = 0.2, 30.0  # the truth: driving east past the town hall (the car does not know)
    for _ in range(8):
        t, x = t + 0.5, x + 2.0
        pipeline.feed(WheelOdometry(t, 2.0, 2.0))
        pipeline.feed(HeadingFix(t, 0.0))
        state = pipeline.estimate
        assert state.lost  # the whole database is searched
        result = recogniser.process(camera.frame_at(t, x, 0.0), state)
        if result.fix is not None:
            out = pipeline.feed(result.fix)
            said += [p.text for p in out.prompts]
            break
    recogniser.close()
    assert "Position found near the town hall" in said, said
    est = pipeline.estimate
    assert est.ellipse.major_axis_m < 100.0
    assert math.hypot(est.x_m - x, est.y_m) < 40.0
    out = pipeline.feed(IntersectionScene(t + 0.1, (0.0, math.pi / 2), 80.0))
    assert out.decisions  # guidance has begun


def test_start_anywhere_is_refused_where_the_car_could_never_find_itself(city: Path) -> None:
    with pytest.raises(UserError, match="must find itself"):
        load_config(_anywhere(city, "unknown = true\nheading_deg = 90.0", camera=False))
    with pytest.raises(UserError, match="give one or the other"):
        load_config(_anywhere(city, "unknown = true\nx_m = 3.0\nheading_deg = 90.0"))
    geo = city / "geo.toml"  # no position and a goal on the globe: the frame is the goal's
    text = _anywhere(city, "heading_deg = 90.0").read_text()
    geo.write_text(text.replace("x_m = 400.0\ny_m = 0.0", "lat_deg = 42.444\nlon_deg = -76.4970"))
    cfg = load_config(geo)
    assert cfg.pipeline.start_unknown and cfg.origin_lat_lon_deg == (42.444, -76.4970)
    assert landmark_warnings(cfg) == []
    wide = city / "wide.toml"  # a reset as wide as lost: said by --check
    wide.write_text(geo.read_text().replace("sighting_range_m = 20.0", "sighting_range_m = 25.0"))
    assert any("can never find itself" in w for w in landmark_warnings(load_config(wide)))
