"""The recorder's health: a ``guidance.core.messages.Health`` with the recorder's statuses,
counters and current file (docs/reliability.md)."""

from __future__ import annotations

from collections.abc import Mapping

from guidance.core.messages import Health

# -- health ----------------------------------------------------------------------------------------
DISK_FULL_WARNING = "Recording stopped. The disk is full."
RECORDING_FAILED_WARNING = "Recording stopped after a write error."


def recorder_health(
    *,
    recording: bool,
    disk_full: bool,
    failed: bool,
    counters: Mapping[str, int],
    current_file: str,
    detail: str,
) -> Health:
    """``status`` "recording", "stopped", "disk_full" or "failed" (stopped by an I/O error, and
    stays stopped until restarted); ``alive`` while it accepts and writes messages, ``valid``
    unless it failed. ``counters``: written, dropped (refused: queue full or stopped), errors,
    files_deleted, bytes_written; ``info``: current_file."""
    if disk_full:
        status, warning = "disk_full", DISK_FULL_WARNING
    elif failed:
        status, warning = "failed", RECORDING_FAILED_WARNING
    else:
        status, warning = ("recording" if recording else "stopped"), ""
    return Health(
        "recorder",
        status,
        alive=recording,
        valid=not failed,
        detail=detail,
        warning=warning,
        counters=dict(counters),
        info={"current_file": current_file},
    )
