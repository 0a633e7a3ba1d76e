"""OpenCV camera: frames from a device index, a video file or a stream URL (SPEC section 6).

Two threads, so a slow consumer never stalls capture: the capture thread reads as fast as the
camera delivers and keeps only the latest frame (a one-slot ring, HOUSE_STYLE); the delivery
thread hands that frame to the sink. Frames overwritten before delivery are counted as dropped.
A camera that fails (unplugged, stream down) is logged once, reopened with exponential backoff,
and its recovery logged; nothing here raises into the application.
"""

from __future__ import annotations

import functools
import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2

from drivers._reader import ThreadedSource
from guidance.core.messages import CameraFrame
from guidance.errors import UserError

log = logging.getLogger(__name__)

STREAM_TIMEOUT_S = 3.0
"""Longest a stream URL may block opening or reading before it counts as a failure."""
HEALTHY_RESET_S = 5.0
"""A camera that delivered this long before failing is retried from the shortest backoff."""


@dataclass(frozen=True, slots=True)
class CameraConfig:
    """``source``: a device index (0), a file path or a stream URL (rtsp://, http://)."""

    source: int | str = 0
    width: int | None = None
    height: int | None = None
    fps: float | None = None
    """Requested device frame rate; for files, the replay rate (default: the file's own)."""
    loop_file: bool = False
    """Restart a video file at its end (demos); otherwise the source ends there."""
    failures_before_reopen: int = 5
    """Consecutive failed reads that mean 'camera gone'."""
    reconnect_initial_s: float = 0.5
    reconnect_max_s: float = 10.0
    stale_after_s: float = 2.0
    """No frame for this long: ``health()`` says 'silent'."""

    def __post_init__(self) -> None:
        if isinstance(self.source, bool) or not isinstance(self.source, int | str):
            raise UserError(f"source must be a device index, file or URL, not {self.source!r}")
        if isinstance(self.source, str) and not self.source:
            raise UserError("source must not be empty")
        if not (isinstance(self.failures_before_reopen, int) and self.failures_before_reopen > 0):
            raise UserError("failures_before_reopen must be a positive integer")
        for name in ("reconnect_initial_s", "reconnect_max_s", "stale_after_s"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and value > 0):
                raise UserError(f"{name} must be a positive number of seconds, not {value!r}")

    @property
    def is_file(self) -> bool:
        return isinstance(self.source, str) and Path(self.source).is_file()


