"""Recording topics and their channel schemas."""

from __future__ import annotations

import errno
from collections.abc import Mapping, Sequence
from typing import Any

from guidance.core import codec
from guidance.outputs.kinds import OUTPUTS
from guidance.recording.foxglove import SCHEMA_OF_TOPIC as FOXGLOVE_TOPICS
from guidance.recording.foxglove_schemas import json_schema

LIBRARY = "guidance-recorder"
_DISK_FULL_ERRNOS = {errno.ENOSPC, errno.EDQUOT, errno.EFBIG}


# -- channel schemas ------------------------------------------------------------------------------
def _schema(title: str, props: Mapping[str, Any], required: Sequence[str]) -> dict[str, Any]:
    return {
        "$schema": "http://json-schema.org/draft-07/schema#",
        "title": title,
        "type": "object",
        "properties": dict(props),
        "required": list(required),
    }


_T = {"type": "number", "description": "car monotonic clock (or simulated time), s"}
INPUT_SCHEMAS: dict[str, dict[str, Any]] = {
    "can": _schema(
        "guidance.can_frame",
        {
            "t_s": _T,
            "id": {"type": "integer", "description": "arbitration id"},
            "data_hex": {"type": "string"},
            "is_extended_id": {"type": "boolean"},
            "is_error_frame": {"type": "boolean"},
            "channel": {"type": "string"},
        },
        ["t_s", "id", "data_hex"],
    ),
    "nmea": _schema(
        "guidance.nmea_line",
        {"t_s": _T, "line": {"type": "string"}, "port": {"type": "string"}},
        ["t_s", "line"],
    ),
    "camera": _schema(
        "guidance.camera_frame",
        {
            "t_s": _T,
            "source": {"type": "string"},
            "width_px": {"type": ["integer", "null"]},
            "height_px": {"type": ["integer", "null"]},
            "file_ref": {"type": "string", "description": "path of the full frame, if saved"},
            "thumbnail": {"type": "boolean", "description": "a /camera/thumbnail went with it"},
        },
        ["t_s"],
    ),
}

TOPICS: dict[str, dict[str, Any]] = {
    "/can": INPUT_SCHEMAS["can"],
    "/nmea": INPUT_SCHEMAS["nmea"],
    "/camera": INPUT_SCHEMAS["camera"],
    "/truth": _schema(
        "guidance.truth",
        {
            "t_s": _T,
            "x_m": {"type": "number"},
            "y_m": {"type": "number"},
            "heading_rad": {"type": "number", "description": "CCW from east"},
            "heading_deg_true": {"type": ["number", "null"], "description": "CW from north"},
        },
        ["t_s", "x_m", "y_m", "heading_rad"],
    ),
    # the processed inputs replay feeds the pipeline: schemas from the message fields
    **{topic: codec.schema(topic) for topic in dict.fromkeys(codec.TOPICS.values())},
    # the outputs: one row of the output table each
    **{k.topic: k.schema for k in OUTPUTS},
    # the published Foxglove schemas (guidance.recording.foxglove): standard viewer panels
    **{topic: json_schema(name) for topic, name in FOXGLOVE_TOPICS.items()},
}
"""Topic -> JSON Schema (its ``title`` is the MCAP schema name); every topic has one."""
INPUT_TOPICS = ("/can", "/nmea", "/camera", "/scene")
OUTPUT_TOPICS = tuple(k.topic for k in OUTPUTS)
