"""Reading recordings, tolerant of damage."""

from __future__ import annotations

import heapq
import logging
import math
from collections.abc import Iterable, Iterator, Sequence
from pathlib import Path
from typing import Any, NamedTuple

from mcap.reader import make_reader
from mcap.records import Channel, Message, Schema

from guidance import files
from guidance.errors import UserError
from guidance.recording.scan import Damage, scan_records

log = logging.getLogger(__name__)


# -- reading ------------------------------------------------------------------------------------
class RecordedMessage(NamedTuple):
    topic: str
    t_s: float
    data: dict[str, Any]


def recording_files(source: str | Path | Sequence[str | Path]) -> list[Path]:
    """The MCAP files of a recording: one file, a folder of rotated files, or a list; each a
    regular file (``guidance.files``: a FIFO or ``/dev/zero`` is refused, never read)."""
    if isinstance(source, str | Path):
        p = Path(source)
        if p.is_dir():
            found = sorted(p.glob("*.mcap"))
            if not found:
                raise UserError(f"no .mcap files in {p}")
            return [files.check(f, "recording") for f in found]
        return [files.check(p, "recording")]
    return [files.check(s, "recording") for s in source]


class Reader:
    """Messages of one MCAP file or a rotated set, as (topic, t_s, dict), in log-time order.

    ``log_time_order=False`` gives them in the order they were written (the
    order the application recorded them). Files cut short by a crash are read
    up to the damage and listed in ``recovered``; damaged chunks (CRC) and records are left out
    and counted in ``damage``, the rest is read; messages that are not JSON objects (or are
    nested too deep, or carry a time that is no finite number) are skipped and counted in
    ``skipped`` (the reasons in ``skipped_why``).
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
        self.skipped_why: list[str] = []
        """Why the first (up to 20) skipped messages were skipped."""
        self.damage = Damage()
        """What could not be read: chunks failing their CRC, broken records (``scan``)."""

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
            with files.opened(path, "recording") as f:
                summary = _summary(f)
            if summary is not None:
                for ch in summary.channels.values():
                    sch = summary.schemas.get(ch.schema_id)
                    out.setdefault(ch.topic, sch.name if sch else "")
                continue
            schemas: dict[int, str] = {}
            for record in scan_records(path, Damage()):  # chunks decompressed with a bound
                if isinstance(record, Schema):
                    schemas[record.id] = record.name
                elif isinstance(record, Channel):
                    out.setdefault(record.topic, schemas.get(record.schema_id, ""))
        return out

    def _iter_file(self, path: Path) -> Iterator[tuple[int, RecordedMessage]]:
        """Chunk by chunk with CRCs checked (``scan``): damage is counted in ``damage`` and
        the rest read; the summary, when readable, only names the channels."""
        channels: dict[int, str] = {}
        with files.opened(path, "recording") as f:
            summary = _summary(f)
        if summary is not None:
            channels.update({cid: ch.topic for cid, ch in summary.channels.items()})
        truncated = self.damage.truncated_files
        found: list[tuple[int, RecordedMessage]] = []
        for record in scan_records(path, self.damage):
            if isinstance(record, Channel):
                channels[record.id] = record.topic
            elif isinstance(record, Message):
                topic = channels.get(record.channel_id)
                if topic is None or (self.topics is not None and topic not in self.topics):
                    continue
                rec = self._decode(topic, record)
                if rec is None:
                    continue
                if self.log_time_order:
                    found.append((record.log_time, rec))
                else:
                    yield record.log_time, rec
        if self.damage.truncated_files > truncated:
            self.recovered.append(path)
            log.info(
                "recording %s is cut short: read up to the damage (`guidance recording repair`"
                " writes a complete copy other MCAP tools open)",
                path,
            )
        if self.log_time_order:
            found.sort(key=lambda pair: pair[0])
            yield from found

    def _decode(self, topic: str, message: Message) -> RecordedMessage | None:
        """The message as a JSON object with a finite time, or None (counted in ``skipped``,
        the first reasons in ``skipped_why``): not JSON, nested too deep for the parser
        (``RecursionError``), not an object, or a ``t_s`` that is no finite number (10^400)."""
        why = ""
        try:
            data = files.parse_json(message.data)
        except ValueError as exc:
            data, why = None, str(exc)[:80]
        if data is not None and not isinstance(data, dict):
            why = f"a JSON {type(data).__name__}, not an object"
        t_s: float = message.log_time / 1e9
        if isinstance(data, dict):
            raw = data.get("t_s")
            if isinstance(raw, int | float) and not isinstance(raw, bool):
                try:
                    t_s = float(raw)
                except OverflowError:
                    t_s = math.inf
                if not math.isfinite(t_s):
                    why = "t_s is not a finite number"
        if why:
            self.skipped += 1
            if len(self.skipped_why) < 20:
                self.skipped_why.append(
                    f"{topic} at log time {message.log_time / 1e9:.3f} s: {why}"
                )
            return None
        assert isinstance(data, dict)
        return RecordedMessage(topic, t_s, data)


def _summary(f: Any) -> Any:
    """The file's summary section, or None when it has none or is cut short."""
    try:
        return make_reader(f).get_summary()
    except Exception as exc:  # a cut-short file ends in arbitrary bytes: any parse error
        log.debug("recording: no readable summary: %s", exc)
        return None
