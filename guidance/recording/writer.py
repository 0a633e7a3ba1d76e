"""``Recorder``: a bounded queue and a writer thread."""

from __future__ import annotations

import base64
import errno
import json
import logging
import math
import queue
import re
import threading
import time
from collections.abc import Callable, Mapping
from functools import partial
from pathlib import Path
from typing import Any

from guidance.core.messages import (
    CameraFrame,
    Health,
)
from guidance.outputs.messages import heading_deg_true
from guidance.outputs.sink import Build, MessageSink
from guidance.recording.config import RecordingConfig
from guidance.recording.files import _STOP, _Item, _OpenFile
from guidance.recording.foxglove import FoxgloveView, stamp
from guidance.recording.health import recorder_health
from guidance.recording.topics import _DISK_FULL_ERRNOS

log = logging.getLogger(__name__)


class Recorder(MessageSink):
    """Records inputs and outputs of a run to rotating MCAP files, off the caller's thread.

    ``record*`` methods return False when the message was not queued (queue
    full, recording stopped or disabled). ``clock`` is wall time, used only for
    ``publish_time`` and file names.
    """

    def __init__(self, config: RecordingConfig, *, clock: Callable[[], float] = time.time) -> None:
        self.config = config
        self.origin_lat_lon_deg = config.origin_lat_lon_deg
        self._clock = clock
        self._queue: queue.Queue[_Item | object] = queue.Queue(maxsize=config.queue_size)
        self._lock = threading.Lock()
        self._thread: threading.Thread | None = None
        self._accepting = False
        self._disk_full = False
        self._failed = False
        self._written = 0
        self._dropped = 0
        self._errors = 0
        self._deleted = 0
        self._bytes = 0
        self._last_error = ""
        self._current: _OpenFile | None = None
        self._index = 0
        self._session_stamp = ""
        self._last_thumb_t_s = -math.inf
        self._last_truth_t_s = -math.inf
        self._warned_thumbnail = False
        self._foxglove = FoxgloveView(config.origin_lat_lon_deg)
        self.files: list[Path] = []

    # -- lifecycle ----------------------------------------------------------------------------
    def start(self) -> None:
        """Create the directory and start the writer thread (files open on the first message)."""
        if not self.config.enabled or self._thread is not None:
            return
        directory = Path(self.config.directory)
        try:
            directory.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            self._fail(f"cannot create {directory}: {exc.strerror or exc}", exc)
            return
        self._session_stamp = time.strftime("%Y%m%d-%H%M%S", time.gmtime(self._clock()))
        self._accepting = True
        self._thread = threading.Thread(target=self._run, name="recorder", daemon=True)
        self._thread.start()

    def close(self, timeout_s: float = 10.0) -> None:
        """Write what is queued, finish the current file (summary, footer) and stop."""
        self._accepting = False
        thread, self._thread = self._thread, None
        if thread is None:
            return
        while True:
            try:
                self._queue.put(_STOP, timeout=0.1)
                break
            except queue.Full:
                if not thread.is_alive():
                    break
        thread.join(timeout_s)
        if thread.is_alive():
            log.warning("recorder: writer thread did not stop within %.0f s", timeout_s)

    def __enter__(self) -> Recorder:
        self.start()
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()

    def health(self) -> Health:
        cur = self._current
        return recorder_health(
            recording=self._accepting,
            disk_full=self._disk_full,
            failed=self._failed,
            counters={
                "written": self._written,
                "dropped": self._dropped,
                "errors": self._errors,
                "files_deleted": self._deleted,
                "bytes_written": self._bytes,
            },
            current_file=str(cur.path) if cur is not None else "",
            detail=self._last_error,
        )

    # -- recording (any thread, never blocks) --------------------------------------------------
    def record(self, topic: str, t_s: float, message: Mapping[str, Any]) -> bool:
        """Queue one JSON-able message on ``topic`` at time ``t_s``."""
        body = dict(message)
        body.setdefault("t_s", t_s)
        return self._put(topic, t_s, lambda: body)

    def record_can(
        self,
        t_s: float,
        arbitration_id: int,
        data: bytes,
        *,
        is_extended_id: bool = False,
        is_error_frame: bool = False,
        channel: str = "",
    ) -> bool:
        body = {
            "t_s": t_s,
            "id": int(arbitration_id),
            "data_hex": bytes(data).hex(),
            "is_extended_id": is_extended_id,
            "is_error_frame": is_error_frame,
            "channel": channel,
        }
        return self._put("/can", t_s, lambda: body)

    def record_nmea(self, t_s: float, line: str | bytes, *, port: str = "") -> bool:
        text = line.decode("ascii", errors="backslashreplace") if isinstance(line, bytes) else line
        body = {"t_s": t_s, "line": text.rstrip("\r\n"), "port": port}
        return self._put("/nmea", t_s, lambda: body)

    def record_camera(self, frame: CameraFrame, *, file_ref: str = "") -> bool:
        """The frame's time, size and (rate-limited, on the writer thread) a JPEG thumbnail.

        The image array is read later on the writer thread: the camera must not
        reuse it in place (drivers here hand out a new array per frame).
        """
        return self._put("/camera", frame.t_s, partial(self._camera_body, frame, file_ref))

    def record_truth(self, t_s: float, x_m: float, y_m: float, heading_rad: float) -> bool:
        """The true pose (simulated drives): ``/truth`` and its Foxglove views, at most one per
        ``truth_interval_s``; False when skipped by the rate limit or not queued."""
        if t_s - self._last_truth_t_s < self.config.truth_interval_s - 1e-9:
            return False
        self._last_truth_t_s = t_s
        body = {
            "t_s": t_s,
            "x_m": float(x_m),
            "y_m": float(y_m),
            "heading_rad": float(heading_rad),
            "heading_deg_true": heading_deg_true(float(heading_rad)),
        }
        return self._put("/truth", t_s, lambda: body)

    def publish(self, kind: str, t_s: float, build: Build) -> bool:
        """The sink port (``guidance.outputs.sink``): one bounded FIFO for every kind."""
        return self._put(f"/{kind}", t_s, partial(build, vehicle_id=self.config.vehicle_id))

    def own_health(self) -> Health:
        return self.health()

    def _put(self, topic: str, t_s: float, build: Callable[..., Mapping[str, Any]]) -> bool:
        if not self._accepting:
            if self._failed:
                with self._lock:
                    self._dropped += 1
            return False
        item = _Item(topic, t_s, build, int(self._clock() * 1e9))
        try:
            self._queue.put_nowait(item)
        except queue.Full:
            with self._lock:
                self._dropped += 1
            return False
        return True

    # -- writer thread --------------------------------------------------------------------------
    def _run(self) -> None:
        next_flush = time.monotonic() + self.config.flush_interval_s
        try:
            while True:
                timeout = max(0.0, next_flush - time.monotonic())
                try:
                    item = self._queue.get(timeout=timeout)
                except queue.Empty:
                    item = None
                if item is _STOP:
                    break
                try:
                    if isinstance(item, _Item) and not self._failed:
                        self._write(item)
                    if time.monotonic() >= next_flush:
                        self._flush()
                        next_flush = time.monotonic() + self.config.flush_interval_s
                except Exception as exc:  # e.g. an mcap error: stop cleanly, never silently
                    log.exception("recorder: unexpected error")
                    self._fail("recording", OSError(errno.EIO, repr(exc)))
        finally:
            self._finish_current()

    def _write(self, item: _Item) -> None:
        try:
            body = dict(item.build())
            thumb = body.pop("_thumbnail", None) if item.topic == "/camera" else None
            data = json.dumps(body, separators=(",", ":"), allow_nan=False).encode()
        except Exception as exc:  # a malformed message must not stop the recording
            with self._lock:
                self._errors += 1
            log.error("recorder: cannot encode a %s message: %r", item.topic, exc)
            return
        views = self._foxglove_views(item.topic, body)
        log_ns = max(0, round(item.t_s * 1e9)) if math.isfinite(item.t_s) else 0
        try:
            cur = self._current
            if cur is None or self._rotation_due(cur):
                cur = self._rotate()
            before = cur.file.tell()
            cur.write(item.topic, log_ns, item.wall_ns, data)
            if thumb is not None:
                cur.write("/camera/thumbnail", log_ns, item.wall_ns, thumb)
            for topic, view in views:
                cur.write(topic, log_ns, item.wall_ns, view)
            self._bytes += cur.file.tell() - before
            self._written += 1
        except OSError as exc:
            self._fail(f"writing {self._current.path if self._current else 'a file'}", exc)

    def _foxglove_views(self, topic: str, body: dict[str, Any]) -> list[tuple[str, bytes]]:
        """The Foxglove messages that go with one message (``guidance.recording.foxglove``)."""
        try:
            return [
                (t, json.dumps(m, separators=(",", ":"), allow_nan=False).encode())
                for t, m in self._foxglove.derive(topic, body)
            ]
        except Exception as exc:  # the message itself is still recorded
            with self._lock:
                self._errors += 1
            log.error("recorder: no Foxglove view of a %s message: %r", topic, exc)
            return []

    def _camera_body(self, frame: CameraFrame, file_ref: str) -> dict[str, Any]:
        image = frame.image
        shape = getattr(image, "shape", None)
        h, w = (int(shape[0]), int(shape[1])) if shape is not None and len(shape) >= 2 else (0, 0)
        body: dict[str, Any] = {
            "t_s": frame.t_s,
            "source": frame.source,
            "width_px": w or None,
            "height_px": h or None,
            "file_ref": file_ref,
            "thumbnail": False,
        }
        interval = self.config.thumbnail_interval_s
        if shape is not None and interval >= 0 and frame.t_s - self._last_thumb_t_s >= interval:
            jpeg = self._thumbnail_jpeg(image)
            if jpeg is not None:
                self._last_thumb_t_s = frame.t_s
                body["thumbnail"] = True
                thumb = {
                    "timestamp": stamp(frame.t_s),
                    "frame_id": frame.source or "camera",
                    "format": "jpeg",
                    "data": base64.b64encode(jpeg).decode("ascii"),
                    "t_s": frame.t_s,
                }
                # carried to _write, which sends it on its own channel and removes it from body
                body["_thumbnail"] = json.dumps(thumb, separators=(",", ":")).encode()
        return body

    def _thumbnail_jpeg(self, image: Any) -> bytes | None:
        try:
            import cv2

            h, w = image.shape[:2]
            width = min(self.config.thumbnail_width_px, w)
            small = cv2.resize(image, (width, max(1, round(h * width / w))))
            ok, buf = cv2.imencode(".jpg", small, [cv2.IMWRITE_JPEG_QUALITY, 70])
            return bytes(buf) if ok else None
        except Exception as exc:  # no OpenCV, odd array: the frame record still goes
            if not self._warned_thumbnail:
                log.warning("recorder: no camera thumbnails: %s", exc)
                self._warned_thumbnail = True
            return None

    def _rotation_due(self, cur: _OpenFile) -> bool:
        return (
            cur.file.tell() >= self.config.max_file_size_bytes
            or time.monotonic() - cur.opened_mono_s >= self.config.max_file_duration_s
        )

    def _rotate(self) -> _OpenFile:
        self._finish_current()
        directory = Path(self.config.directory)
        while True:  # a restart within the same second finds its predecessor's names taken
            self._index += 1
            name = f"{self.config.prefix}-{self._session_stamp}-{self._index:04d}.mcap"
            path = directory / name
            if not path.exists():
                break
        cur = _OpenFile(path, self.config, self._index, self._clock())
        self._current = cur
        self.files.append(path)
        log.info("recorder: writing %s", path)
        self._enforce_cap(keep=path)
        return cur

    def _enforce_cap(self, keep: Path) -> None:
        """Delete the oldest recordings (this prefix, this folder) beyond the total size cap."""
        pattern = re.compile(rf"^{re.escape(self.config.prefix)}-\d{{8}}-\d{{6}}-\d{{4}}\.mcap$")
        files = []
        for p in Path(self.config.directory).iterdir():
            if pattern.match(p.name):
                try:
                    files.append((p.name, p, p.stat().st_size))
                except FileNotFoundError:
                    continue
        files.sort()
        total = sum(size for _, _, size in files)
        for _, path, size in files:
            if total <= self.config.max_total_size_bytes:
                break
            if path == keep:
                continue
            try:
                path.unlink()
            except OSError as exc:
                log.warning("recorder: cannot delete %s to keep under the cap: %s", path, exc)
                continue
            total -= size
            self._deleted += 1
            log.info("recorder: deleted %s (total size cap)", path.name)

    def _flush(self) -> None:
        cur = self._current
        if cur is None:
            return
        flush = getattr(cur.writer, "flush", None)  # mcap >= 1.6; before, chunks close by size
        if flush is None:
            return
        try:
            before = cur.file.tell()
            flush()
            self._bytes += cur.file.tell() - before
        except OSError as exc:
            self._fail(f"writing {cur.path}", exc)

    def _finish_current(self) -> None:
        cur, self._current = self._current, None
        if cur is None:
            return
        try:
            cur.finish()
        except OSError as exc:
            cur.abandon()
            self._fail(f"finishing {cur.path}", exc)

    def _fail(self, what: str, exc: OSError) -> None:
        """Stop recording after an I/O error; the caller keeps running."""
        disk_full = exc.errno in _DISK_FULL_ERRNOS
        with self._lock:
            self._errors += 1
        self._last_error = f"{what}: {exc.strerror or exc}"
        if not self._failed:
            log.error(
                "recorder: %s; recording stopped%s",
                self._last_error,
                " (disk full)" if disk_full else "",
            )
        self._disk_full = self._disk_full or disk_full
        self._failed = True
        self._accepting = False
        cur, self._current = self._current, None
        if cur is not None:
            cur.abandon()
