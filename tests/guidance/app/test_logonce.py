"""The app logs a repeating failure once and its recovery once (ARCHITECTURE.md section 2)."""

from __future__ import annotations

import logging

import pytest

from guidance.app.logonce import LogOnce


def test_a_repeating_failure_is_logged_once_and_its_recovery_once(
    caplog: pytest.LogCaptureFixture,
) -> None:
    log = logging.getLogger("test.logonce")
    failures = LogOnce(log)
    with caplog.at_level(logging.WARNING, logger="test.logonce"):
        for _ in range(100):
            try:
                raise RuntimeError("stats broke")
            except RuntimeError:
                failures.failed("odometry: stats()")
        failures.ok("odometry: stats()")
        failures.ok("odometry: stats()")
    messages = [r.getMessage() for r in caplog.records]
    assert len(messages) == 2
    assert "odometry: stats() failed" in messages[0] and caplog.records[0].exc_info
    assert "works again after 100 failures" in messages[1]
    assert failures.counts["odometry: stats()"] == 100
