"""Drive recording to MCAP (SPEC section 6) and the reader that replay uses.

Every run can record its raw inputs (``/can``, ``/nmea``, ``/camera`` with
``/camera/thumbnail``, ``/scene``) and its outputs (``/state``, ``/decision``,
``/prompt``, ``/landmark``, ``/health``) to MCAP files that Foxglove opens:
JSON-encoded channels, each with a JSON Schema (``/camera/thumbnail`` uses
Foxglove's own ``foxglove.CompressedImage`` so the Image panel shows it). The
output messages are exactly the telemetry messages (docs/telemetry.md).

Time: a message's MCAP ``log_time`` is its ``t_s`` (the car's monotonic clock,
or simulated time) in nanoseconds, and the JSON payload keeps the exact float
``t_s``; ``publish_time`` is wall-clock nanoseconds, for people.

Crash safety: messages are grouped in small chunks (``chunk_size_bytes``,
default 64 KiB) and a chunk goes to the operating system the moment it is
closed, also every ``flush_interval_s``; so a crash (even SIGKILL) loses at most
the chunk being filled. A file cut short has no summary; ``Reader`` then reads
it record by record up to the damage.

Files rotate by size and age and the oldest are deleted beyond a total cap.
Writing happens on a thread fed by a bounded queue: ``record*`` never blocks,
and when the queue is full the message is dropped and counted. A full disk
(ENOSPC, EDQUOT, or EFBIG from a file-size limit) stops the recording, sets
``health().disk_full`` and counts the error; the caller carries on.
"""

from __future__ import annotations

import base64
import errno
import heapq
import json
import logging
import math
import os
import queue
import re
import struct
import threading
import time
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, fields
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple

from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.records import Channel, Message, Schema
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType, Writer

from guidance.errors import UserError
from guidance.messages import (
    CameraFrame,
    EstimateState,
    IntersectionScene,
    LandmarkFix,
    TurnCompleted,
)
from guidance.telemetry import (
    MESSAGE_SCHEMAS,
    SCHEMA_VERSION,
    InputHealth,
    LandmarkMatch,
    LandmarkRejection,
    TargetLike,
    decision_message,
    health_message,
    landmark_message,
    prompt_message,
    state_message,
)

if TYPE_CHECKING:
    from guidance.navigator import Decision

log = logging.getLogger(__name__)

LIBRARY = "guidance-recorder"
_DISK_FULL_ERRNOS = {errno.ENOSPC, errno.EDQUOT, errno.EFBIG}


# -- channel schemas ------------------------------------------------------------------------------
def _schema(title: str, props: Mapping[str, Any], required: Sequence[str]) -> dict[str, Any]:
    return {
        "$schema": "http://json-schema.org/draft-07/schema#",
        "title": title,
        "type": "object",
        "properties": dict(props),
        "required": list(required),
    }


_T = {"type": "number", "description": "car monotonic clock (or simulated time), s"}
INPUT_SCHEMAS: dict[str, dict[str, Any]] = {
    "can": _schema(
        "guidance.can_frame",
        {
            "t_s": _T,
            "id": {"type": "integer", "description": "arbitration id"},
            "data_hex": {"type": "string"},
            "is_extended_id": {"type": "boolean"},
            "is_error_frame": {"type": "boolean"},
            "channel": {"type": "string"},
        },
        ["t_s", "id", "data_hex"],
    ),
    "nmea": _schema(
        "guidance.nmea_line",
        {"t_s": _T, "line": {"type": "string"}, "port": {"type": "string"}},
        ["t_s", "line"],
    ),
    "camera": _schema(
        "guidance.camera_frame",
        {
            "t_s": _T,
            "source": {"type": "string"},
            "width_px": {"type": ["integer", "null"]},
            "height_px": {"type": ["integer", "null"]},
            "file_ref": {"type": "string", "description": "path of the full frame, if saved"},
            "thumbnail": {"type": "boolean", "description": "a /camera/thumbnail went with it"},
        },
        ["t_s"],
    ),
    "thumbnail": _schema(
        "foxglove.CompressedImage",
        {
            "timestamp": {
                "type": "object",
                "properties": {"sec": {"type": "integer"}, "nsec": {"type": "integer"}},
            },
            "frame_id": {"type": "string"},
            "data": {"type": "string", "contentEncoding": "base64"},
            "format": {"type": "string"},
            "t_s": _T,
        },
        ["timestamp", "frame_id", "data", "format"],
    ),
    "scene": _schema(
        "guidance.scene",
        {
            "t_s": _T,
            "kind": {"type": "string", "enum": ["intersection", "turn"]},
            "exit_headings_rad": {"type": "array", "items": {"type": "number"}},
            "distance_m": {"type": ["number", "null"]},
            "labels": {"type": "array", "items": {"type": "string"}},
            "heading_change_rad": {"type": ["number", "null"]},
            "source": {"type": "string"},
        },
        ["t_s", "kind"],
    ),
}

