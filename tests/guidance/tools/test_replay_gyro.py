"""``guidance replay`` of a gyro car's raw inputs (issue 38): the yaw-rate frames decoded as
``guidance run`` decodes them (``guidance.tools.replay_can``), from a raw recording's ``/can``
frames and from a CAN log.

Real frames: the comma2k19 RAV4's ``KINEMATICS`` 0x24 (yaw rate) and ``WHEEL_SPEEDS`` 0xAA
(tests/data/realdrives)."""

from __future__ import annotations

import asyncio
import json
import os
import signal
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import AbstractContextManager
from pathlib import Path

import can
import pytest

from drivers.can_odometry import CanOdometry, CanOdometryConfig, LogReadResult, read_can_log
from guidance.core.messages import WheelOdometry, YawRate
from guidance.tools.replay_can import can_log_inputs


@pytest.fixture(autouse=True)
def no_leaks(leak_check: Callable[..., AbstractContextManager[None]]) -> Iterator[None]:
    with leak_check(grace_s=3.0, ignore_threads=("asyncio_",), ptys=False):
        yield


def _candump(frames: list[can.Message], path: Path) -> Path:
    path.write_text("".join(f"({m.timestamp:.6f}) can0 {m.arbitration_id:03X}#{m.data.hex()}\n"
                            for m in frames))  # fmt: skip
    return path


def _send(channel: str, frames: list[can.Message]) -> None:
    """At the frames' own pace, stamped by the bus as a car's are."""
    t0, start = frames[0].timestamp, time.monotonic()
    with can.Bus(interface="virtual", channel=channel) as tx:
        for m in frames:
            wait = start + (m.timestamp - t0) - time.monotonic()
            if wait > 0:
                time.sleep(wait)
            tx.send(can.Message(arbitration_id=m.arbitration_id, data=bytes(m.data),
                                is_extended_id=False))  # fmt: skip


def _run(tmp_path: Path, car: str, source: str, frames: list[can.Message]) -> Path:
    """``guidance run`` of the car on the frames; its recording's folder."""
    from guidance.app.run import run_car

    channel = f"gyro-replay-{source}-{os.getpid()}"
    cfg = tmp_path / "car.toml"
    cfg.write_text(car.format(source=source, channel=channel))

    async def scenario() -> int:
        task = asyncio.create_task(run_car(str(cfg), screen="off"))
        await asyncio.sleep(1.0)
        sender = threading.Thread(target=_send, args=(channel, frames))
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
    return tmp_path / "rec"


def _without_topic(src: Path, dest: Path, topic: str) -> None:
    """A copy of the MCAP file ``src`` without ``topic``'s messages (in the file's order)."""
    from mcap.reader import make_reader
    from mcap.writer import Writer

    with src.open("rb") as f, dest.open("wb") as g:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None
        w = Writer(g)
        w.start()
        schemas = {sid: w.register_schema(s.name, s.encoding, s.data)
                   for sid, s in summary.schemas.items()}  # fmt: skip
        channels = {cid: w.register_channel(c.topic, c.message_encoding,
                                            schemas.get(c.schema_id, 0), c.metadata)
                    for cid, c in summary.channels.items() if c.topic != topic}  # fmt: skip
        for _, channel, m in reader.iter_messages(log_time_order=False):
            if channel.id in channels:
                w.add_message(channels[channel.id], m.log_time, m.data, m.publish_time,
                              m.sequence)  # fmt: skip
        w.finish()


