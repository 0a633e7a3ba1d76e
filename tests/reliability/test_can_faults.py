"""CAN bus faults on a python-can virtual bus, through the real CanOdometry driver.

Each test drives the simulated wheels at a constant 10 m/s straight ahead (the GM profile of the
2007 Tahoe reference car: 0x348 front and 0x34A rear at 20 Hz), injects one fault with a second
bus on the same virtual channel, and checks the three things docs/reliability.md promises:

* the health record (status, alive/valid, counters; the pipeline words a bad status);
* the estimate is not corrupted: every increment the driver lets through is fed into the real
  ``PoseEstimator``, and its position equals the distance actually driven while data was good;
* the driver keeps running (frames after the fault are decoded again).

Time is the frames' own (``clock="frame"``, ``preserve_timestamps``) and the health clock is a
``FakeClock``, so "silent for 5 s" takes no 5 s.
"""

from __future__ import annotations

import logging
import math
import random
import uuid
from collections.abc import Iterator
from dataclasses import dataclass, field

import can
import pytest
from reliability_helpers import HEALTH_KEYS, FakeClock, wait_until

from drivers.can_odometry import CanOdometry, CanOdometryConfig
from drivers.profiles import get_profile, load_dbc
from guidance.core.localize.estimator import PoseEstimator
from guidance.core.messages import WheelOdometry
from hal_sim.sim_can import SimCanWheels

SPEED_MPS = 10.0
PERIOD_S = 0.05
REAR, FRONT = 0x34A, 0x348
QUANT_M_PER_S = 0.0311 / 3.6 / 2  # half a count of the GM wheel-speed signal
"""Worst speed error of one encoded sample; distance error is at most this times the time."""


@dataclass
class Rig:
    """Simulated wheels + an injector on one virtual channel, the driver, and what it emitted."""

    wheels: SimCanWheels
    inject: can.BusABC
    odo: CanOdometry
    clock: FakeClock
    out: list[WheelOdometry] = field(default_factory=list)
    sent: int = 0

    def drive(self, t0: float, t1: float, speed: float = SPEED_MPS) -> float:
        """Send good frame pairs every 50 ms in [t0, t1); returns the time after the last one."""
        self.wheels.set_speeds(speed, speed)
        n = round((t1 - t0) / PERIOD_S)
        for i in range(n):
            self.clock.t = t0 + i * PERIOD_S  # the health clock follows the frames' time
            self.wheels.send(t0 + i * PERIOD_S)
            self.sent += 2
        return t0 + n * PERIOD_S

    def raw(self, msg: can.Message) -> None:
        if math.isfinite(msg.timestamp):
            self.clock.t = max(self.clock.t, msg.timestamp)
        self.inject.send(msg)
        self.sent += 1

    def settle(self) -> None:
        """Wait until the driver has read every frame sent so far."""
        wait_until(lambda: self.odo.stats()["frames"] >= self.sent, what="frames decoded")

    def estimate_x(self) -> float:
        est = PoseEstimator()
        for inc in self.out:
            assert est.process(inc).accepted
        x = est.x
        assert all(math.isfinite(v) for v in x)
        return float(x[0])


@pytest.fixture
def rig() -> Iterator[Rig]:
    channel = f"rel_{uuid.uuid4().hex}"
    clock = FakeClock()
    cfg = CanOdometryConfig(
        interface="virtual",
        channel=channel,
        bitrate=None,
        clock="frame",
        hardware_filters=False,  # let every frame reach the decoder: it must sort them out
        bus_options={"preserve_timestamps": True},
        receive_timeout_s=0.02,
    )
    odo = CanOdometry(cfg, clock=clock)
    wheels = SimCanWheels(channel, profile="gm_global_a").open()
    inject = can.Bus(interface="virtual", channel=channel, preserve_timestamps=True)
    r = Rig(wheels, inject, odo, clock)
    odo.start(r.out.append)
    try:
        yield r
    finally:
        odo.stop()
        wheels.close()
        inject.shutdown()