TOPICS: dict[str, dict[str, Any]] = {
    "/can": INPUT_SCHEMAS["can"],
    "/nmea": INPUT_SCHEMAS["nmea"],
    "/camera": INPUT_SCHEMAS["camera"],
    "/camera/thumbnail": INPUT_SCHEMAS["thumbnail"],
    "/scene": INPUT_SCHEMAS["scene"],
    "/state": MESSAGE_SCHEMAS["state"],
    "/decision": MESSAGE_SCHEMAS["decision"],
    "/prompt": MESSAGE_SCHEMAS["prompt"],
    "/landmark": MESSAGE_SCHEMAS["landmark"],
    "/health": MESSAGE_SCHEMAS["health"],
}
"""Topic -> JSON Schema (its ``title`` is the MCAP schema name). Other topics get a bare one."""
INPUT_TOPICS = ("/can", "/nmea", "/camera", "/scene")
OUTPUT_TOPICS = ("/state", "/decision", "/prompt", "/landmark", "/health")


# -- configuration --------------------------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class RecordingConfig:
    """The ``[recording]`` table of the car's TOML config (docs/telemetry.md)."""

    enabled: bool = True
    directory: str = "recordings"
    prefix: str = "drive"
    vehicle_id: str = "car1"
    chunk_size_bytes: int = 64 * 1024
    flush_interval_s: float = 1.0
    max_file_size_bytes: int = 64 * 1024 * 1024
    max_file_duration_s: float = 600.0
    max_total_size_bytes: int = 2 * 1024 * 1024 * 1024
    queue_size: int = 4096
    thumbnail_interval_s: float = 1.0
    """At most one camera thumbnail this often (0: every frame; negative: none)."""
    thumbnail_width_px: int = 160
    compression: str = "zstd"
    """"zstd", "lz4" or "none" (chunk compression; Foxglove reads all three)."""

    def __post_init__(self) -> None:
        if not re.match(r"^[A-Za-z0-9_.-]{1,64}$", self.prefix):
            raise UserError(f"[recording] prefix {self.prefix!r}: use letters, digits, _ . -")
        if self.compression not in ("zstd", "lz4", "none"):
            raise UserError("[recording] compression must be zstd, lz4 or none")
        positive = (
            "chunk_size_bytes",
            "flush_interval_s",
            "max_file_size_bytes",
            "max_file_duration_s",
            "max_total_size_bytes",
            "queue_size",
            "thumbnail_width_px",
        )
        for name in positive:
            if not getattr(self, name) > 0:
                raise UserError(f"[recording] {name} must be > 0")
        if self.max_total_size_bytes < self.max_file_size_bytes:
            raise UserError("[recording] max_total_size_bytes must be >= max_file_size_bytes")

    @classmethod
    def from_mapping(
        cls, table: Mapping[str, Any], base_dir: Path | None = None
    ) -> RecordingConfig:
        """Build from a parsed ``[recording]`` TOML table; ``directory`` is relative to base_dir."""
        types = {f.name: f.type for f in fields(cls)}
        unknown = sorted(set(table) - set(types))
        if unknown:
            raise UserError(f"[recording]: unknown key(s) {', '.join(unknown)}")
        kwargs: dict[str, Any] = {}
        for key, value in table.items():
            want = types[key]
            ok = {
                "bool": isinstance(value, bool),
                "int": isinstance(value, int) and not isinstance(value, bool),
                "float": isinstance(value, int | float) and not isinstance(value, bool),
                "str": isinstance(value, str),
            }.get(str(want), False)
            if not ok:
                raise UserError(f"[recording] {key} must be {want}, not {value!r}")
            kwargs[key] = float(value) if want == "float" else value
        if base_dir is not None and "directory" in kwargs:
            d = Path(kwargs["directory"])
            kwargs["directory"] = str(d if d.is_absolute() else base_dir / d)
        return cls(**kwargs)


