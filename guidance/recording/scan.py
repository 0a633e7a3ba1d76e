"""Reading an MCAP file record by record, chunk by chunk, past damage (issue 14).

``scan_messages`` walks the data section itself instead of trusting the summary: every chunk is
decompressed and its CRC checked (the recorder writes one), a chunk that fails is left out and
counted, and where the record framing itself is broken (a flipped length or opcode) the scan
searches forward for the next chunk whose CRC checks and carries on from there. A file cut short
ends quietly. What was lost is counted in ``Damage``; everything else is returned in the order
it was written.
"""

from __future__ import annotations

import mmap
import struct
import zlib
from collections.abc import Iterator
from dataclasses import dataclass, field
from io import BytesIO
from pathlib import Path

from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import Channel, Chunk, Message, Metadata, Schema

from guidance import files

MAGIC = b"\x89MCAP0\r\n"
_U64 = struct.Struct("<Q")
_KNOWN = frozenset(int(op) for op in Opcode)
MAX_UNCOMPRESSED = 64 << 20
"""A chunk claiming more than this when decompressed is damaged: the recorder closes a chunk
at ``[recording] chunk_size_bytes`` (64 KiB by default, at most 16 MiB) plus one message (a
thumbnail is a few KiB). Every chunk is decompressed to at most the size it claims (zstd and
lz4 alike), so a small file cannot inflate to gigabytes in memory (issue 40, defect 8)."""


@dataclass
class Damage:
    """What a scan could not read (summed over the files of a recording)."""

    bad_chunks: int = 0
    """Chunks left out: CRC mismatch, undecodable compression or records."""
    bad_records: int = 0
    """Top-level records that did not parse, and resynchronisations after broken framing."""
    skipped_bytes: int = 0
    """Bytes jumped over to find the next good chunk."""
    truncated_files: int = 0
    """Files that end before their footer (cut short)."""
    notes: list[str] = field(default_factory=list)

    @property
    def any(self) -> bool:
        return bool(self.bad_chunks or self.bad_records or self.skipped_bytes)

    def note(self, text: str) -> None:
        if len(self.notes) < 20:
            self.notes.append(text)


def _chunk_at(data: bytes | mmap.mmap, pos: int) -> tuple[Chunk, bytes, int] | None:
    """The chunk record at ``pos``, its checked uncompressed data and the end offset; None when
    there is no intact chunk there."""
    if pos + 9 > len(data) or data[pos] != Opcode.CHUNK:
        return None
    (length,) = _U64.unpack_from(data, pos + 1)
    end = pos + 9 + length
    if length < 32 or end > len(data):
        return None
    try:
        chunk = Chunk.read(ReadDataStream(BytesIO(data[pos + 9 : end])))
        if chunk.uncompressed_size > MAX_UNCOMPRESSED:
            return None
        if chunk.compression == "zstd":
            import zstandard

            raw = zstandard.ZstdDecompressor().decompress(
                chunk.data, max_output_size=chunk.uncompressed_size
            )
        elif chunk.compression == "lz4":
            import lz4.frame  # type: ignore[import-untyped]

            lz = lz4.frame.LZ4FrameDecompressor()  # bounded: never past the claimed size
            raw = lz.decompress(chunk.data, max_length=chunk.uncompressed_size)
            if not lz.needs_input:  # more to come than the chunk claims: a bomb or damage
                return None
        elif chunk.compression == "":
            raw = chunk.data
        else:
            return None
    except Exception:  # any parse or decompression error: not an intact chunk
        return None
    if len(raw) != chunk.uncompressed_size:
        return None
    if chunk.uncompressed_crc != 0 and zlib.crc32(raw) != chunk.uncompressed_crc:
        return None
    return chunk, raw, end


def _inner_records(raw: bytes) -> list[Channel | Schema | Message]:
    """The records of a chunk (its CRC matched); raises on a malformed one."""
    stream = ReadDataStream(BytesIO(raw))
    out: list[Channel | Schema | Message] = []
    while stream.count < len(raw):
        opcode = stream.read1()
        length = stream.read8()
        if length > len(raw) - stream.count:
            raise ValueError("record longer than its chunk")
        start = stream.count
        if opcode == Opcode.CHANNEL:
            out.append(Channel.read(stream))
        elif opcode == Opcode.SCHEMA:
            out.append(Schema.read(stream))
        elif opcode == Opcode.MESSAGE:
            out.append(Message.read(stream, length))
        else:
            stream.read(length)
        if stream.count - start != length:
            raise ValueError("record length disagrees with its content")
    return out