def check_distance(r: Rig, driven_s: float) -> None:
    """Decoder distance and estimator position both equal the good driving, within one count."""
    tol = QUANT_M_PER_S * driven_s + 1e-6
    truth = SPEED_MPS * driven_s
    assert r.odo.decoder.distance_m == pytest.approx(truth, abs=tol)
    assert r.estimate_x() == pytest.approx(truth, abs=tol + 1e-3)
    # No increment ever came from a bad frame: none faster than the car.
    for a, b in zip(r.out, r.out[1:], strict=False):
        dt = b.t_s - a.t_s
        assert max(abs(b.d_left_m), abs(b.d_right_m)) <= (SPEED_MPS + 0.01) * dt + 1e-9


def test_silent_for_5_s_is_flagged_not_integrated_and_recovers(
    rig: Rig, caplog: pytest.LogCaptureFixture
) -> None:
    with caplog.at_level(logging.WARNING, logger="drivers.health"):
        t = rig.drive(0.0, 2.0)
        rig.settle()
        h = rig.odo.health()
        assert h.status == "ok" and h.ok and h.warning == ""
        assert set(h.as_dict()) >= HEALTH_KEYS

        rig.clock.t += 5.0  # five seconds without a single frame
        wait_until(lambda: any("silent" in r.getMessage() for r in caplog.records))
        h = rig.odo.health()
        assert (h.status, h.alive) == ("silent", False)
        assert h.warning == ""
        assert h.age_s is not None and h.age_s >= 5.0

        rig.drive(t + 5.0, t + 7.0)  # the bus comes back
        rig.settle()
        h = rig.odo.health()
        assert h.status == "ok" and h.ok
    s = rig.odo.stats()
    assert s["rejected_gap"] == 1 and h.counters["gap_ms"] == pytest.approx(5050, abs=1)
    # The silence is not integrated: 2 s + 2 s of driving less the first interval of each run.
    check_distance(rig, 4.0 - 2 * PERIOD_S)
    flips = [r.getMessage() for r in caplog.records]
    assert sum(m.endswith(": silent") for m in flips) == 1
    assert sum("ok again" in m for m in flips) == 1


def test_bursty_timestamps_integrate_exactly(rig: Rig) -> None:
    """Frames in clumps (10 within 9 ms, then 0.49 s of nothing): the same distance."""
    rig.wheels.set_speeds(SPEED_MPS, SPEED_MPS)
    t = 0.0
    for _burst in range(8):
        for _ in range(10):
            rig.clock.t = t
            rig.wheels.send(t)
            rig.sent += 2
            t += 0.001
        t += 0.49
    rig.clock.t = t
    rig.settle()
    last = t - 0.49 - 0.001
    assert rig.odo.health().ok
    assert rig.odo.stats()["rejected"] == 0
    check_distance(rig, last)


def test_wrong_dlc_is_rejected_counted_and_a_storm_is_invalid(rig: Rig) -> None:
    t = rig.drive(0.0, 1.0)
    good = list(rig.wheels.encode())
    # 0.8 s in which every frame is one byte short: nothing usable arrives.
    for i in range(16):
        for msg in good:
            bad = can.Message(
                timestamp=t + i * PERIOD_S,
                arbitration_id=msg.arbitration_id,
                data=bytes(msg.data)[:-1],
                is_extended_id=False,
            )
            rig.raw(bad)
    rig.clock.t = t + 15 * PERIOD_S
    rig.settle()
    h = rig.odo.health()
    assert (h.status, h.alive, h.valid) == ("invalid", True, False)
    assert h.warning == ""
    assert h.counters["rejected_dlc"] == 32
    # Good frames again: bridged (0.85 s < max_gap_s) and the window refills with good frames.
    rig.drive(t + 16 * PERIOD_S, t + 16 * PERIOD_S + 1.0)
    rig.settle()
    assert rig.odo.health().ok
    check_distance(rig, 2.8 - PERIOD_S)


