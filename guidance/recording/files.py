"""Crash-safe MCAP files: direct writes, rotation units."""

from __future__ import annotations

import json
import os
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from mcap.writer import Writer

from guidance.outputs.messages import SCHEMA_VERSION
from guidance.recording.config import _COMPRESSION, RecordingConfig
from guidance.recording.topics import LIBRARY, TOPICS, _schema


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
    build: Callable[[], Mapping[str, Any]]
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
        self.schemas: dict[str, int] = {}
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
            sid = self.schemas.get(schema["title"])
            if sid is None:  # one schema record per name (several topics may share one)
                data = json.dumps(schema, separators=(",", ":")).encode()
                sid = self.writer.register_schema(
                    name=schema["title"], encoding="jsonschema", data=data
                )
                self.schemas[schema["title"]] = sid
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
