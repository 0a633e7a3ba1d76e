"""Fixtures for the landmark tests: small synthetic databases, shared data, thread-leak check."""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from contextlib import AbstractContextManager
from pathlib import Path

import numpy as np
import pytest

from hal_sim.sim_camera import SimLandmark, build_sim_landmark_db
from landmark_db.store import LandmarkDb

REPO = Path(__file__).resolve().parents[2]
SHARED_DATA = Path(os.environ.get("GUIDANCE_SHARED_DATA", REPO.parent / "shared" / "data"))

CITY_SEED = 20
LANDMARK_XY = np.array([[0.0, 0.0], [300.0, 0.0], [0.0, 300.0], [300.0, 300.0], [150.0, 150.0]])
"""Five landmarks, far enough apart that a 20 m gate around one never holds another."""


@pytest.fixture(autouse=True)
def no_leaked_threads(leak_check: Callable[..., AbstractContextManager[None]]) -> Iterator[None]:
    """Fail a test that leaves a thread running (executors must be shut down)."""
    with leak_check(grace_s=2.0, virtual_can=False, ptys=False):
        yield


@pytest.fixture(scope="session")
def sim_db_path(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[SimLandmark]]:
    """A synthetic five-landmark database (built once per session; tests open it read-only)."""
    path = tmp_path_factory.mktemp("landmarks") / "city.sqlite"
    db, lms = build_sim_landmark_db(path, LANDMARK_XY, CITY_SEED)
    db.close()
    return path, lms


@pytest.fixture
def sim_db(sim_db_path: tuple[Path, list[SimLandmark]]) -> Iterator[LandmarkDb]:
    from landmark_db.store import open_db

    db = open_db(sim_db_path[0])
    yield db
    db.close()


@pytest.fixture
def shared_images() -> Path:
    """../shared/data/images; the test is skipped when it is absent (it is optional)."""
    folder = SHARED_DATA / "images"
    if not folder.is_dir():
        pytest.skip(f"shared image folder {folder} not present (optional real-data check)")
    return folder
