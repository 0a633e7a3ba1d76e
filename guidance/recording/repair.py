"""``guidance recording repair IN OUT``: a complete MCAP file from a damaged or cut-short one.

A recorder killed by SIGKILL (or a power cut) leaves a file without its summary and footer,
often ending in the middle of a chunk; ``guidance replay`` reads it (``scan``), but the
standard ``mcap`` reader and other MCAP tools stop at the cut (``RecordLengthLimitExceeded``).
``repair`` reads the file as the replay does (every chunk's CRC checked, damage counted) and
writes what is complete (schemas, channels, metadata, every message of an intact chunk) into a
new, finished file that any MCAP reader opens, then checks it with the standard reader. The
original is never changed; OUT is written to a temporary file beside it and renamed.
"""

from __future__ import annotations

import contextlib
import os
from dataclasses import dataclass
from pathlib import Path

from mcap.reader import make_reader
from mcap.records import Channel, Message, Metadata, Schema
from mcap.writer import CompressionType, Writer

from guidance import files
from guidance.errors import UserError
from guidance.recording.scan import Damage, scan_records

LIBRARY = "guidance recording repair"


@dataclass(frozen=True, slots=True)
class Repaired:
    """What ``repair`` wrote and what it could not save."""

    messages: int
    channels: int
    orphans: int
    """Messages whose channel record was lost with the damage (left out)."""
    damage: Damage


def repair(src: Path, dest: Path) -> Repaired:
    """Write the complete records of ``src`` into ``dest`` (see the module docstring)."""
    files.check(src, "recording")  # a regular file, or one line why not
    if dest.exists():
        raise UserError(f"{dest} exists: give a new file")
    if dest.parent.resolve() == src.parent.resolve() and dest.name == src.name:
        raise UserError("IN and OUT must differ: the original is never changed")
    damage = Damage()
    schemas: dict[int, int] = {0: 0}
    channels: dict[int, int] = {}
    messages = orphans = 0
    tmp = dest.with_name(f".{dest.name}.{os.getpid()}.tmp")
    try:
        with tmp.open("xb") as f:
            w = Writer(f, compression=CompressionType.ZSTD)
            w.start(profile="", library=LIBRARY)
            for rec in scan_records(src, damage):
                if isinstance(rec, Schema):
                    if rec.id not in schemas:
                        schemas[rec.id] = w.register_schema(rec.name, rec.encoding, rec.data)
                elif isinstance(rec, Channel):
                    if rec.id not in channels:
                        channels[rec.id] = w.register_channel(
                            rec.topic, rec.message_encoding, schemas.get(rec.schema_id, 0),
                            rec.metadata,
                        )  # fmt: skip
                elif isinstance(rec, Metadata):
                    w.add_metadata(rec.name, rec.metadata)
                elif isinstance(rec, Message):
                    cid = channels.get(rec.channel_id)
                    if cid is None:
                        orphans += 1
                        continue
                    w.add_message(cid, rec.log_time, rec.data, rec.publish_time, rec.sequence)
                    messages += 1
            w.finish()
            f.flush()
            os.fsync(f.fileno())
        if messages == 0:
            raise UserError(f"{src}: no complete message to recover")
        # what other tools will do: the standard reader, to the end
        with files.opened(tmp, "recording") as f:
            n = sum(1 for _ in make_reader(f).iter_messages())
        if n != messages:
            raise UserError(f"{dest}: the standard reader reads {n} of {messages} messages")
        os.replace(tmp, dest)
    except OSError as exc:
        raise UserError(f"{dest}: {exc.strerror or exc}") from None
    finally:
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()
    return Repaired(messages, len(channels), orphans, damage)


def damage_text(d: Damage) -> str:
    """What a repair or a replay could not read, in words ("" when nothing)."""
    parts = []
    if d.truncated_files:
        parts.append("cut short (the recorder was stopped before it finished the file)")
    if d.bad_chunks:
        parts.append(f"{d.bad_chunks} chunks failed their CRC or decoding")
    if d.bad_records:
        parts.append(f"{d.bad_records} broken records")
    if d.skipped_bytes:
        parts.append(f"{d.skipped_bytes} bytes skipped")
    return ", ".join(parts)


def repair_hint(path: Path | str) -> str:
    """The sentence that goes where a damaged recording is reported."""
    return (
        f"other MCAP tools need a complete file: `guidance recording repair {path} "
        f"REPAIRED.mcap` writes one"
    )
