"""The recorder's health: a ``guidance.core.messages.Health`` with the recorder's statuses,
counters and current file (docs/reliability.md)."""

from __future__ import annotations

from collections.abc import Mapping

from guidance.core.messages import Health, Say, Speech
from guidance.core.speech import words

# -- health ----------------------------------------------------------------------------------------


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
        status = "disk_full"
    elif failed:
        status = "failed"
    else:
        status = "recording" if recording else "stopped"
    bad = disk_full or failed
    warning = words(Say(Speech.COMPONENT, input="recorder", status=status)) if bad else ""
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