def test_unknown_ids_and_error_frames_are_ignored(rig: Rig) -> None:
    rng = random.Random(7)
    t = 0.0
    rig.wheels.set_speeds(SPEED_MPS, SPEED_MPS)
    for i in range(40):
        rig.clock.t = t
        rig.wheels.send(t)
        rig.sent += 2
        for _ in range(10):  # a busy bus: ten other frames per wheel-speed pair
            fid = rng.choice([x for x in range(0x7FF) if x not in (REAR, FRONT)][:2000])
            data = bytes(rng.randrange(256) for _ in range(rng.randrange(9)))
            rig.raw(can.Message(timestamp=t, arbitration_id=fid, data=data, is_extended_id=False))
        if i % 4 == 0:
            rig.raw(can.Message(timestamp=t, is_error_frame=True, arbitration_id=REAR))
        if i % 5 == 0:  # an extended id that collides with the rear id's low bits
            rig.raw(can.Message(timestamp=t, arbitration_id=0x1000_0000 | REAR, data=bytes(5)))
        t += PERIOD_S
    rig.clock.t = t - PERIOD_S
    rig.settle()
    h = rig.odo.health()
    assert h.ok, h
    s = rig.odo.stats()
    assert s["error_frames"] == 10 and "error frame" in h.detail
    assert s["ignored"] == 400 + 10 + 8 and s["rejected"] == 0
    check_distance(rig, 39 * PERIOD_S)


def test_speed_spikes_are_rejected_not_integrated(rig: Rig) -> None:
    """A single sample at 40 m/s in a 10 m/s drive (over 20 m/s^2 * dt + 3 m/s): rejected;
    a raw 0xFFFF ('invalid', 2038 km/h) sample: implausible. The next good frame bridges."""
    t = rig.drive(0.0, 1.0)
    rig.wheels.set_speeds(40.0, 40.0)
    spike = rig.wheels.encode()[1]  # the rear frame only
    spike.timestamp = t
    rig.raw(spike)
    t = rig.drive(t + PERIOD_S, t + 1.0)
    raw_ffff = {"RLWheelSpd": 0xFFFF, "RRWheelSpd": 0xFFFF, "RLWheelDir": 1, "RRWheelDir": 1}
    data = (
        load_dbc(get_profile("gm_global_a").dbc_file)
        .get_message_by_frame_id(REAR)
        .encode(raw_ffff, scaling=False, strict=False)
    )
    ffff = can.Message(timestamp=t, arbitration_id=REAR, data=data, is_extended_id=False)
    rig.raw(ffff)
    rig.drive(t + PERIOD_S, t + 1.0)
    rig.settle()
    s = rig.odo.stats()
    assert s["rejected_spike"] == 1 and s["rejected_implausible"] == 1
    assert rig.odo.health().ok  # two bad frames in a healthy stream: counted, no alarm
    check_distance(rig, 3.0 - PERIOD_S)


def test_missing_bus_is_disconnected_with_a_warning_and_keeps_trying() -> None:
    cfg = CanOdometryConfig(
        interface="socketcan", channel="nocan7", reconnect_initial_s=0.01, reconnect_max_s=0.02
    )
    odo = CanOdometry(cfg)
    try:
        odo.start(lambda _: None)
    except Exception as exc:  # python-can without socketcan on this platform
        pytest.skip(f"socketcan not available: {exc}")
    try:
        wait_until(lambda: odo.stats().get("bus_errors", 0) >= 3)
        h = odo.health()
        assert (h.status, h.alive, h.valid) == ("disconnected", False, False)
        assert h.warning == "" and "nocan7" in h.detail
    finally:
        odo.stop()
    assert odo.health().status == "stopped"
