"""Fixtures for the fault-matrix, fuzz and security tests: leak checks and small helpers."""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import can.interfaces.virtual
import pytest


def _pty_fds() -> set[str]:
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
    deadline = time.monotonic() + 3.0
    while True:
        extra = [
            t
            for t in threading.enumerate()
            if t not in threads and t.is_alive() and not t.name.startswith(("pyo3", "zenoh"))
        ]
        if not extra or time.monotonic() > deadline:
            break
        time.sleep(0.01)
    assert not extra, f"leaked threads: {extra}"
    assert not can.interfaces.virtual.channels, (
        f"leaked virtual CAN buses: {list(can.interfaces.virtual.channels)}"
    )
    leaked = _pty_fds() - ptys
    assert not leaked, f"leaked pty file descriptors: {leaked}"
