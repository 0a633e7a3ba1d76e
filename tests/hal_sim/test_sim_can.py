"""SimCanWheels -> python-can virtual bus -> the real CanOdometry driver (round trips)."""

from __future__ import annotations

import time
import uuid
from collections.abc import Callable, Iterator
from contextlib import AbstractContextManager

import pytest

from drivers.can_odometry import CanOdometry, CanOdometryConfig, WheelSpeedDecoder
from drivers.profiles import PROFILES, get_profile
from guidance.core.messages import WheelOdometry
from hal_sim.sim_can import SimCanWheels


@pytest.fixture(autouse=True)
def no_leaks(leak_check: Callable[..., AbstractContextManager[None]]) -> Iterator[None]:
    """Fail a test that leaves a thread running or a virtual CAN bus open."""
    with leak_check(grace_s=2.0, ptys=False):
        yield


def channel() -> str:
    return f"simcan_{uuid.uuid4().hex}"


def wait_frames(odo: CanOdometry, n: int, timeout_s: float = 5.0) -> None:
    deadline = time.monotonic() + timeout_s
    while odo.stats()["frames"] < n:
        assert time.monotonic() < deadline, odo.stats()
        time.sleep(0.005)


def half_count_mps(profile: str) -> float:
    return 0.5 * get_profile(profile).speed_resolution_mps


@pytest.mark.parametrize("profile", sorted(PROFILES))
def test_round_trip_recovers_distance_within_quantisation(profile: str) -> None:
    """An accelerated drive: 10 s of frames with simulated timestamps, sent at once."""
    ch = channel()
    period = get_profile(profile).message_period_s
    n = round(10.0 / period)
    got: list[WheelOdometry] = []
    odo = CanOdometry(
        CanOdometryConfig(interface="virtual", channel=ch, profile=profile, clock="frame")
    )
    odo.start(got.append)
    try:
        with SimCanWheels(ch, profile=profile) as sim:
            sim.set_speeds(5.0, 6.0)
            for i in range(n + 1):
                sim.send(t_s=1000.0 + i * period)
            wait_frames(odo, sim.frames_sent)
    finally:
        odo.stop()
    assert len(got) == n
    assert got[0].t_s == pytest.approx(1000.0 + period) and got[-1].t_s == pytest.approx(1010.0)
    duration = n * period
    for total, v in ((sum(g.d_left_m for g in got), 5.0), (sum(g.d_right_m for g in got), 6.0)):
        assert abs(total - v * duration) <= half_count_mps(profile) * duration + 1e-9
    assert odo.stats()["rejected"] == 0


def test_round_trip_at_the_real_message_rate() -> None:
    """The sim on its own thread at the GM rate (20 Hz); the driver on wall-clock frame times."""
    ch = channel()
    got: list[WheelOdometry] = []
    odo = CanOdometry(CanOdometryConfig(interface="virtual", channel=ch))
    odo.start(got.append)
    try:
        with SimCanWheels(ch) as sim:
            sim.set_speeds(10.0, 10.0)
            t0 = time.monotonic()
            sim.start()
            time.sleep(0.6)
            sim.stop()
            elapsed = time.monotonic() - t0
            wait_frames(odo, sim.frames_sent)
    finally:
        odo.stop()
    rate_hz = (len(got) + 1) / elapsed
    assert 14.0 <= rate_hz <= 22.0  # 20 Hz nominal, minus scheduling on a busy machine
    span = got[-1].t_s - got[0].t_s + 0.05
    assert sum(g.d_left_m for g in got) == pytest.approx(10.0 * span, rel=0.05)
    now = time.monotonic()
    assert all(now - 5.0 < g.t_s <= now for g in got)  # mapped onto the monotonic clock


def test_reverse_and_turning_over_the_bus() -> None:
    ch = channel()
    got: list[WheelOdometry] = []
    odo = CanOdometry(CanOdometryConfig(interface="virtual", channel=ch, clock="frame"))
    odo.start(got.append)
    try:
        with SimCanWheels(ch) as sim:
            sim.set_speeds(-1.0, -1.2)
            for i in range(11):
                sim.send(t_s=5.0 + 0.05 * i)
            wait_frames(odo, sim.frames_sent)
    finally:
        odo.stop()
    assert len(got) == 10
    assert all(g.d_left_m < 0 and g.d_right_m < g.d_left_m for g in got)


def test_front_wheels_only_edge_case_over_the_bus() -> None:
    """Rears stuck at 0 while the fronts move (the Civic 8th-generation log), GM encoding."""
    ch = channel()
    got: list[WheelOdometry] = []
    odo = CanOdometry(CanOdometryConfig(interface="virtual", channel=ch, clock="frame"))
    odo.start(got.append)
    try:
        with SimCanWheels(ch) as sim:
            sim.set_speeds(0.0, 0.0, 4.0, 4.0)
            for i in range(21):
                sim.send(t_s=5.0 + 0.05 * i)
            wait_frames(odo, sim.frames_sent)
    finally:
        odo.stop()
    assert odo.stats()["front_fallback"] == 20
    assert sum(g.d_left_m for g in got) == pytest.approx(4.0, abs=half_count_mps("gm_global_a"))


@pytest.mark.parametrize("profile", sorted(PROFILES))
def test_encoded_frames_decode_to_the_set_speeds(profile: str) -> None:
    sim = SimCanWheels(channel(), profile=profile)
    dec = WheelSpeedDecoder(profile)
    sim.set_speeds(7.0, 7.5, 7.2, 7.7)
    for t in (1.0, 1.0 + sim.period_s):
        out = None
        for msg in sim.encode():
            msg.timestamp = t
            out = dec.feed(msg) or out
    assert out is not None
    tol = half_count_mps(profile) * sim.period_s + 1e-12
    assert out.d_left_m == pytest.approx(7.0 * sim.period_s, abs=tol)
    assert out.d_right_m == pytest.approx(7.5 * sim.period_s, abs=tol)
    assert dec.stats()["rejected"] == 0
    sim.close()


def test_speeds_beyond_the_signal_range_are_clipped_not_raised() -> None:
    sim = SimCanWheels(channel())
    sim.set_speeds(500.0, 500.0)
    dec = WheelSpeedDecoder("gm_global_a")
    for msg in sim.encode():
        msg.timestamp = 1.0
        dec.feed(msg)
    assert dec.rejected == 0 and dec.decoded == 2  # 255 km/h: the DBC's stated maximum
    sim.close()