_COMPRESSION = {
    "zstd": CompressionType.ZSTD,
    "lz4": CompressionType.LZ4,
    "none": CompressionType.NONE,
}


# -- health ----------------------------------------------------------------------------------------
DISK_FULL_WARNING = "Recording stopped. The disk is full."
RECORDING_FAILED_WARNING = "Recording stopped after a write error."


@dataclass(frozen=True, slots=True)
class RecorderHealth:
    """The recorder's health; ``as_dict`` also carries the keys every component's health has
    (status, alive, valid, ok, warning: docs/reliability.md)."""

    recording: bool
    """Accepting and writing messages."""
    disk_full: bool
    written: int
    dropped: int
    """Messages refused because the queue was full or the recording had stopped."""
    errors: int
    files_deleted: int
    current_file: str
    bytes_written: int
    last_error: str
    failed: bool = False
    """Stopped by an I/O error (disk full or another); stays stopped until restarted."""

    @property
    def status(self) -> str:
        if self.disk_full:
            return "disk_full"
        if self.failed:
            return "failed"
        return "recording" if self.recording else "stopped"

    @property
    def alive(self) -> bool:
        return self.recording

    @property
    def valid(self) -> bool:
        return not self.failed

    @property
    def ok(self) -> bool:
        return self.alive and self.valid

    @property
    def warning(self) -> str:
        if self.disk_full:
            return DISK_FULL_WARNING
        return RECORDING_FAILED_WARNING if self.failed else ""

    def as_dict(self) -> dict[str, Any]:
        out = {f.name: getattr(self, f.name) for f in fields(self)}
        out.update(
            status=self.status,
            alive=self.alive,
            valid=self.valid,
            ok=self.ok,
            warning=self.warning,
        )
        return out


class _DirectFile:
    """A binary file whose every ``write`` goes straight to the OS (no user-space buffer).

    ``mcap.Writer`` wraps raw files in a ``BufferedWriter``; handing it this
    instead means a chunk reaches the kernel as soon as mcap closes it, so a
    killed process loses only the chunk in progress.
    """

    def __init__(self, path: Path) -> None:
        self.path = path
        self._fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
        self._pos = 0

    def write(self, data: bytes | bytearray | memoryview) -> int:
        view = memoryview(data)
        while view:
            n = os.write(self._fd, view)
            view = view[n:]
            self._pos += n
        return len(data)

    def tell(self) -> int:
        return self._pos

    def flush(self) -> None:
        return None

    def fsync(self) -> None:
        os.fsync(self._fd)

    def close(self) -> None:
        if self._fd >= 0:
            fd, self._fd = self._fd, -1
            os.close(fd)


@dataclass(slots=True)
class _Item:
    topic: str
    t_s: float
    build: Callable[[], dict[str, Any]]
    wall_ns: int


_STOP = object()


