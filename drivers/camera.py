"""OpenCV camera: frames from a device index, a video file or a stream URL (SPEC section 6).

Two threads, so a slow consumer never stalls capture: the capture thread reads as fast as the
camera delivers and keeps only the latest frame (a one-slot ring, HOUSE_STYLE); the delivery
thread hands that frame to the sink. Frames overwritten before delivery are counted as dropped.
A camera that fails (unplugged, stream down) is logged once, reopened with exponential backoff,
and its recovery logged; nothing here raises into the application.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2

from drivers.health import DeviceHealth, HealthTracker
from guidance.errors import UserError
from guidance.messages import CameraFrame

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


WARNINGS = {
    "silent": "Camera stopped. Landmarks cannot be recognised.",
    "invalid": "Camera images are failing. Landmarks cannot be recognised.",
    "disconnected": "Camera lost. Landmarks cannot be recognised.",
}
"""Spoken when ``health()`` turns bad (docs/reliability.md)."""


class OpenCvCamera:
    """``CameraSource`` backed by ``cv2.VideoCapture``.

    A camera that disappears is a ``health()`` status ('disconnected'), not an exception; the
    app goes on without landmark fixes, so the estimate only grows less certain.
    """

    def __init__(
        self,
        config: CameraConfig | None = None,
        name: str = "camera",
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        """``clock`` stamps each frame: ``time.monotonic`` live, the world's clock in simulation."""
        self.config = config or CameraConfig()
        self.name = name
        self._clock = clock
        self._tracker = HealthTracker(
            name, stale_after_s=self.config.stale_after_s, clock=clock, warnings=WARNINGS
        )
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._new_frame = threading.Condition(self._lock)
        self._latest: CameraFrame | None = None
        self._counts: Counter[str] = Counter()
        self._threads: list[threading.Thread] = []
        self._healthy: bool | None = None
        self._sink_failing = False
        self.ended = threading.Event()
        """Set when a (non-looping) file source has been read to its end."""

    # CameraSource ------------------------------------------------------------------------------

    def start(self, sink: Callable[[CameraFrame], None]) -> None:
        if self._threads:
            raise RuntimeError(f"{self.name} already started")
        self._stop.clear()
        self.ended.clear()
        self._tracker.started()
        self._threads = [
            threading.Thread(target=self._capture, name=f"{self.name}-capture", daemon=True),
            threading.Thread(
                target=self._deliver, args=(sink,), name=f"{self.name}-deliver", daemon=True
            ),
        ]
        for t in self._threads:
            t.start()

    def stop(self) -> None:
        self._stop.set()
        with self._new_frame:
            self._new_frame.notify_all()
        for t in self._threads:
            t.join(timeout=5.0)
            if t.is_alive():  # pragma: no cover - a driver read hung past its timeout
                log.error("%s: thread %s did not stop", self.name, t.name)
        self._threads = []
        self._tracker.stopped()

    def health(self) -> DeviceHealth:
        """alive: frames arriving; 'disconnected' while the camera cannot be opened or read."""
        return self._tracker.evaluate(self.stats())

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

    def __enter__(self) -> OpenCvCamera:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

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

    def _health(self, healthy: bool, detail: str = "") -> None:
        """Log once when the camera goes and once when it comes back."""
        self._tracker.connected(healthy, detail)
        if healthy == self._healthy:
            return
        was, self._healthy = self._healthy, healthy
        if healthy:
            if was is False:
                log.warning("%s: camera %r is back", self.name, self.config.source)
        else:
            log.warning(
                "%s: camera %r unavailable (%s); retrying with backoff",
                self.name,
                self.config.source,
                detail,
            )

    def _count(self, key: str, n: int = 1) -> None:
        with self._lock:
            self._counts[key] += n

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
                        delay = min(2.0 * delay, cfg.reconnect_max_s)
                    tried = True
                    cap = self._open()
                    if cap is None:
                        self._count("open_failures")
                        self._health(False, "cannot open")
                        continue
                    if self._healthy is False:
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
                self._health(True)
                self._publish(image)
                continue
            failures += 1
            self._count("read_failures")
            self._tracker.error(f"{failures} frame reads failed in a row")
            if failures >= self.config.failures_before_reopen:
                self._health(False, f"{failures} failed reads")
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
                    self._tracker.ended()
                    self.ended.set()
                    self._stop.wait()  # a file that ended stays ended until stop()
                    return cap
            self._health(True)
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
        self._tracker.data(True, frame.t_s)
        with self._new_frame:
            self._counts["frames"] += 1
            if self._latest is not None:
                self._counts["dropped"] += 1
            self._latest = frame
            self._new_frame.notify()

    # delivery thread ---------------------------------------------------------------------------

    def _deliver(self, sink: Callable[[CameraFrame], None]) -> None:
        while True:
            with self._new_frame:
                while self._latest is None and not self._stop.is_set():
                    self._new_frame.wait(0.5)
                if self._stop.is_set():
                    return
                frame, self._latest = self._latest, None
            assert frame is not None
            try:
                sink(frame)
            except Exception:
                self._count("sink_errors")
                if not self._sink_failing:
                    self._sink_failing = True
                    log.exception("%s: the frame sink raised; continuing", self.name)
                continue
            self._count("delivered")
            if self._sink_failing:
                self._sink_failing = False
                log.warning("%s: the frame sink works again", self.name)
