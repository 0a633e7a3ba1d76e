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