class _OpenFile:
    """One MCAP file being written: the writer, its channels and when it was opened."""

    def __init__(self, path: Path, cfg: RecordingConfig, index: int, wall_s: float) -> None:
        self.path = path
        self.file = _DirectFile(path)
        try:
            self._start(cfg, index, wall_s)
        except BaseException:
            self.file.close()
            raise

    def _start(self, cfg: RecordingConfig, index: int, wall_s: float) -> None:
        self.writer = Writer(
            self.file,  # type: ignore[arg-type]  # duck-typed binary stream
            chunk_size=cfg.chunk_size_bytes,
            compression=_COMPRESSION[cfg.compression],
        )
        self.opened_mono_s = time.monotonic()
        self.channels: dict[str, int] = {}
        self.sequence: dict[int, int] = {}
        self.writer.start(profile="", library=LIBRARY)
        self.writer.add_metadata(
            "recording",
            {
                "vehicle_id": cfg.vehicle_id,
                "index": str(index),
                "schema_version": str(SCHEMA_VERSION),
                "log_time": "t_s of the message (car monotonic clock or simulated time), ns",
                "publish_time": "wall clock when recorded, ns since the Unix epoch",
                "opened_wall_time_unix_s": f"{wall_s:.6f}",
            },
        )
        for topic in TOPICS:
            self.channel(topic)

    def channel(self, topic: str) -> int:
        cid = self.channels.get(topic)
        if cid is None:
            schema = TOPICS.get(topic) or _schema(f"guidance{topic.replace('/', '.')}", {}, [])
            sid = self.writer.register_schema(
                name=schema["title"], encoding="jsonschema", data=json.dumps(schema).encode()
            )
            cid = self.writer.register_channel(topic=topic, message_encoding="json", schema_id=sid)
            self.channels[topic] = cid
        return cid

    def write(self, topic: str, log_time_ns: int, publish_ns: int, data: bytes) -> None:
        cid = self.channel(topic)
        seq = self.sequence.get(cid, 0) + 1
        self.sequence[cid] = seq
        self.writer.add_message(
            channel_id=cid, log_time=log_time_ns, data=data, publish_time=publish_ns, sequence=seq
        )

    def finish(self) -> None:
        try:
            self.writer.finish()
            self.file.fsync()
        finally:
            self.file.close()

    def abandon(self) -> None:
        self.file.close()


