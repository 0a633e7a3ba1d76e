"""The JSON Schemas of the output messages (docs/telemetry.md; the MCAP channel schemas, the
monitor's check): one per kind, generated from the message's shape
(``guidance.outputs.shapes``, what the encoders return) by the generator the inputs' schemas
use (``guidance.core.codec.json_schema``)."""

from __future__ import annotations

from typing import Any

from guidance.core.codec import json_schema
from guidance.outputs.shapes import MESSAGE_SHAPES, POINT_RULES


def message_schema(kind: str, **extra: Any) -> dict[str, Any]:
    """The schema of the ``guidance.<kind>`` message: its shape's properties and required
    keys (the envelope's), and ``extra`` keywords."""
    body = json_schema(MESSAGE_SHAPES[kind])
    return {
        "$schema": "http://json-schema.org/draft-07/schema#",
        "title": f"guidance.{kind}",
        "type": "object",
        "properties": body["properties"],
        "required": body["required"],
        **extra,
    }


SCHEMAS: dict[str, dict[str, Any]] = {
    kind: message_schema(kind, **({"allOf": POINT_RULES} if kind == "state" else {}))
    for kind in MESSAGE_SHAPES
}
"""The car's position is a point too: coordinates in pairs (``POINT_RULES``)."""
