"""Issue 40, defect 8: an lz4 chunk is decompressed with a bound. An 8 MB recording whose chunk
inflated to 1.5 GB took ``repair``, ``replay`` and ``check-guidance`` to 3.3 GB each (zstd was
bounded already); now a chunk inflates to at most the size it claims, and a claim over
``MAX_UNCOMPRESSED`` is refused before any decompression. Each is measured in a child process
whose peak memory is measured."""

from __future__ import annotations

import subprocess
import sys
import textwrap
import zlib
from pathlib import Path

import lz4.frame  # type: ignore[import-untyped]
import pytest
from mcap.data_stream import RecordBuilder
from mcap.records import Channel, Chunk, Header, Message, Schema

from guidance.recording.scan import MAGIC

REPO = Path(__file__).resolve().parents[3]
BOMB_BYTES = 1 << 30
"""What the bomb chunk inflates to: 1 GiB of zeros (about 4 MiB of lz4)."""
PEAK_LIMIT_BYTES = 400 << 20
"""The child's peak resident memory: the reader's own needs fit (about 60 MiB), the bomb not.
(An address-space limit would not do: the old reader caught the MemoryError it caused. The
peak is the child's ``VmHWM``, not ``ru_maxrss``, which keeps the forking pytest's across
``exec``.)"""


def _lz4_zeros(n: int) -> bytes:
    """``n`` zero bytes as one lz4 frame, compressed a MiB at a time (never held whole)."""
    c = lz4.frame.LZ4FrameCompressor()
    out = [c.begin()]
    block = bytes(1 << 20)
    for _ in range(n >> 20):
        out.append(c.compress(block))
    out.append(c.flush())
    return b"".join(out)


def _good_chunk() -> bytes:
    inner = RecordBuilder()
    Schema(id=1, name="s", encoding="jsonschema", data=b"{}").write(inner)
    Channel(id=1, topic="/odometry", message_encoding="json", schema_id=1, metadata={}).write(inner)
    for i in range(3):
        Message(channel_id=1, sequence=i, log_time=i, publish_time=i, data=b'{"t_s": 1.0}').write(
            inner
        )
    data = inner.end()
    out = RecordBuilder()
    Chunk("", data, 2, 0, zlib.crc32(data), len(data)).write(out)
    return out.end()


def _recording(path: Path, claimed: int) -> None:
    out = RecordBuilder()
    Header(profile="", library="test").write(out)
    Chunk("lz4", _lz4_zeros(BOMB_BYTES), 0, 0, 0, claimed).write(out)
    path.write_bytes(MAGIC + out.end() + _good_chunk())


@pytest.mark.parametrize("claimed", [1024, 1_500_000_000], ids=["claims 1 KiB", "claims 1.5 GB"])
def test_an_lz4_bomb_is_a_damaged_chunk_in_bounded_memory(tmp_path: Path, claimed: int) -> None:
    path = tmp_path / "bomb.mcap"
    _recording(path, claimed)
    assert path.stat().st_size < 8 << 20
    code = textwrap.dedent(
        f"""
        from pathlib import Path
        from mcap.records import Message
        from guidance.recording.scan import Damage, scan_records
        d = Damage()
        n = sum(isinstance(r, Message) for r in scan_records(Path({str(path)!r}), d))
        peak = [ln for ln in open("/proc/self/status") if ln.startswith("VmHWM:")][0]
        print(n, d.bad_chunks, int(peak.split()[1]) * 1024)
        """
    )
    res = subprocess.run(
        [sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=120
    )
    assert res.returncode == 0, res.stderr[-2000:]
    messages, bad, peak = (int(v) for v in res.stdout.split())
    assert bad == 1 and messages == 3  # the bomb left out and counted, the rest read
    assert peak < PEAK_LIMIT_BYTES, f"peak resident memory {peak >> 20} MiB"
