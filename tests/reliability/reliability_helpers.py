"""Helpers shared by the reliability tests (imported by name: this folder is on sys.path)."""

from __future__ import annotations

import socket
import time
from collections.abc import Callable
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]

HEALTH_KEYS = frozenset(
    {"name", "status", "alive", "valid", "ok", "age_s", "detail", "warning", "counters", "info"}
)
"""Keys every ``Health.as_dict()`` carries, a driver's or a component's (docs/reliability.md)."""


def wait_until(cond: Callable[[], bool], timeout_s: float = 5.0, what: str = "") -> None:
    deadline = time.monotonic() + timeout_s
    while not cond():
        assert time.monotonic() < deadline, f"timed out waiting for {what or cond}"
        time.sleep(0.003)


def closed_port() -> int:
    """A loopback TCP port nobody listens on (bound, then released)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class FakeClock:
    """A clock the test moves by hand (the drivers' ``clock`` parameter)."""

    def __init__(self, t: float = 0.0) -> None:
        self.t = t

    def __call__(self) -> float:
        return self.t
