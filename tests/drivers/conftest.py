"""Fixtures for the driver tests: leak checks (threads, python-can buses, ptys) and data paths."""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import can.interfaces.virtual
import pytest

REPO = Path(__file__).resolve().parents[2]
TEST_DATA = REPO / "tests" / "data"
SHARED_DATA = Path(os.environ.get("GUIDANCE_SHARED_DATA", REPO.parent / "shared" / "data"))


def _pty_fds() -> set[str]:
    """Open file descriptors of this process that point at pseudo-terminals."""
    out = set()
    fd_dir = Path("/proc/self/fd")
    for entry in fd_dir.iterdir() if fd_dir.exists() else ():
        try:
            target = os.readlink(entry)
        except OSError:
            continue
        if target.startswith(("/dev/pts/", "/dev/ptmx")):
            out.add(f"{entry.name}->{target}")
    return out


@pytest.fixture(autouse=True)
def no_leaks() -> Iterator[None]:
    """Fail a test that leaves a thread running, a virtual CAN bus open or a pty open."""
    threads = set(threading.enumerate())
    ptys = _pty_fds()
    yield
    deadline = time.monotonic() + 2.0
    while True:
        extra = [t for t in threading.enumerate() if t not in threads and t.is_alive()]
        if not extra or time.monotonic() > deadline:
            break
        time.sleep(0.01)
    assert not extra, f"leaked threads: {extra}"
    assert not can.interfaces.virtual.channels, (
        f"leaked virtual CAN buses: {list(can.interfaces.virtual.channels)}"
    )
    leaked = _pty_fds() - ptys
    assert not leaked, f"leaked pty file descriptors: {leaked}"


@pytest.fixture
def shared_data() -> Path:
    """../shared/data (GPL and large real logs); the test is skipped when it is absent."""
    if not SHARED_DATA.is_dir():
        pytest.skip(f"shared data folder {SHARED_DATA} not present (optional real-data check)")
    return SHARED_DATA
