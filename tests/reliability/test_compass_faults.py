"""Compass faults on a real pseudo-terminal, read by the real pyserial SerialCompass driver.

One drive, east at 10 m/s (compass 90 degrees, declination 0), 10 Hz compass, in phases:
good headings; garbage bytes mixed with good headings; only sentences with broken checksums
that claim a wrong heading (270 degrees); the adapter unplugged, then plugged back in; good
headings again. The health record goes ok -> ok (garbage counted) -> invalid -> disconnected ->
ok, each with its warning; no bad line ever becomes a heading; and the estimator, fed with the
odometry and what the driver let through, keeps the right heading while its uncertainty grows
during the fault (inflated, not corrupted).
"""

from __future__ import annotations

import logging
import math
import random
from collections.abc import Iterator

import numpy as np
import pytest
from reliability_helpers import HEALTH_KEYS, FakeClock, wait_until

from drivers.compass import SerialCompass, SerialCompassConfig
from guidance.core.localize.compass_cal import compass_heading_to_theta
from guidance.core.localize.estimator import EstimatorConfig, PoseEstimator
from guidance.core.messages import CompassHeading, HeadingFix, WheelOdometry
from hal_sim.sim_compass import SimCompassPty

RATE_HZ = 10.0
DT = 1.0 / RATE_HZ


@pytest.fixture
def sim() -> Iterator[SimCompassPty]:
    with SimCompassPty() as s:
        yield s


def estimate(headings: list[CompassHeading], t_end: float) -> tuple[PoseEstimator, list[float]]:
    """Odometry (1 m east every 0.1 s) and the delivered headings, in time order; the heading
    variance after each odometry step."""
    est = PoseEstimator(EstimatorConfig(compass_two_sigma_deg=10.0))
    inputs: list[WheelOdometry | HeadingFix] = [
        HeadingFix(h.t_s, compass_heading_to_theta(h, 0.0)) for h in headings
    ]
    n = round(t_end / DT)
    inputs += [WheelOdometry(k * DT + DT / 2, 1.0, 1.0) for k in range(n)]
    inputs.sort(key=lambda m: m.t_s)
    var_theta = []
    for msg in inputs:
        est.process(msg)
        if isinstance(msg, WheelOdometry):
            var_theta.append(float(est.P[2, 2]))
    assert np.all(np.isfinite(est.x)) and np.all(np.isfinite(est.P))
    return est, var_theta


def test_garbage_checksums_unplug_and_replug(
    sim: SimCompassPty, caplog: pytest.LogCaptureFixture
) -> None:
    clock = FakeClock()
    cfg = SerialCompassConfig(
        port=sim.port,
        read_timeout_s=0.02,
        reconnect_initial_s=0.02,
        reconnect_max_s=0.2,
        stale_after_s=1.0,
    )
    compass = SerialCompass(cfg, clock=clock)
    got: list[CompassHeading] = []
    rng = random.Random(3)
    k = 0  # compass sample index: time k * DT

    def tick(write: bool = True, **kw: bool) -> None:
        nonlocal k
        clock.t = k * DT
        before = compass.parser.lines
        if write:
            sim.write_heading(90.0, **kw)
            wait_until(lambda: compass.parser.lines > before, what="line read")
        k += 1

    with caplog.at_level(logging.WARNING):
        compass.start(got.append)
        try:
            wait_until(lambda: compass.connected)
            for _ in range(20):  # 0-2 s: good
                tick()
            assert compass.health().status == "ok"

            noise = [b for b in range(256) if b not in b"\r\n"]
            for i in range(20):  # 2-4 s: a burst of line noise after every other sentence
                if i % 2:
                    sim.write_raw(bytes(rng.choice(noise) for _ in range(40)) + b"\r\n")
                tick()
            h = compass.health()
            assert h.ok, h  # mostly good: counted, no alarm
            assert h.counters["rejected"] == 10

            for _ in range(20):  # 4-6 s: every sentence claims 270 deg with a broken checksum
                clock.t = k * DT
                before = compass.parser.lines
                sim.write_heading(270.0, corrupt_checksum=True)
                wait_until(lambda: compass.parser.lines > before)  # noqa: B023
                k += 1
            h = compass.health()
            assert (h.status, h.alive, h.valid) == ("invalid", True, False)
            assert h.warning == "" and "checksum" in h.detail
            assert set(h.as_dict()) >= HEALTH_KEYS

            sim.unplug()  # 6-8 s: the USB adapter is pulled
            wait_until(lambda: not compass.connected)
            k += 20
            clock.t = k * DT
            h = compass.health()
            assert (h.status, h.alive) == ("disconnected", False)
            assert h.warning == ""
            sim.plug()
            wait_until(lambda: compass.connected, what="reconnect")
            for _ in range(20):  # 8-10 s: good again
                tick()
            h = compass.health()
            assert h.status == "ok", h
        finally:
            compass.stop()
    s = compass.stats()
    assert s["disconnects"] == 1 and s["reconnects"] == 1
    assert s["rejected_checksum"] == 20
    # Only the good sentences became headings: 20 + 20 + 20, all 90 degrees.
    assert len(got) == 60 and {g.heading_deg for g in got} == {90.0}

    est, var_theta = estimate(got, k * DT)
    assert abs(est.x[2]) < math.radians(1.0)  # never pulled towards 270 degrees
    assert est.x[0] == pytest.approx(k * 1.0, abs=0.5)
    i_fault_start, i_fault_end = 40, 79  # odometry steps 4.0-8.0 s: no compass update
    assert var_theta[i_fault_end] > 3 * var_theta[i_fault_start]  # inflated during the fault
    assert var_theta[-1] < var_theta[i_fault_end] / 3  # and back down once headings return
    flips = [r.getMessage() for r in caplog.records if r.name == "drivers.health"]
    assert sum(m.startswith("serial_compass: invalid") for m in flips) == 1, flips
    # Losing and finding the device is logged by the driver, once each way.
    driver = [r.getMessage() for r in caplog.records if r.name == "drivers.compass"]
    assert sum("unavailable" in m for m in driver) == 1, driver
    assert sum("is back" in m for m in driver) == 1, driver
