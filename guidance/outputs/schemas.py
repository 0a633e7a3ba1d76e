"""The JSON Schemas of the output messages (docs/telemetry.md; the MCAP channel schemas, the
monitor's check): one per kind, listed with its encoder in ``guidance.outputs.kinds``."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

# -- JSON Schemas (docs/telemetry.md; MCAP channel schemas) ------------------------------------
_NUM = {"type": ["number", "null"]}
_ENVELOPE_PROPS: dict[str, Any] = {
    "schema": {"type": "string", "description": "name/version, e.g. guidance.state/1"},
    "vehicle_id": {"type": "string"},
    "seq": {"type": "integer", "description": "per vehicle and kind; gaps are drops"},
    "t_s": {"type": ["number", "null"], "description": "car monotonic clock, s"},
    "wall_time_unix_s": {"type": ["number", "null"], "description": "for logs only, s"},
}
_TARGET: dict[str, Any] = {
    "type": ["object", "null"],
    "properties": {
        "x_m": _NUM,
        "y_m": _NUM,
        "kind": {"type": "string", "enum": ["goal", "landmark"]},
        "id": {"type": ["integer", "null"]},
    },
}


def _together(a: str, b: str) -> list[dict[str, Any]]:
    """Rules that make ``a`` a number only with ``b`` a number, and ``b`` only with ``a``:
    a point is drawn from both or neither (``lat_deg`` without ``lon_deg``, or with
    ``lon_deg: null``, cannot be drawn; the web page and the monitor's check agree on it)."""

    def number(k: str) -> dict[str, Any]:
        return {"required": [k], "properties": {k: {"type": "number"}}}

    return [{"if": number(a), "then": number(b)}, {"if": number(b), "then": number(a)}]


_POINT_RULES = [*_together("x_m", "y_m"), *_together("lat_deg", "lon_deg")]
"""Every point of a state (the car, its target, its goal): coordinates in pairs."""


def _obj(title: str, props: Mapping[str, Any]) -> dict[str, Any]:
    return {
        "$schema": "http://json-schema.org/draft-07/schema#",
        "title": title,
        "type": "object",
        "properties": {**_ENVELOPE_PROPS, **props},
        "required": ["schema", "vehicle_id", "seq", "t_s"],
    }


_HEALTH: dict[str, Any] = {
    "type": "object",
    "description": "guidance.core.messages.Health.as_dict(): one record for inputs and components",
    "properties": {
        "name": {"type": "string"},
        "status": {"type": "string"},
        "alive": {"type": "boolean"},
        "valid": {"type": "boolean"},
        "ok": {"type": "boolean"},
        "age_s": _NUM,
        "rate_hz": _NUM,
        "expected_rate_hz": _NUM,
        "detail": {"type": "string"},
        "warning": {"type": "string"},
        "counters": {"type": "object", "additionalProperties": {"type": "integer"}},
        "info": {"type": "object", "additionalProperties": {"type": "string"}},
    },
}
"""The schema of one ``Health.as_dict()``."""
_LAT = {"type": ["number", "null"], "description": "WGS-84 latitude, degrees (null: no origin)"}
_LON = {"type": ["number", "null"], "description": "WGS-84 longitude, degrees (null: no origin)"}
_GEO_TARGET: dict[str, Any] = {
    **_TARGET,
    "properties": {**dict(_TARGET["properties"]), "lat_deg": _LAT, "lon_deg": _LON},
    "allOf": _POINT_RULES,
}

SCHEMAS: dict[str, dict[str, Any]] = {
    "state": _obj(
        "guidance.state",
        {
            "x_m": _NUM,
            "y_m": _NUM,
            "lat_deg": _LAT,
            "lon_deg": _LON,
            "origin": {
                "type": ["object", "null"],
                "description": "the local frame's origin (x east, y north metres), WGS-84",
                "properties": {
                    "lat_deg": {"type": "number", "minimum": -90, "maximum": 90},
                    "lon_deg": {"type": "number", "minimum": -180, "maximum": 180},
                },
                "required": ["lat_deg", "lon_deg"],
            },
            "heading_rad": _NUM,
            "heading_deg": _NUM,
            "heading_deg_true": {
                "type": ["number", "null"],
                "description": "compass heading: degrees clockwise from true north, [0, 360)",
            },
            "covariance": {
                "type": "array",
                "description": "3x3 over (x_m, y_m, heading_rad)",
                "items": {"type": "array", "items": _NUM},
            },
            "ellipse": {
                "type": "object",
                "properties": {
                    "semi_major_m": _NUM,
                    "semi_minor_m": _NUM,
                    "orientation_rad": _NUM,
                    "major_axis_m": _NUM,
                },
            },
            "speed_mps": _NUM,
            "target": _GEO_TARGET,
            "goal": {
                "type": ["object", "null"],
                "properties": {"x_m": _NUM, "y_m": _NUM, "lat_deg": _LAT, "lon_deg": _LON},
                "allOf": _POINT_RULES,
            },
            "method": {"type": ["string", "null"]},
            "mode": {"type": ["string", "null"]},
            "chance": {
                "type": ["number", "null"],
                "minimum": 0,
                "maximum": 1,
                "description": "chance of reaching the goal from here (the study engine's "
                "table, guidance.core.plan.chance); null: not computed",
            },
            "lost": {"type": "boolean"},
            "healthy": {"type": "boolean"},
        },
    ),
    "decision": _obj(
        "guidance.decision",
        {
            "exit_index": {"type": "integer"},
            "exit_heading_rad": _NUM,
            "turn_rad": _NUM,
            "turn_deg": _NUM,
            "options": {
                "type": "array",
                "items": {
                    "type": "object",
                    "properties": {
                        "index": {"type": "integer"},
                        "heading_rad": _NUM,
                        "turn_rad": _NUM,
                        "angle_cost_rad": _NUM,
                        "penalty_rad": _NUM,
                        "cost_rad": _NUM,
                    },
                },
            },
            "target": _TARGET,
            "intersection_id": {"type": "integer"},
            "revisit": {"type": "boolean"},
            "mode": {"type": "string"},
            "reason": {"type": "string"},
        },
    ),
    "prompt": _obj(
        "guidance.prompt",
        {"text": {"type": "string"}, "kind": {"type": "string"}, "priority": {"type": "integer"}},
    ),
    "landmark": _obj(
        "guidance.landmark",
        {
            "gated": {"type": ["integer", "null"]},
            "matches": {
                "type": "array",
                "items": {
                    "type": "object",
                    "properties": {
                        "landmark_id": {"type": "integer"},
                        "x_m": _NUM,
                        "y_m": _NUM,
                        "sigma_m": _NUM,
                        "score": _NUM,
                        "name": {"type": "string"},
                    },
                },
            },
            "rejections": {
                "type": "array",
                "items": {
                    "type": "object",
                    "properties": {
                        "landmark_id": {"type": ["integer", "null"]},
                        "reason": {"type": "string"},
                        "detail": {"type": "string"},
                    },
                },
            },
        },
    ),
    "health": _obj(
        "guidance.health",
        {
            "ok": {"type": "boolean"},
            "inputs": {"type": "object", "additionalProperties": _HEALTH},
            "components": {
                "type": "object",
                "description": "by name: a Health record (telemetry, recorder, voice) or a "
                "free-form object (estimator, loop)",
            },
        },
    ),
}
SCHEMAS["state"]["allOf"] = _POINT_RULES  # the car's position: coordinates in pairs too


SCHEMAS.update(
    {
        "turn": _obj(
            "guidance.turn",
            {
                "heading_change_rad": {"type": ["number", "null"]},
                "heading_change_deg": {"type": ["number", "null"]},
                "source": {"type": "string"},
            },
        ),
        "exit": _obj(
            "guidance.exit",
            {
                "intersection_id": {"type": "integer"},
                "decision_t_s": {"type": ["number", "null"]},
                "advised_exit": {"type": "integer"},
                "taken_exit": {"type": "integer"},
                "followed": {"type": "boolean"},
                "source": {"type": "string"},
            },
        ),
    }
)
