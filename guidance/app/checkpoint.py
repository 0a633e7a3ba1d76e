"""Crash recovery: the pipeline's state written atomically every few seconds (issue 7).

A checkpoint is one small JSON file: the estimator (pose, covariance, time), the navigator's
memory (remembered intersections, exits taken, mode, passed landmarks), the pending decision
and counters (``Pipeline.snapshot``), plus whatever the caller adds under ``extra`` (the
simulation stores its world's seed and route so far). It is written to a temporary file in the
same folder, flushed, fsynced and renamed over the old one with ``os.replace``: a reader (the
restarted process) sees the previous checkpoint or the new one, never half of one, even after
``kill -9`` or a power cut in the middle of a write.

The interval is measured on the message clock, so an accelerated simulation checkpoints as
often per simulated minute as the car does per real minute.
"""

from __future__ import annotations

import contextlib
import json
import logging
import math
import os
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from guidance.errors import UserError

log = logging.getLogger(__name__)

SCHEMA = "guidance.checkpoint/1"


class Checkpointer:
    """Writes checkpoints to ``path`` at most every ``interval_s`` of message time."""

    def __init__(self, path: str | Path, interval_s: float = 5.0) -> None:
        if not (math.isfinite(interval_s) and interval_s > 0):
            raise UserError(f"checkpoint interval must be > 0 s, not {interval_s!r}")
        self.path = Path(path)
        self.interval_s = interval_s
        self.saved = 0
        self.errors = 0
        self._next_t = -math.inf
        self._failing = False

    def due(self, t_s: float) -> bool:
        return t_s >= self._next_t

    def maybe_save(self, t_s: float, state: Mapping[str, Any]) -> bool:
        """Save when due; True when written."""
        if not self.due(t_s):
            return False
        return self.save(t_s, state)

    def save(self, t_s: float, state: Mapping[str, Any]) -> bool:
        """Write now (atomically). A failure (disk full, read-only) is logged once, not raised."""
        self._next_t = t_s + self.interval_s
        doc = {"schema": SCHEMA, "t_s": t_s, "wall_time_unix_s": time.time(), **state}
        try:
            write_atomic(self.path, json.dumps(doc, allow_nan=False).encode())
        except (OSError, ValueError) as exc:
            self.errors += 1
            if not self._failing:
                self._failing = True
                log.warning("checkpoint %s not written: %s", self.path, exc)
            return False
        if self._failing:
            self._failing = False
            log.warning("checkpoint %s written again", self.path)
        self.saved += 1
        return True


def write_atomic(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` so that readers see the old or the new content, never a mix."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
    try:
        view = memoryview(data)
        while view:
            n = os.write(fd, view)
            view = view[n:]
        os.fsync(fd)
    finally:
        os.close(fd)
    try:
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise
    with contextlib.suppress(OSError):  # make the rename itself durable
        dfd = os.open(path.parent, os.O_RDONLY)
        try:
            os.fsync(dfd)
        finally:
            os.close(dfd)


def load_checkpoint(path: str | Path) -> dict[str, Any] | None:
    """The checkpoint at ``path``, or None when there is none; a damaged one is a UserError."""
    p = Path(path)
    try:
        raw = p.read_bytes()
    except FileNotFoundError:
        return None
    except OSError as exc:
        raise UserError(f"checkpoint {p}: {exc.strerror or exc}") from None
    try:
        doc = json.loads(raw)
    except ValueError as exc:
        raise UserError(f"checkpoint {p} is damaged ({exc}); delete it to start afresh") from None
    if not isinstance(doc, dict) or doc.get("schema") != SCHEMA:
        raise UserError(f"checkpoint {p} is not a {SCHEMA} file; delete it to start afresh")
    return doc