class OpenCvCamera(ThreadedSource[CameraFrame]):
    """``CameraSource`` backed by ``cv2.VideoCapture``.

    A camera that disappears is a ``health()`` status ('disconnected'), not an exception; the
    app goes on without landmark fixes, so the estimate only grows less certain.
    """

    sink_kind = "frame"

    def __init__(
        self,
        config: CameraConfig | None = None,
        name: str = "camera",
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        """``clock`` stamps each frame: ``time.monotonic`` live, the world's clock in simulation."""
        self.config = config or CameraConfig()
        super().__init__(name, self.config, clock=clock)
        self._device = f"camera {self.config.source!r}"
        self._clock = clock
        self._new_frame = threading.Condition(self._lock)
        self._latest: CameraFrame | None = None
        self.ended = threading.Event()
        """Set when a (non-looping) file source has been read to its end."""

    # CameraSource ------------------------------------------------------------------------------

    def stats(self) -> dict[str, int]:
        with self._lock:
            return {
                key: self._counts[key]
                for key in (
                    "frames",
                    "delivered",
                    "dropped",
                    "read_failures",
                    "reopens",
                    "open_failures",
                    "sink_errors",
                )
            }

    # threads -----------------------------------------------------------------------------------

    def _workers(self, sink: Callable[[CameraFrame], None]) -> list[tuple[str, Callable[[], None]]]:
        return [("capture", self._capture), ("deliver", functools.partial(self._delivery, sink))]

    def _on_start(self) -> None:
        self.ended.clear()

    def _wake(self) -> None:
        with self._new_frame:
            self._new_frame.notify_all()

    # capture thread ----------------------------------------------------------------------------

    def _open(self) -> Any:
        cfg = self.config
        if isinstance(cfg.source, str) and not cfg.is_file:
            # A stream URL: bound the time a dead server can block open() and read().
            timeouts = [
                cv2.CAP_PROP_OPEN_TIMEOUT_MSEC,
                int(STREAM_TIMEOUT_S * 1000),
                cv2.CAP_PROP_READ_TIMEOUT_MSEC,
                int(STREAM_TIMEOUT_S * 1000),
            ]
            cap = cv2.VideoCapture(cfg.source, cv2.CAP_ANY, timeouts)
        else:
            cap = cv2.VideoCapture(cfg.source)
        if not cap.isOpened():
            cap.release()
            return None
        if cfg.width:
            cap.set(cv2.CAP_PROP_FRAME_WIDTH, cfg.width)
        if cfg.height:
            cap.set(cv2.CAP_PROP_FRAME_HEIGHT, cfg.height)
        if cfg.fps and not cfg.is_file:
            cap.set(cv2.CAP_PROP_FPS, cfg.fps)
        return cap

    def _capture(self) -> None:
        cfg = self.config
        delay = cfg.reconnect_initial_s
        cap = None
        tried = False
        opened_at = 0.0
        try:
            while not self._stop.is_set():
                if cap is None:
                    if tried:  # back off before every reopen, also after a lost camera
                        if self._stop.wait(delay):
                            break
                        delay = self._backoff(delay)
                    tried = True
                    cap = self._open()
                    if cap is None:
                        self._count("open_failures")
                        self._set_connected(False, "cannot open")
                        continue
                    if self._connected is False:
                        self._count("reopens")
                    opened_at = time.monotonic()
                cap = self._play_file(cap) if cfg.is_file else self._read_live(cap)
                if cap is None and time.monotonic() - opened_at > HEALTHY_RESET_S:
                    delay = cfg.reconnect_initial_s  # it worked for a while: retry quickly
        finally:
            if cap is not None:
                cap.release()

    def _read_live(self, cap: Any) -> Any:
        failures = 0
        while not self._stop.is_set():
            ok, image = cap.read()
            if ok and image is not None:
                failures = 0
                self._set_connected(True)
                self._publish(image)
                continue
            failures += 1
            self._count("read_failures")
            self._health.error(f"{failures} frame reads failed in a row")
            if failures >= self.config.failures_before_reopen:
                self._set_connected(False, f"{failures} failed reads")
                cap.release()
                return None
            self._stop.wait(0.01)
        return cap

    def _play_file(self, cap: Any) -> Any:
        fps = self.config.fps or cap.get(cv2.CAP_PROP_FPS) or 30.0
        period = 1.0 / fps if fps > 0 else 0.0
        deadline = time.monotonic()
        while not self._stop.is_set():
            ok, image = cap.read()
            if not ok or image is None:
                if self.config.loop_file:
                    cap.set(cv2.CAP_PROP_POS_FRAMES, 0)
                    ok, image = cap.read()
                if not ok or image is None:
                    log.info("%s: end of %s", self.name, self.config.source)
                    self._health.ended()
                    self.ended.set()
                    self._stop.wait()  # a file that ended stays ended until stop()
                    return cap
            self._set_connected(True)
            self._publish(image)
            deadline += period  # absolute deadlines: replay at the file's rate without drift
            wait = deadline - time.monotonic()
            if wait > 0:
                self._stop.wait(wait)
            else:
                deadline = time.monotonic()
        return cap

    def _publish(self, image: Any) -> None:
        frame = CameraFrame(t_s=self._clock(), image=image, source=str(self.config.source))
        self._health.data(True, frame.t_s)
        with self._new_frame:
            self._counts["frames"] += 1
            if self._latest is not None:
                self._counts["dropped"] += 1
            self._latest = frame
            self._new_frame.notify()

    # delivery thread ---------------------------------------------------------------------------

    def _delivery(self, sink: Callable[[CameraFrame], None]) -> None:
        while True:
            with self._new_frame:
                while self._latest is None and not self._stop.is_set():
                    self._new_frame.wait(0.5)
                if self._stop.is_set():
                    return
                frame, self._latest = self._latest, None
            assert frame is not None
            if self._deliver(sink, frame):
                self._count("delivered")