def _resync(data: bytes | mmap.mmap, pos: int) -> tuple[Chunk, bytes, int, int] | None:
    """The next intact chunk after ``pos``: (chunk, data, end, its start)."""
    find = data.find
    q = find(bytes([Opcode.CHUNK]), pos + 1)
    while q != -1:
        found = _chunk_at(data, q)
        if found is not None:
            return (*found, q)
        q = find(bytes([Opcode.CHUNK]), q + 1)
    return None


def _top_record(opcode: int, body: bytes) -> Channel | Schema | Message | Metadata | None:
    stream = ReadDataStream(BytesIO(body))
    if opcode == Opcode.METADATA:
        return Metadata.read(stream)
    if opcode == Opcode.CHANNEL:
        return Channel.read(stream)
    if opcode == Opcode.SCHEMA:
        return Schema.read(stream)
    if opcode == Opcode.MESSAGE:
        return Message.read(stream, len(body))
    return None


def scan_records(path: Path, damage: Damage) -> Iterator[Channel | Schema | Message | Metadata]:
    """Channels, schemas, messages and metadata of one file in written order, past damage
    (counted)."""
    with files.opened(path, "recording") as f:
        try:
            data: bytes | mmap.mmap = mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ)
        except ValueError:  # an empty file cannot be mapped
            data = b""
        try:
            yield from _scan(data, path, damage)
        finally:
            if isinstance(data, mmap.mmap):
                data.close()


def _scan(
    data: bytes | mmap.mmap, path: Path, damage: Damage
) -> Iterator[Channel | Schema | Message | Metadata]:
    n = len(data)
    pos = len(MAGIC)
    if data[: len(MAGIC)] != MAGIC:
        damage.bad_records += 1
        damage.note(f"{path.name}: no MCAP magic")
    while True:
        if pos + 9 > n:
            damage.truncated_files += 1
            return
        opcode = data[pos]
        (length,) = _U64.unpack_from(data, pos + 1)
        end = pos + 9 + length
        if opcode in (Opcode.DATA_END, Opcode.FOOTER) and end <= n:
            return  # the summary holds nothing the scan needs
        if opcode == Opcode.CHUNK:
            found = _chunk_at(data, pos)
            if found is not None:
                _chunk, raw, end = found
                try:
                    records = _inner_records(raw)
                except Exception:
                    damage.bad_chunks += 1
                    damage.note(f"{path.name}: malformed records in the chunk at {pos}")
                else:
                    yield from records
                pos = end
                continue
            if end <= n:  # the framing holds: only this chunk is bad
                if not _framing_ok(data, end):
                    damage.bad_chunks += 1
                    damage.note(f"{path.name}: damaged chunk at byte {pos}")
                    pos = _skip_to_next(data, pos, damage, path)
                    if pos < 0:
                        return
                    continue
                damage.bad_chunks += 1
                damage.note(f"{path.name}: chunk at byte {pos} fails its CRC or decompression")
                pos = end
                continue
        elif opcode in _KNOWN and end <= n and _framing_ok(data, end):
            try:
                rec = _top_record(opcode, bytes(data[pos + 9 : end]))
            except Exception:
                damage.bad_records += 1
                damage.note(f"{path.name}: damaged record at byte {pos}")
            else:
                if rec is not None:
                    yield rec
            pos = end
            continue
        if end > n and _resync(data, pos) is None:  # cut short: the rest is gone
            damage.truncated_files += 1
            return
        damage.bad_records += 1
        damage.note(f"{path.name}: broken record framing at byte {pos}")
        pos = _skip_to_next(data, pos, damage, path)
        if pos < 0:
            return


def _framing_ok(data: bytes | mmap.mmap, pos: int) -> bool:
    """Whether a plausible record (or the end of the file) starts at ``pos``."""
    if pos == len(data):
        return True
    if pos + 9 > len(data):
        return False
    (length,) = _U64.unpack_from(data, pos + 1)
    return data[pos] in _KNOWN and pos + 9 + length <= len(data)


def _skip_to_next(data: bytes | mmap.mmap, pos: int, damage: Damage, path: Path) -> int:
    """Offset of the next intact chunk after ``pos`` (the bytes between counted), or -1."""
    found = _resync(data, pos)
    if found is None:
        damage.skipped_bytes += len(data) - pos
        damage.note(f"{path.name}: nothing readable after byte {pos}")
        return -1
    start = found[3]
    damage.skipped_bytes += start - pos
    return start