@pytest.mark.parametrize("source", ["gyro", "both"])
def test_a_gyro_cars_raw_recording_replays_its_yaw_rate_frames_exactly(
    tmp_path: Path,
    source: str,
    capsys: pytest.CaptureFixture[str],
    gyro_car: str,
    rav4_frames: Callable[[float], list[can.Message]],
) -> None:
    """``guidance run`` on 4 s of the RAV4's frames, then ``guidance replay --raw`` of its
    recording with the decoded ``/yaw_rate`` taken out: the yaw rates come from the ``/can``
    frames through the car's decoder, every one as the car had it, and the replay gives the
    recorded estimates and decisions bit for bit."""
    from guidance.recording.reader import Reader
    from guidance.tools.cli import main
    from guidance.tools.replay_mcap import mcap_inputs

    rec = _run(tmp_path, gyro_car, source, rav4_frames(4.0))
    (original,) = sorted(rec.glob("*.mcap"))
    recorded = [(m.data["t_s"], m.data["yaw_rate_rad_s"])
                for m in Reader(original, topics=["/yaw_rate"], log_time_order=False)]  # fmt: skip
    assert len(recorded) > 250  # ~83 Hz
    stripped = tmp_path / "stripped.mcap"
    _without_topic(original, stripped, "/yaw_rate")
    assert "/yaw_rate" not in Reader(stripped).channels()

    _, inputs = mcap_inputs(stripped, raw=True, profile="toyota")
    raw = list(inputs)
    decoded = [(m.t_s, m.yaw_rate_rad_s) for m in raw if isinstance(m, YawRate)]
    odometry = [(m.t_s, m.d_left_m, m.d_right_m) for m in raw if isinstance(m, WheelOdometry)]
    took = [(m.data["t_s"], m.data["d_left_m"], m.data["d_right_m"])
            for m in Reader(original, topics=["/odometry"], log_time_order=False)]  # fmt: skip
    if odometry != took or decoded != recorded:  # only as the driver's back-pressure does
        _assert_behind(odometry, took, decoded, recorded)
        pytest.skip(
            "the run's loop fell behind (load): the driver coalesced increments "
            "or dropped yaw readings, which a replay of raw frames cannot repeat"
        )
    assert decoded == recorded  # exactly: the same decoder on the same frames

    # the session record names the car's profile: no --profile needed
    assert main(["replay", str(stripped), "--raw", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert summary["matches_recording"] is True, summary["differences"][:3]
    assert summary["damaged_records"] == 0
    # the run's heading moved by the gyro's readings (the RAV4's reads -0.4 deg/s here)
    assert abs(summary["final"]["heading_rad"]) > 1e-3


def _assert_behind(
    odometry: list[tuple[float, float, float]],
    took: list[tuple[float, float, float]],
    decoded: list[tuple[float, float]],
    recorded: list[tuple[float, float]],
) -> None:
    """What the run took differs from the raw frames decoded only as a driver behind its
    consumer makes it differ: each increment taken is a run of decoded ones summed, stamped
    with the last (coalesced), and the yaw rates taken are some of those decoded (the rest
    dropped); anything else is a decoding difference, and fails."""
    runs = iter(odometry)
    for t, left, right in took:
        sum_l = sum_r = 0.0
        for t_d, dl, dr in runs:
            sum_l, sum_r = sum_l + dl, sum_r + dr
            if t_d == t:
                break
        else:
            pytest.fail(f"the increment taken at {t} s is no run of decoded ones")
        assert (sum_l, sum_r) == pytest.approx((left, right), abs=1e-9)
    assert set(recorded) <= set(decoded)


def test_a_gyro_cars_can_log_replays_as_the_cars_can_driver_delivers_it(
    tmp_path: Path, rav4_frames: Callable[[float], list[can.Message]]
) -> None:
    """The frames of a CAN log through ``guidance run``'s CAN driver (a python-can virtual
    bus, the frames' own stamps) and through the replay's decoders: the same increments and
    yaw rates, in the same order."""
    log = _candump(rav4_frames(1.5), tmp_path / "rav4.log")
    frames = list(read_can_log(log, LogReadResult()))
    channel = f"gyro-log-{os.getpid()}"
    got: list[WheelOdometry | YawRate] = []
    odo = CanOdometry(CanOdometryConfig(interface="virtual", channel=channel, profile="toyota",
                                        bitrate=None, yaw_rate=True, clock="frame"))  # fmt: skip
    odo.start(got.append)
    try:
        with can.Bus(interface="virtual", channel=channel, preserve_timestamps=True) as tx:
            for m in frames:
                tx.send(m)
        deadline = time.monotonic() + 10.0
        while _read(odo) < len(frames) and time.monotonic() < deadline:
            time.sleep(0.05)
        time.sleep(0.2)
    finally:
        odo.stop()
    assert _read(odo) == len(frames)
    yaws = sum(isinstance(g, YawRate) for g in got)
    assert yaws > 100 and len(got) - yaws > 100
    assert list(can_log_inputs(log, "toyota", yaw_rate=True)) == got


def _read(odo: CanOdometry) -> int:
    """Frames the driver read: the wheels' and the yaw rate's."""
    stats = odo.stats()
    return stats["read"] + stats["yaw_read"]


def test_the_session_names_the_profile_a_raw_replay_decodes_with() -> None:
    """``/session``'s ``can_profile`` (a file from outside): a known name is used, anything
    else is one clear error, and a record from before it was kept decodes as it did."""
    from guidance.errors import UserError
    from guidance.tools.replay_mcap import session_profile

    assert session_profile({"can_profile": "toyota"}) == "toyota"
    assert session_profile({}) == "gm_global_a"
    for bad in ("no_such_car", 5, "x" * 10_000, ["toyota"]):
        with pytest.raises(UserError):
            session_profile({"can_profile": bad})
