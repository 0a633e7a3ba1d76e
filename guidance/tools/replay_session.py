"""What ``guidance replay`` reads from a recording, checked at the boundary (issue 14).

A recording is a file from outside: a valid MCAP may carry a ``/session`` record of another
schema, NaN or 1e308 in the pipeline settings, text where numbers belong, a million landmarks.
``pipeline_config_from_session`` rebuilds the ``PipelineConfig`` only from values that are the
right type, finite and within their rule (written once, on the core's config dataclasses, and
read by the config file too), and otherwise raises one ``UserError`` line naming the setting.
``recording_sessions`` splits a folder into the recorded sessions
(``<prefix>-<YYYYmmdd-HHMMSS>-<NNNN>.mcap``, one per start of the recorder), so each is replayed
on its own instead of merging different drives.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

from guidance.config_tables import from_table
from guidance.errors import UserError

if TYPE_CHECKING:
    from guidance.core.pipeline import PipelineConfig

_SESSION_FILE = re.compile(r"^(?P<key>.+-\d{8}-\d{6})-\d{4}\.mcap$")
PREFIX = "the recording's /session record: "


def pipeline_config_from_session(session: Mapping[str, Any]) -> PipelineConfig:
    """Rebuild the pipeline configuration from a recording's ``/session`` record (checked):
    ``PipelineConfig.describe()`` read back by the config loader with the rules written on
    the core's config dataclasses (the config file's own), so the replay is the car that was
    recorded, ``[health]`` and the turn detector included. A record from before a setting
    existed keeps that setting's default."""
    from guidance.core.pipeline_config import PipelineConfig

    d = session.get("pipeline") if isinstance(session, Mapping) else None
    if not isinstance(d, Mapping):
        raise UserError("the recording's /session record has no pipeline configuration")
    try:
        return from_table(PipelineConfig, d, "pipeline", record=True)
    except UserError as exc:
        raise UserError(f"{PREFIX}{str(exc)[:300]}") from None


def recording_sessions(path: Path) -> list[list[Path]]:
    """The recorded sessions of a folder (rotated files of one start together, in order); a
    file is one session. Files not named by the recorder are each a session of their own."""
    if not path.is_dir():
        return [[path]]
    groups: dict[str, list[Path]] = {}
    for f in sorted(path.glob("*.mcap")):
        m = _SESSION_FILE.match(f.name)
        groups.setdefault(m.group("key") if m else f.name, []).append(f)
    if not groups:
        raise UserError(f"no .mcap files in {path}")
    return list(groups.values())


OUTPUT_FIELDS = {
    "/decision": ("t_s", "exit_index", "intersection_id", "exit_heading_rad"),
    "/state": ("t_s", "x_m", "y_m", "heading_rad"),
}


def well_formed_output(topic: str, data: Mapping[str, Any]) -> bool:
    """A recorded decision or state with the fields the comparison reads, each a finite
    number (else it is counted as damaged, never a crash)."""
    for key in OUTPUT_FIELDS[topic]:
        v = data.get(key)
        if isinstance(v, bool) or not isinstance(v, int | float):
            return False
        try:
            if not math.isfinite(v):
                return False
        except OverflowError:
            return False
    return True
