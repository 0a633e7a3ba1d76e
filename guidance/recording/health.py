"""The recorder's health record."""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any

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
