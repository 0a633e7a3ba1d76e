"""Fixtures for the driver tests: leak checks (threads, python-can buses, ptys) and data paths."""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from contextlib import AbstractContextManager
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
TEST_DATA = REPO / "tests" / "data"
SHARED_DATA = Path(os.environ.get("GUIDANCE_SHARED_DATA", REPO.parent / "shared" / "data"))


@pytest.fixture(autouse=True)
def no_leaks(leak_check: Callable[..., AbstractContextManager[None]]) -> Iterator[None]:
    """Fail a test that leaves a thread running, a virtual CAN bus open or a pty open."""
    with leak_check(grace_s=2.0):
        yield


@pytest.fixture
def shared_data() -> Path:
    """../shared/data (GPL and large real logs); the test is skipped when it is absent."""
    if not SHARED_DATA.is_dir():
        pytest.skip(f"shared data folder {SHARED_DATA} not present (optional real-data check)")
    return SHARED_DATA
