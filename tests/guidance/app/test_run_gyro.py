"""``guidance run`` with a gyro car (issue 38): the in-car CAN driver delivers the stability
control's yaw rate from the same bus as the wheel speeds, and the app turns the heading by it.

Real frames (the comma2k19 RAV4's ``KINEMATICS`` 0x24 and ``WHEEL_SPEEDS`` 0xAA, tests/data)
are sent on a python-can virtual bus at their own pace into ``run_car`` from a TOML file; the
recording says what the app took and how the gyro's health went: ok while its frames arrive,
silent and garbled while they arrive damaged, silent while they stop, the wheels ok
throughout."""

from __future__ import annotations

import asyncio
import itertools
import math
import os
import signal
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import AbstractContextManager
from pathlib import Path

import can
import pytest

from drivers.can_odometry import CanOdometry, CanOdometryConfig
from drivers.can_yaw import YawRateDecoder
from guidance.app.config import profile_track_m
from guidance.core.localize.gyro import GyroConfig
from guidance.core.messages import WheelOdometry, YawRate
from guidance.errors import UserError

YAW_ID = 0x24  # KINEMATICS, the RAV4 frames' yaw rate (conftest.rav4_frames)


@pytest.fixture(autouse=True)
def no_leaks(leak_check: Callable[..., AbstractContextManager[None]]) -> Iterator[None]:
    with leak_check(grace_s=3.0, ignore_threads=("asyncio_",), ptys=False):
        yield


def _send(channel: str, frames: list[can.Message], phases: Callable[[float], str]) -> None:
    """Send at the frames' own pace; ``phases(t)`` says what the yaw frame becomes: "ok",
    "damaged" (cut to 4 bytes: refused by its length) or "gone"."""
    t0, start = frames[0].timestamp, time.monotonic()
    with can.Bus(interface="virtual", channel=channel) as tx:
        for m in frames:
            rel = m.timestamp - t0
            wait = start + rel - time.monotonic()
            if wait > 0:
                time.sleep(wait)
            data = bytes(m.data)
            if m.arbitration_id == YAW_ID:
                phase = phases(rel)
                if phase == "gone":
                    continue
                if phase == "damaged":
                    data = data[:4]
            tx.send(can.Message(arbitration_id=m.arbitration_id, data=data,
                                is_extended_id=False))  # fmt: skip


def test_the_driver_delivers_the_yaw_rate_of_real_frames_and_counts_damaged_ones(
    rav4_frames: Callable[[float], list[can.Message]],
) -> None:
    channel = f"gyro-drv-{os.getpid()}"
    frames = rav4_frames(1.5)
    decoder = YawRateDecoder("toyota")
    expected = [r for m in frames if (r := decoder.feed(m)) is not None]
    got: list[WheelOdometry | YawRate] = []
    odo = CanOdometry(CanOdometryConfig(interface="virtual", channel=channel, profile="toyota",
                                        bitrate=None, yaw_rate=True))  # fmt: skip
    odo.start(got.append)
    try:
        _send(channel, frames, lambda t: "ok" if t < 1.0 else "damaged")
        time.sleep(0.3)
    finally:
        odo.stop()
    yaws = [g for g in got if isinstance(g, YawRate)]
    sent_ok = sum(1 for m in frames if m.arbitration_id == YAW_ID
                  and m.timestamp - frames[0].timestamp < 1.0)  # fmt: skip
    assert len(yaws) == sent_ok > 50  # every good frame, none of the damaged
    assert [y.yaw_rate_rad_s for y in yaws] == pytest.approx(
        [e.yaw_rate_rad_s for e in expected[: len(yaws)]]
    )
    assert sum(isinstance(g, WheelOdometry) for g in got) > 50
    stats = odo.stats()
    assert stats["yaw_read"] == sum(1 for m in frames if m.arbitration_id == YAW_ID)
    assert stats["yaw_rejected"] == stats["yaw_read"] - sent_ok > 10


def test_a_profile_without_a_yaw_rate_signal_is_refused() -> None:
    from drivers.profiles import PROFILES

    without = next(name for name, p in PROFILES.items() if p.yaw_rate is None)
    with pytest.raises(UserError, match="no yaw-rate signal"):
        CanOdometryConfig(interface="virtual", channel="x", profile=without, yaw_rate=True)


