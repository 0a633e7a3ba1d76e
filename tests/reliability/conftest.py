"""Fixtures for the fault-matrix, fuzz and security tests: leak checks and small helpers."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import AbstractContextManager

import pytest


@pytest.fixture(autouse=True)
def no_leaks(leak_check: Callable[..., AbstractContextManager[None]]) -> Iterator[None]:
    """Fail a test that leaves a thread running, a virtual CAN bus open or a pty open."""
    with leak_check(grace_s=3.0, ignore_threads=("pyo3", "zenoh")):
        yield
