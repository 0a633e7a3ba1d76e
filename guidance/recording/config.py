"""The ``[recording]`` table."""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mcap.writer import CompressionType

from guidance.config_tables import from_table, rule
from guidance.core.geo import Origin
from guidance.errors import UserError

# -- configuration --------------------------------------------------------------------------------
MAX_CHUNK_SIZE_BYTES = 16 << 20
"""The largest chunk the recorder may write: the readers refuse a chunk that inflates past
64 MiB (``guidance.recording.scan.MAX_UNCOMPRESSED``)."""


@dataclass(frozen=True, slots=True)
class RecordingConfig:
    """The ``[recording]`` table of the car's TOML config (docs/telemetry.md)."""

    enabled: bool = True
    directory: str = field(default="recordings", metadata=rule(path=True))
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
    truth_interval_s: float = 0.1
    """At most one true pose (``record_truth``, simulated drives) this often."""
    compression: str = field(default="zstd", metadata=rule(choices=("zstd", "lz4", "none")))
    """"zstd", "lz4" or "none" (chunk compression; Foxglove reads all three)."""
    origin_lat_lon_deg: tuple[float, float] | None = field(default=None, metadata=rule(read=False))
    """WGS-84 origin of the local frame (not a ``[recording]`` key: the app's config sets it
    from ``[start]``, the simulator from its city); the Foxglove topics need it for the map."""

    def __post_init__(self) -> None:
        if self.origin_lat_lon_deg is not None:  # a place on Earth
            Origin.checked(self.origin_lat_lon_deg)
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
        if self.chunk_size_bytes > MAX_CHUNK_SIZE_BYTES:  # readers bound a chunk (recording.scan)
            raise UserError(f"[recording] chunk_size_bytes must be <= {MAX_CHUNK_SIZE_BYTES}")
        if self.max_total_size_bytes < self.max_file_size_bytes:
            raise UserError("[recording] max_total_size_bytes must be >= max_file_size_bytes")

    @classmethod
    def from_mapping(
        cls, table: Mapping[str, Any], base_dir: Path | None = None
    ) -> RecordingConfig:
        """Build from a parsed ``[recording]`` TOML table (``guidance.config_tables``);
        a relative ``directory`` is taken from ``base_dir`` (the TOML file's folder)."""
        return from_table(cls, table, "recording", base_dir)


_COMPRESSION = {
    "zstd": CompressionType.ZSTD,
    "lz4": CompressionType.LZ4,
    "none": CompressionType.NONE,
}