@pytest.mark.parametrize("source", ["gyro", "both"])
def test_guidance_run_turns_a_gyro_car_by_its_can_yaw_rate(
    tmp_path: Path, source: str, gyro_car: str, rav4_frames: Callable[[float], list[can.Message]]
) -> None:
    """4 s of good frames, 2 s of damaged yaw frames, 2 s without them (the wheels go on)."""
    from guidance.app.run import run_car
    from guidance.recording.reader import Reader

    channel = f"gyro-run-{source}-{os.getpid()}"
    cfg = tmp_path / "car.toml"
    cfg.write_text(gyro_car.format(source=source, channel=channel))
    frames = rav4_frames(8.0)

    def phases(t: float) -> str:
        return "ok" if t < 4.0 else "damaged" if t < 6.0 else "gone"

    async def scenario() -> int:
        task = asyncio.create_task(run_car(str(cfg), screen="off"))
        await asyncio.sleep(1.0)
        sender = threading.Thread(target=_send, args=(channel, frames, phases))
        sender.start()
        await asyncio.get_running_loop().run_in_executor(None, sender.join)
        await asyncio.sleep(0.3)
        os.kill(os.getpid(), signal.SIGTERM)
        return await asyncio.wait_for(task, 10.0)

    cwd = os.getcwd()
    os.chdir(tmp_path)
    try:
        assert asyncio.run(scenario()) == 0
    finally:
        os.chdir(cwd)
    rates: list[tuple[float, float]] = []
    wheels: list[tuple[float, float]] = []
    gyro_status: list[str] = []
    gyro_detail: list[str] = []
    odo_status: list[str] = []
    for m in Reader(list((tmp_path / "rec").glob("*.mcap"))):
        if m.topic == "/odometry":
            wheels.append((m.data["t_s"], m.data["d_right_m"] - m.data["d_left_m"]))
        elif m.topic == "/yaw_rate":
            rates.append((m.data["t_s"], m.data["yaw_rate_rad_s"]))
        elif m.topic == "/health":
            inputs = m.data["inputs"]
            gyro_status.append(inputs["gyro"]["status"])
            gyro_detail.append(inputs["gyro"]["detail"])
            odo_status.append(inputs["odometry"]["status"])
    assert len(rates) > 250  # ~83 Hz for the 4 s of good frames
    # damaged frames deliver nothing (silent) and are counted (garbled), as the wheels' are
    assert "ok" in gyro_status and gyro_status.index("ok") < gyro_status.index("silent")
    assert any("garbled" in d for d in gyro_detail)
    assert set(gyro_status[gyro_status.index("silent") :]) == {"silent"}
    assert set(odo_status[gyro_status.index("ok") :]) == {"ok"}
    # the heading turned by the gyro's readings while they came (no stop: its bias is the
    # prior's zero), then by the wheels' difference once they were older than max_hold_s
    import json

    doc = json.loads((tmp_path / "ck.json").read_bytes())
    turned = math.degrees(doc["pipeline"]["x"][2])  # compass 90 (east) is 0 rad
    integral = math.degrees(sum(0.5 * (a[1] + b[1]) * (b[0] - a[0])
                                for a, b in itertools.pairwise(rates)))  # fmt: skip
    assert abs(integral) > 0.5  # the RAV4's gyro reads -0.4 deg/s on this road
    stale = rates[-1][0] + GyroConfig().max_hold_s
    integral += math.degrees(sum(dd for t, dd in wheels if t > stale) / profile_track_m("toyota"))
    if source == "gyro":
        assert turned == pytest.approx(integral, abs=max(0.1, 0.05 * abs(integral)))
        return
    # "both": the wheels' turn measures each step's; they say the road is nearly straight (the
    # truth turns +0.9 deg in this minute) where the gyro reads -0.4 deg/s, so the filter takes
    # the difference for the gyro's bias and learns it in 4 s without a stop (kept for the
    # next drive). The heading itself is not compared: the wheels' turn over these seconds
    # depends on how the loaded machine spaced the frames' arrival stamps
    from guidance.app.learned_file import load_learned

    learned, _ = load_learned(tmp_path / "learned.json", "g1")
    assert learned is not None and learned.gyro_bias_deg_s is not None
    said = f"turned {turned:.2f}, gyro {integral:.2f}, {learned}"
    assert learned.gyro_bias_deg_s < -0.15, said
    assert learned.gyro_bias_sigma_deg_s is not None and learned.gyro_bias_sigma_deg_s < 0.2