class Recorder:
    """Records inputs and outputs of a run to rotating MCAP files, off the caller's thread.

    ``record*`` methods return False when the message was not queued (queue
    full, recording stopped or disabled). ``clock`` is wall time, used only for
    ``publish_time`` and file names.
    """

    def __init__(self, config: RecordingConfig, *, clock: Callable[[], float] = time.time) -> None:
        self.config = config
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
        self._warned_thumbnail = False
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

    def health(self) -> RecorderHealth:
        cur = self._current
        return RecorderHealth(
            recording=self._accepting,
            disk_full=self._disk_full,
            written=self._written,
            dropped=self._dropped,
            errors=self._errors,
            files_deleted=self._deleted,
            current_file=str(cur.path) if cur is not None else "",
            bytes_written=self._bytes,
            last_error=self._last_error,
            failed=self._failed,
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

    def record_scene(self, event: IntersectionScene | TurnCompleted) -> bool:
        if isinstance(event, IntersectionScene):
            body: dict[str, Any] = {
                "t_s": event.t_s,
                "kind": "intersection",
                "exit_headings_rad": list(event.exit_headings_rad),
                "distance_m": event.distance_m,
                "labels": list(event.labels),
                "heading_change_rad": None,
                "source": "",
            }
        else:
            body = {
                "t_s": event.t_s,
                "kind": "turn",
                "exit_headings_rad": [],
                "distance_m": None,
                "labels": [],
                "heading_change_rad": event.heading_change_rad,
                "source": event.source,
            }
        return self._put("/scene", event.t_s, lambda: body)

    def record_state(
        self,
        state: EstimateState,
        *,
        speed_mps: float | None = None,
        target: TargetLike | None = None,
        goal: tuple[float, float] | None = None,
        method: str | None = None,
        mode: str | None = None,
    ) -> bool:
        return self._put(
            "/state",
            state.t_s,
            partial(
                state_message,
                state,
                vehicle_id=self.config.vehicle_id,
                speed_mps=speed_mps,
                target=target,
                goal=goal,
                method=method,
                mode=mode,
            ),
        )

    def record_decision(self, decision: Decision) -> bool:
        return self._put(
            "/decision",
            getattr(decision, "t_s", math.nan),  # a bad object fails on the writer thread
            partial(decision_message, decision, vehicle_id=self.config.vehicle_id),
        )

    def record_prompt(
        self, t_s: float, text: str, *, kind: str = "info", priority: int = 0
    ) -> bool:
        return self._put(
            "/prompt",
            t_s,
            partial(
                prompt_message,
                t_s,
                text,
                vehicle_id=self.config.vehicle_id,
                kind=kind,
                priority=priority,
            ),
        )

    def record_landmark(
        self,
        t_s: float,
        *,
        matches: Sequence[LandmarkMatch | LandmarkFix] = (),
        rejections: Sequence[LandmarkRejection] = (),
        gated: int | None = None,
    ) -> bool:
        return self._put(
            "/landmark",
            t_s,
            partial(
                landmark_message,
                t_s,
                vehicle_id=self.config.vehicle_id,
                matches=tuple(matches),
                rejections=tuple(rejections),
                gated=gated,
            ),
        )

    def record_health(
        self,
        t_s: float,
        inputs: Mapping[str, InputHealth | Mapping[str, Any]],
        *,
        components: Mapping[str, Mapping[str, Any]] | None = None,
    ) -> bool:
        comps = {**(components or {}), "recorder": self.health().as_dict()}
        return self._put(
            "/health",
            t_s,
            partial(
                health_message,
                t_s,
                dict(inputs),
                vehicle_id=self.config.vehicle_id,
                components=comps,
            ),
        )

    def _put(self, topic: str, t_s: float, build: Callable[..., dict[str, Any]]) -> bool:
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
            body = item.build()
            thumb = body.pop("_thumbnail", None) if item.topic == "/camera" else None
            data = json.dumps(body, separators=(",", ":"), allow_nan=False).encode()
        except Exception as exc:  # a malformed message must not stop the recording
            with self._lock:
                self._errors += 1
            log.error("recorder: cannot encode a %s message: %r", item.topic, exc)
            return
        log_ns = max(0, round(item.t_s * 1e9)) if math.isfinite(item.t_s) else 0
        try:
            cur = self._current
            if cur is None or self._rotation_due(cur):
                cur = self._rotate()
            before = cur.file.tell()
            cur.write(item.topic, log_ns, item.wall_ns, data)
            if thumb is not None:
                cur.write("/camera/thumbnail", log_ns, item.wall_ns, thumb)
            self._bytes += cur.file.tell() - before
            self._written += 1
        except OSError as exc:
            self._fail(f"writing {self._current.path if self._current else 'a file'}", exc)

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
                sec = math.floor(frame.t_s)
                thumb = {
                    "timestamp": {"sec": sec, "nsec": round((frame.t_s - sec) * 1e9)},
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


# -- reading ------------------------------------------------------------------------------------
class RecordedMessage(NamedTuple):
    topic: str
    t_s: float
    data: dict[str, Any]


def recording_files(source: str | Path | Sequence[str | Path]) -> list[Path]:
    """The MCAP files of a recording: one file, a folder of rotated files, or a list."""
    if isinstance(source, str | Path):
        p = Path(source)
        if p.is_dir():
            files = sorted(p.glob("*.mcap"))
            if not files:
                raise UserError(f"no .mcap files in {p}")
            return files
        if not p.is_file():
            raise UserError(f"recording not found: {p}")
        return [p]
    files = [Path(s) for s in source]
    for p in files:
        if not p.is_file():
            raise UserError(f"recording not found: {p}")
    return files


class Reader:
    """Messages of one MCAP file or a rotated set, as (topic, t_s, dict), in log-time order.

    ``log_time_order=False`` gives them in the order they were written (the
    order the application recorded them). Files cut short by a crash are read
    up to the damage and listed in ``recovered``; messages that are not JSON
    objects are skipped and counted in ``skipped``.
    """

    def __init__(
        self,
        source: str | Path | Sequence[str | Path],
        *,
        topics: Iterable[str] | None = None,
        log_time_order: bool = True,
    ) -> None:
        self.files = recording_files(source)
        self.topics = None if topics is None else frozenset(topics)
        self.log_time_order = log_time_order
        self.recovered: list[Path] = []
        self.skipped = 0

    def __iter__(self) -> Iterator[RecordedMessage]:
        streams = [self._iter_file(p) for p in self.files]
        if not self.log_time_order:
            for stream in streams:
                for _, msg in stream:
                    yield msg
            return
        for _, msg in heapq.merge(*streams, key=lambda pair: pair[0]):
            yield msg

    def channels(self) -> dict[str, str]:
        """Topic -> schema name over all files (readable summaries or a scan)."""
        out: dict[str, str] = {}
        for path in self.files:
            with path.open("rb") as f:
                summary = _summary(f)
                if summary is not None:
                    for ch in summary.channels.values():
                        sch = summary.schemas.get(ch.schema_id)
                        out.setdefault(ch.topic, sch.name if sch else "")
                    continue
                f.seek(0)
                schemas: dict[int, str] = {}
                for record in _records_until_damage(f):
                    if isinstance(record, Schema):
                        schemas[record.id] = record.name
                    elif isinstance(record, Channel):
                        out.setdefault(record.topic, schemas.get(record.schema_id, ""))
        return out

    def _iter_file(self, path: Path) -> Iterator[tuple[int, RecordedMessage]]:
        with path.open("rb") as f:
            summary = _summary(f)
            if summary is not None and summary.chunk_indexes:
                reader = make_reader(f)
                for _schema_rec, channel, message in reader.iter_messages(
                    topics=self.topics, log_time_order=self.log_time_order
                ):
                    rec = self._decode(channel.topic, message)
                    if rec is not None:
                        yield message.log_time, rec
                return
            if summary is None:
                self.recovered.append(path)
                log.info("recording %s has no summary (cut short?): reading up to the damage", path)
            f.seek(0)
            channels: dict[int, str] = {}
            found: list[tuple[int, RecordedMessage]] = []
            for record in _records_until_damage(f):
                if isinstance(record, Channel):
                    channels[record.id] = record.topic
                elif isinstance(record, Message):
                    topic = channels.get(record.channel_id)
                    if topic is None or (self.topics is not None and topic not in self.topics):
                        continue
                    rec = self._decode(topic, record)
                    if rec is not None:
                        found.append((record.log_time, rec))
            if self.log_time_order:
                found.sort(key=lambda pair: pair[0])
            yield from found

    def _decode(self, topic: str, message: Message) -> RecordedMessage | None:
        try:
            data = json.loads(message.data)
        except ValueError:
            data = None
        if not isinstance(data, dict):
            self.skipped += 1
            return None
        t_s = data.get("t_s")
        if not isinstance(t_s, int | float) or isinstance(t_s, bool):
            t_s = message.log_time / 1e9
        return RecordedMessage(topic, float(t_s), data)


def read_messages(
    source: str | Path | Sequence[str | Path], topics: Iterable[str] | None = None
) -> Iterator[RecordedMessage]:
    """Shortcut: ``Reader(source, topics=topics)`` iterated."""
    return iter(Reader(source, topics=topics))


def _summary(f: Any) -> Any:
    """The file's summary section, or None when it has none or is cut short."""
    try:
        return make_reader(f).get_summary()
    except Exception as exc:  # a cut-short file ends in arbitrary bytes: any parse error
        log.debug("recording: no readable summary: %s", exc)
        return None


def _records_until_damage(f: Any) -> Iterator[Any]:
    """MCAP records in file order, stopping quietly at a truncated or corrupt record."""
    records = StreamReader(f, skip_magic=False).records
    while True:
        try:
            record = next(records)
        except StopIteration:
            return
        except (McapError, struct.error, ValueError, EOFError) as exc:
            log.debug("recording: stopped at damaged record: %s", exc)
            return
        except Exception as exc:  # decompression errors come from zstd/lz4 with their own types
            log.debug("recording: stopped at undecodable record: %s", exc)
            return
        yield record
