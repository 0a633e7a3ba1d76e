"""Wall-clock steps in the middle of a drive, on the simulated devices (issue 14, item 1).

The real CAN driver in its default "wall" clock mode reads frames from a python-can virtual bus,
stamped with a wall clock that steps by -0.5 s, +0.5 s and +1 h while the car drives at
10 m/s; its odometry and a compass stamped on the monotonic clock (as the serial driver stamps
lines) go through the real pipeline. The estimate must keep moving, stay within its ellipse of
the truth, and each step must be reported.
"""

from __future__ import annotations

import math
import threading
import time

import pytest

from drivers.can_odometry import CanOdometry, CanOdometryConfig
from guidance.core.localize.estimator import EstimatorConfig
from guidance.core.messages import CompassHeading, WheelOdometry
from guidance.core.pipeline import Pipeline, PipelineConfig
from guidance.core.plan.navigator import NavigatorConfig
from hal_sim.sim_can import SimCanWheels

SPEED = 10.0
STEPS = ((1.0, -0.5), (2.0, +0.5), (3.0, +3600.0))
"""(seconds into the drive, wall-clock step)."""


@pytest.mark.timeout(60)
def test_wall_clock_steps_leave_the_estimate_moving_and_are_reported() -> None:
    channel = f"clock-steps-{time.monotonic_ns()}"
    pipeline = Pipeline(
        PipelineConfig(
            estimator=EstimatorConfig(compass_two_sigma_deg=20.0),
            navigator=NavigatorConfig(),
            start_xy_m=(0.0, 0.0),
            start_heading_rad=0.0,
            expected_rates_hz={"odometry": 50.0, "compass": 10.0},
            stop_at_arrival=False,
        )
    )
    lock = threading.Lock()
    rejected: list[str] = []

    def feed(msg: WheelOdometry | CompassHeading) -> None:
        with lock:
            out = pipeline.feed(msg)
            if not out.accepted and out.reason not in (None, "held_after_gap"):
                rejected.append(str(out.reason))

    odo = CanOdometry(
        CanOdometryConfig(
            interface="virtual", channel=channel, bitrate=None, clock="wall", profile="toyota"
        )
    )
    wheels = SimCanWheels(channel, profile="toyota").open()
    odo.start(feed)
    try:
        wheels.set_speeds(SPEED, SPEED)
        t0 = time.monotonic()
        shift = 0.0
        k = 0
        while (elapsed := time.monotonic() - t0) < 4.0:
            shift = sum(step for at, step in STEPS if elapsed >= at)
            wheels.send(time.time() + shift)  # the adapter's stamp: the (stepped) wall clock
            if k % 5 == 0:  # the compass on the monotonic clock, heading east
                feed(CompassHeading(time.monotonic(), 90.0, is_true=True))
            k += 1
            time.sleep(0.02)
        driven_s = time.monotonic() - t0
    finally:
        odo.stop()
        wheels.close()
    assert odo.stats().get("clock_steps", 0) == len(STEPS)  # each step reported
    x = pipeline.localizer.estimator.x
    expected = SPEED * driven_s
    assert x[0] == pytest.approx(expected, rel=0.1)  # moving all along, nothing lost
    assert pipeline.localizer.estimator.major_axis_m < 50.0  # and not widened by an hour of driving
    assert math.hypot(x[0] - expected, x[1]) < pipeline.localizer.estimator.major_axis_m
    assert rejected.count("out_of_order") <= 2, rejected
