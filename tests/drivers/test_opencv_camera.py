"""OpenCvCamera with real OpenCV captures: a video file, an image sequence that runs dry
(a camera that goes and comes back), a device that does not exist, slow consumers."""

from __future__ import annotations

import itertools
import logging
import threading
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from drivers.camera import CameraConfig, OpenCvCamera
from guidance.app.ports import CameraSource
from guidance.core.messages import CameraFrame
from guidance.errors import UserError

N_FRAMES = 30


@pytest.fixture
def video(tmp_path: Path) -> Path:
    """A 30-frame MJPG clip whose frame i has brightness 8 * i."""
    path = tmp_path / "clip.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter.fourcc(*"MJPG"), 30.0, (64, 48))
    assert writer.isOpened()
    for i in range(N_FRAMES):
        writer.write(np.full((48, 64, 3), 8 * i, np.uint8))
    writer.release()
    return path


def test_is_a_camera_source() -> None:
    assert isinstance(OpenCvCamera(CameraConfig(source=0)), CameraSource)


def test_file_frames_arrive_in_order_and_the_file_ends(video: Path) -> None:
    got: list[CameraFrame] = []
    cam = OpenCvCamera(CameraConfig(source=str(video), fps=300.0))
    cam.start(got.append)
    try:
        assert cam.ended.wait(5.0)
        deadline = time.monotonic() + 2.0
        while cam.stats()["delivered"] + cam.stats()["dropped"] < N_FRAMES:
            assert time.monotonic() < deadline
            time.sleep(0.01)
    finally:
        cam.stop()
    s = cam.stats()
    assert s["frames"] == N_FRAMES and s["read_failures"] == 0
    assert s["delivered"] + s["dropped"] == N_FRAMES
    levels = [int(np.asarray(f.image).mean() + 0.5) for f in got]
    assert levels == sorted(levels) and abs(levels[-1] - 8 * (N_FRAMES - 1)) <= 3  # MJPG loss
    assert all(b.t_s >= a.t_s for a, b in itertools.pairwise(got))
    assert got[0].source == str(video)


def test_slow_consumer_gets_the_latest_frame(video: Path) -> None:
    got: list[CameraFrame] = []

    def slow(frame: CameraFrame) -> None:
        got.append(frame)
        time.sleep(0.03)

    cam = OpenCvCamera(CameraConfig(source=str(video), fps=300.0))
    cam.start(slow)
    try:
        assert cam.ended.wait(5.0)
        time.sleep(0.1)
    finally:
        cam.stop()
    s = cam.stats()
    assert s["dropped"] > 10  # the capture side never waited for the consumer
    assert s["delivered"] == len(got) < N_FRAMES
    last = int(np.asarray(got[-1].image).mean() + 0.5)
    assert abs(last - 8 * (N_FRAMES - 1)) <= 3  # the newest frame was handed over, not a stale one


def test_camera_that_goes_and_comes_back(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    """An image sequence read as a live source runs dry (reads fail) and reopens."""
    for i in range(5):
        cv2.imwrite(str(tmp_path / f"f_{i:03d}.png"), np.full((16, 16, 3), 40 * i, np.uint8))
    cfg = CameraConfig(
        source=str(tmp_path / "f_%03d.png"), reconnect_initial_s=0.05, reconnect_max_s=0.1
    )
    got: list[CameraFrame] = []
    cam = OpenCvCamera(cfg)
    with caplog.at_level(logging.WARNING, logger="drivers.camera"):
        cam.start(got.append)
        try:
            deadline = time.monotonic() + 5.0
            while cam.stats()["reopens"] < 1 or cam.stats()["frames"] < 10:
                assert time.monotonic() < deadline
                time.sleep(0.01)
            for png in tmp_path.glob("*.png"):  # now it is gone for good
                png.unlink()
            time.sleep(0.5)
        finally:
            cam.stop()
    s = cam.stats()
    assert s["read_failures"] >= cfg.failures_before_reopen
    assert s["reopens"] >= 1 and s["open_failures"] >= 1
    lost = [r for r in caplog.records if "unavailable" in r.getMessage()]
    back = [r for r in caplog.records if "is back" in r.getMessage()]
    assert len(back) >= 1 and len(lost) == len(back) + 1  # one line per flip, not per retry


def test_missing_device_never_crashes_and_stops_quickly(caplog: pytest.LogCaptureFixture) -> None:
    cam = OpenCvCamera(CameraConfig(source=97, reconnect_initial_s=0.02, reconnect_max_s=0.05))
    with caplog.at_level(logging.WARNING, logger="drivers.camera"):
        cam.start(lambda f: None)
        time.sleep(0.3)
        t0 = time.monotonic()
        cam.stop()
    assert time.monotonic() - t0 < 4.0  # woken, not abandoned at the 5 s join timeout
    assert cam.stats()["open_failures"] >= 3 and cam.stats()["frames"] == 0
    assert sum("unavailable" in r.getMessage() for r in caplog.records) == 1


def test_sink_errors_are_counted(video: Path) -> None:
    def bad(frame: CameraFrame) -> None:
        raise ValueError("matcher bug")

    cam = OpenCvCamera(CameraConfig(source=str(video), fps=300.0))
    cam.start(bad)
    try:
        assert cam.ended.wait(5.0)
        time.sleep(0.1)
    finally:
        cam.stop()
    assert cam.stats()["sink_errors"] == cam.stats()["frames"] - cam.stats()["dropped"] > 0
    assert not [t for t in threading.enumerate() if t.name.startswith("camera-")]


def test_config_values_are_checked() -> None:
    with pytest.raises(UserError, match="source"):
        CameraConfig(source="")
    with pytest.raises(UserError, match="source"):
        CameraConfig(source=True)
    with pytest.raises(UserError, match="reconnect_max_s"):
        CameraConfig(reconnect_max_s=0)
