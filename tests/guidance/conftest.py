"""Fixtures shared by the guidance tests (the app's and the pure pipeline's)."""

from __future__ import annotations

import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from guidance.core.localize.estimator import EstimatorConfig
from guidance.core.pipeline import Pipeline, PipelineConfig
from guidance.core.plan.navigator import Method, NavigatorConfig


@pytest.fixture
def make_pipeline() -> Callable[..., Pipeline]:
    """``make_pipeline(**overrides)``: a pipeline heading east from the origin to (1000, 400)
    straight to the goal, with a 20-degree compass and odometry expected at 20 Hz; keywords
    replace any ``PipelineConfig`` field."""

    def make(**kw: Any) -> Pipeline:
        base: dict[str, Any] = {
            "estimator": EstimatorConfig(compass_two_sigma_deg=20.0),
            "navigator": NavigatorConfig(method=Method.STRAIGHT_TO_GOAL),
            "start_xy_m": (0.0, 0.0),
            "goal_xy_m": (1000.0, 400.0),
            "start_heading_rad": 0.0,
            "expected_rates_hz": {"odometry": 20.0},
        }
        base.update(kw)
        return Pipeline(PipelineConfig(**base))

    return make


ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="session")
def sim_landmarks_home(request: pytest.FixtureRequest) -> Path:
    """A folder to run README row 3 from, ``guidance run --config config/sim-landmarks.toml``,
    without writing into the repository: the shipped config copied to ``config/`` (fresh each
    session), its outputs (``../out/sim-landmarks``: the landmark database built on first use,
    about 200 MB and a minute) in ``out/``. The folder is pytest's cache (``.pytest_cache``),
    so the database is built once for every test and every later run that uses it."""
    cache = getattr(request.config, "cache", None)
    if cache is not None:
        home = Path(cache.mkdir("sim-landmarks"))
    else:  # -p no:cacheprovider
        home = request.getfixturevalue("tmp_path_factory").mktemp("sim-landmarks")
    (home / "config").mkdir(exist_ok=True)
    shutil.copy(ROOT / "config" / "sim-landmarks.toml", home / "config" / "sim-landmarks.toml")
    return home


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Under pytest-xdist (``make test``: two workers, ``--dist loadgroup``) the tests that run
    from ``sim_landmarks_home`` go to one worker, in order: the first builds the database in
    the shared folder, and two builds at once would write the same files."""
    for item in items:
        if "sim_landmarks_home" in getattr(item, "fixturenames", ()):
            item.add_marker(pytest.mark.xdist_group("sim-landmarks"))


RAV4_LOGS = tuple(
    ROOT / "tests" / "data" / "realdrives" / name
    for name in ("comma2k19_ex1_kinematics.log", "comma2k19_ex1_wheelspeeds.log")
)
"""The comma2k19 RAV4's real ``KINEMATICS`` 0x24 (yaw rate) and ``WHEEL_SPEEDS`` 0xAA frames."""
RAV4_YAW_ID = 0x24

GYRO_CAR = """
[vehicle]
id = "g1"
yaw_source = "{source}"
[start]
x_m = 0.0
y_m = 0.0
heading_deg = 90.0
[goal]
x_m = 0.0
y_m = 5000.0
[estimator]
compass_two_sigma_deg = false
[odometry]
interface = "virtual"
channel = "{channel}"
profile = "toyota"
expected_rate_hz = 80.0
[compass]
enabled = false
[scene]
keyboard = false
[voice]
backend = "none"
[checkpoint]
path = "ck.json"
learned_path = "learned.json"
[telemetry]
enabled = false
[recording]
directory = "rec"
"""
"""A gyro car on those frames (``GYRO_CAR.format(source=..., channel=...)``): the Toyota
profile on a python-can virtual bus, no compass, a checkpoint, a learned file, a recording."""


@pytest.fixture
def rav4_frames() -> Callable[[float], list[Any]]:
    """``rav4_frames(span_s)``: the first ``span_s`` of both RAV4 logs, in time order."""
    import heapq

    from drivers.can_odometry import LogReadResult, read_can_log

    def frames(span_s: float) -> list[Any]:
        logs = [list(read_can_log(p, LogReadResult())) for p in RAV4_LOGS]
        merged = list(heapq.merge(*logs, key=lambda m: m.timestamp))
        t0 = merged[0].timestamp
        return [m for m in merged if m.timestamp - t0 < span_s]

    return frames


@pytest.fixture
def gyro_car() -> str:
    """``GYRO_CAR``: a gyro car's TOML on the RAV4's frames."""
    return GYRO_CAR
