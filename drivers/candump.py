"""Reading candump ``-L`` logs (``.log``, optionally ``.gz``) line by line, defensively (issue 14).

A log is text from outside: every line is checked against the candump format before python-can
parses it, so a line missing one hex digit is rejected instead of decoded with a shifted byte,
and a time like ``1_0_0`` (which ``float()`` accepts) is not a time. Lines are read with a bound
(``MAX_LINE_BYTES``): a 200 MB line costs 64 KiB of memory, not 1.5 GB, and is counted as
unreadable. A damaged or truncated ``.gz`` stream ends the reading with the frames before the
damage kept and ``LogReadResult.error`` saying where.
"""

from __future__ import annotations

import gzip
import io
import re
import zlib
from collections.abc import Iterator
from pathlib import Path
from typing import Protocol

import can

from guidance import files

MAX_LINE_BYTES = 4096
"""A candump line is under 300 bytes (CAN FD, 64 data bytes); longer is not a candump line."""
_READ = 1 << 16

CANDUMP_LINE = re.compile(
    rb"\(\s*[0-9]+(?:\.[0-9]+)?\)\s+\S+\s+"  # (time) interface
    rb"(?:[0-9A-Fa-f]{3}|[0-9A-Fa-f]{8})"  # standard or extended id
    rb"(?:#R[0-9A-Fa-f]?|#(?:[0-9A-Fa-f]{2})*|##[0-9A-Fa-f](?:[0-9A-Fa-f]{2})*)"  # data
    rb"(?:\s+[RT])?"  # direction (python-can writes it)
)
"""One candump ``-L`` line: whole bytes of data only (an odd hex digit is damage)."""


class _Readable(Protocol):
    def readline(self, size: int = -1, /) -> bytes: ...


class ReadResult(Protocol):
    unreadable: int
    error: str | None


def bounded_lines(raw: _Readable, result: ReadResult) -> Iterator[bytes]:
    """Lines of ``raw`` of at most ``MAX_LINE_BYTES``; a longer one is skipped (counted) without
    being held in memory."""
    while True:
        line = raw.readline(MAX_LINE_BYTES + 1)
        if not line:
            return
        if len(line) > MAX_LINE_BYTES and not line.endswith(b"\n"):
            result.unreadable += 1
            while True:  # drop the rest of the line, a buffer at a time
                rest = raw.readline(_READ)
                if not rest or rest.endswith(b"\n"):
                    break
            continue
        yield line


def read_candump(path: Path, gz: bool, result: ReadResult) -> Iterator[can.Message]:
    """Frames of a candump log; bad lines counted in ``result.unreadable``, a damaged stream
    stops with ``result.error`` (the frames before it are kept)."""
    lines = 0
    with files.opened(path, "can_log") as f, gzip.open(f, "rb") if gz else f as raw:
        try:
            for line in bounded_lines(raw, result):
                lines += 1
                text = line.strip()
                if not text:
                    continue
                if CANDUMP_LINE.fullmatch(text) is None:
                    result.unreadable += 1
                    continue
                try:
                    msgs = list(can.CanutilsLogReader(io.StringIO(text.decode("ascii"))))
                except Exception:  # python-can raises ValueError/IndexError on a bad line
                    result.unreadable += 1
                    continue
                yield from msgs
        except (EOFError, OSError, zlib.error) as exc:  # truncated or corrupt .gz
            result.unreadable += 1
            why = getattr(exc, "strerror", None) or exc
            result.error = f"the file is damaged after line {lines}: {why}"
