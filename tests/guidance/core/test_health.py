"""Input health: the one judge of garbled input (``guidance.core.health.garbled``), asked by the
driver over its last units of data and by the pipeline over the counts since it last looked
(the storm a driver must flag fast: tests/reliability/test_can_faults.py)."""

from __future__ import annotations

import pytest

from drivers.health import HealthTracker
from guidance.core.health import (
    MAX_REJECTED_FRACTION,
    VALIDITY_WINDOW,
    HealthConfig,
    HealthMonitor,
    garbled,
)


def test_garbled_is_more_than_the_limit_rejected() -> None:
    assert garbled(20, 10) == ""  # half rejected: still usable
    assert garbled(20, 11) == "garbled: 55% rejected"
    assert garbled(20, 20) == "garbled: 100% rejected"
    assert garbled(0, 0) == ""  # nothing read: nothing to judge
    assert garbled(10, 4, max_fraction=0.3) == "garbled: 40% rejected"


def _driver_valid(read: int, rejected: int) -> bool:
    t = 100.0
    tracker = HealthTracker("odometry", stale_after_s=1.0, clock=lambda: t)
    tracker.started()
    for k in range(read):
        tracker.data(k >= rejected, t)  # the rejected ones first, the good ones last
    return tracker.evaluate().valid


def _pipeline_health(read: int, rejected: int, config: HealthConfig | None = None) -> bool:
    monitor = HealthMonitor({"odometry": 20.0}, config)
    monitor.observe("odometry", 100.0)
    monitor.update_counts("odometry", read, rejected)
    return monitor.status("odometry", 100.0).valid


@pytest.mark.parametrize("read", [5, 12, VALIDITY_WINDOW])
def test_the_driver_and_the_pipeline_judge_the_same_share_alike(read: int) -> None:
    """Same units, same verdict: one rule, whichever of the two looks."""
    for rejected in range(read):
        expected = not garbled(read, rejected)
        assert _driver_valid(read, rejected) is expected, (read, rejected)
        assert _pipeline_health(read, rejected) is expected, (read, rejected)


def test_the_pipeline_limit_is_the_health_table_and_defaults_to_the_drivers() -> None:
    assert HealthConfig().max_reject_fraction == MAX_REJECTED_FRACTION
    strict = HealthConfig(max_reject_fraction=0.3)
    assert _pipeline_health(20, 7) and not _pipeline_health(20, 7, strict)
    monitor = HealthMonitor({"odometry": 20.0}, strict)
    monitor.observe("odometry", 100.0)
    monitor.update_counts("odometry", 20, 7)
    assert monitor.status("odometry", 100.0).detail == "garbled: 35% rejected"
    monitor.update_counts("odometry", 22, 8)  # too few new reads to judge: the verdict stays
    assert not monitor.status("odometry", 100.0).valid
