"""Telemetry message encoders and their JSON Schemas (pure: no zenoh; shared with
``guidance.recording``).
"""

from __future__ import annotations

import functools
import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from guidance.core.messages import EstimateState, Health, LandmarkFix, Target
from guidance.core.model import heading_to_compass, wrap_angle
from guidance.errors import UserError
from guidance.telemetry.keys import schema_tag

if TYPE_CHECKING:
    from guidance.core.navigator import Decision


# -- message encoders (pure functions, shared with guidance.recording) --------------------------
def _num(value: float | None) -> float | None:
    """A JSON-safe float: non-finite values become null (strict JSON has no NaN)."""
    if value is None:
        return None
    f = float(value)
    return f if math.isfinite(f) else None


def _envelope(
    kind: str, vehicle_id: str, seq: int, t_s: float, wall_time_unix_s: float | None
) -> dict[str, Any]:
    return {
        "schema": schema_tag(kind),
        "vehicle_id": vehicle_id,
        "seq": seq,
        "t_s": _num(t_s),
        "wall_time_unix_s": _num(wall_time_unix_s),
    }


def _target_dict(target: Target | None) -> dict[str, Any] | None:
    if target is None:
        return None
    tid = target.id
    return {"x_m": _num(target.x_m), "y_m": _num(target.y_m), "kind": target.kind,
            "id": None if tid is None else int(tid)}  # fmt: skip


def _wrap_deg(angle_rad: float) -> float | None:
    """Degrees in (-180, 180]; None for a non-finite angle (the field, not the message, is lost)."""
    return _num(math.degrees(wrap_angle(angle_rad))) if math.isfinite(angle_rad) else None


Origin = tuple[float, float]
"""(latitude, longitude) in degrees (WGS-84) of the local frame's origin: x east, y north."""


def check_origin(origin: Origin | None) -> None:
    """An origin is a (latitude, longitude) in degrees within range, or None."""
    if origin is None:
        return
    lat, lon = origin
    if not (-90.0 <= lat <= 90.0 and -180.0 <= lon <= 180.0):
        raise UserError(f"origin {origin!r}: latitude must be in [-90, 90], longitude [-180, 180]")


def heading_deg_true(heading_rad: float | None) -> float | None:
    """Compass heading: degrees clockwise from true north in [0, 360), from ``heading_rad``
    (counter-clockwise from east, the local frame's convention)."""
    if heading_rad is None or not math.isfinite(heading_rad):
        return None
    return float(heading_to_compass(heading_rad, 0.0))  # true: no declination


def lat_lon_deg(x_m: float | None, y_m: float | None, origin: Origin | None) -> Origin | None:
    """WGS-84 latitude and longitude of a local point (east, north metres from ``origin``),
    through pymap3d's ENU conversion; None without an origin or a finite point."""
    if origin is None or x_m is None or y_m is None:
        return None
    if not (math.isfinite(x_m) and math.isfinite(y_m)):
        return None
    return _geodetic(float(x_m), float(y_m), float(origin[0]), float(origin[1]))


@functools.lru_cache(maxsize=256)
def _geodetic(x_m: float, y_m: float, lat0: float, lon0: float) -> Origin:
    """pymap3d's ENU -> WGS-84 (about 0.13 ms). Cached: the goal and the target stay the same
    from one state message to the next, and telemetry and the recorder each build the same one."""
    import pymap3d

    lat, lon, _h = pymap3d.enu2geodetic(x_m, y_m, 0.0, lat0, lon0, 0.0)
    return float(lat), float(lon)


def _with_geo(point: dict[str, Any] | None, origin: Origin | None) -> dict[str, Any] | None:
    """A point dict with ``lat_deg``/``lon_deg`` added (null without an origin)."""
    if point is None:
        return None
    geo = lat_lon_deg(point["x_m"], point["y_m"], origin)
    point["lat_deg"], point["lon_deg"] = geo if geo is not None else (None, None)
    return point


def state_message(
    state: EstimateState,
    *,
    vehicle_id: str,
    seq: int = 0,
    wall_time_unix_s: float | None = None,
    speed_mps: float | None = None,
    target: Target | None = None,
    goal: tuple[float, float] | None = None,
    method: str | None = None,
    mode: str | None = None,
    origin_lat_lon_deg: Origin | None = None,
) -> dict[str, Any]:
    """The ``guidance.state`` message (docs/telemetry.md).

    With ``origin_lat_lon_deg`` (the configured start), the position, target and goal also
    carry WGS-84 ``lat_deg``/``lon_deg``; without it those are null.
    """
    e = state.ellipse
    x, y = _num(state.x_m), _num(state.y_m)
    geo = lat_lon_deg(x, y, origin_lat_lon_deg)
    goal_d = None if goal is None else {"x_m": _num(goal[0]), "y_m": _num(goal[1])}
    msg = _envelope("state", vehicle_id, seq, state.t_s, wall_time_unix_s)
    msg.update(
        {
            "x_m": x,
            "y_m": y,
            "lat_deg": None if geo is None else geo[0],
            "lon_deg": None if geo is None else geo[1],
            "origin": None
            if origin_lat_lon_deg is None
            else {"lat_deg": origin_lat_lon_deg[0], "lon_deg": origin_lat_lon_deg[1]},
            "heading_rad": _num(state.heading_rad),
            "heading_deg": _wrap_deg(state.heading_rad),
            "heading_deg_true": heading_deg_true(_num(state.heading_rad)),
            "covariance": [[_num(v) for v in row] for row in state.covariance],
            "ellipse": {
                "semi_major_m": _num(e.semi_major_m),
                "semi_minor_m": _num(e.semi_minor_m),
                "orientation_rad": _num(e.orientation_rad),
                "major_axis_m": _num(e.major_axis_m),
            },
            "speed_mps": _num(speed_mps),
            "target": _with_geo(_target_dict(target), origin_lat_lon_deg),
            "goal": _with_geo(goal_d, origin_lat_lon_deg),
            "method": None if method is None else str(method),
            "mode": mode,
            "lost": bool(state.lost),
            "healthy": bool(state.healthy),
        }
    )
    return msg


def decision_message(
    decision: Decision,
    *,
    vehicle_id: str,
    seq: int = 0,
    wall_time_unix_s: float | None = None,
) -> dict[str, Any]:
    """The ``guidance.decision`` message from a ``guidance.navigator.Decision``."""
    d = decision
    msg = _envelope("decision", vehicle_id, seq, d.t_s, wall_time_unix_s)
    msg.update(
        {
            "exit_index": int(d.exit_index),
            "exit_heading_rad": _num(d.exit_heading_rad),
            "turn_rad": _num(d.turn_rad),
            "turn_deg": _wrap_deg(d.turn_rad),
            "options": [
                {
                    "index": int(o.index),
                    "heading_rad": _num(o.heading_rad),
                    "turn_rad": _num(o.turn_rad),
                    "angle_cost_rad": _num(o.angle_cost_rad),
                    "penalty_rad": _num(o.penalty_rad),
                    "cost_rad": _num(o.cost_rad),
                }
                for o in d.options
            ],
            "target": _target_dict(Target(d.target_x_m, d.target_y_m, d.target_kind, d.target_id)),
            "intersection_id": int(d.intersection_id),
            "revisit": bool(d.revisit),
            "mode": d.mode,
            "reason": d.reason,
        }
    )
    return msg


def prompt_message(
    t_s: float,
    text: str,
    *,
    vehicle_id: str,
    kind: str = "info",
    priority: int = 0,
    seq: int = 0,
    wall_time_unix_s: float | None = None,
) -> dict[str, Any]:
    """The ``guidance.prompt`` message: what the driver was told."""
    msg = _envelope("prompt", vehicle_id, seq, t_s, wall_time_unix_s)
    msg.update({"text": text, "kind": kind, "priority": int(priority)})
    return msg


@dataclass(frozen=True, slots=True)
class LandmarkRejection:
    """A candidate (or a whole frame) that did not give a fix, and why.

    ``reason`` is a short machine-readable word: "outside_gate", "too_few_matches",
    "ratio_test", "geometry", "innovation_gate", "no_candidates", "camera_down"...
    """

    reason: str
    landmark_id: int | None = None
    detail: str = ""


def landmark_message(
    t_s: float,
    *,
    vehicle_id: str,
    matches: Sequence[LandmarkFix] = (),
    rejections: Sequence[LandmarkRejection] = (),
    gated: int | None = None,
    seq: int = 0,
    wall_time_unix_s: float | None = None,
) -> dict[str, Any]:
    """The ``guidance.landmark`` message: matches and rejections of one recognition pass."""
    msg = _envelope("landmark", vehicle_id, seq, t_s, wall_time_unix_s)
    msg.update(
        {
            "gated": gated,
            "matches": [
                {
                    "landmark_id": int(m.landmark_id),
                    "x_m": _num(m.x_m),
                    "y_m": _num(m.y_m),
                    "sigma_m": _num(m.sigma_m),
                    "score": None,  # kept for readers of guidance.landmark/1
                    "name": "",
                }
                for m in matches
            ],
            "rejections": [
                {
                    "landmark_id": None if r.landmark_id is None else int(r.landmark_id),
                    "reason": r.reason,
                    "detail": r.detail,
                }
                for r in rejections
            ],
        }
    )
    return msg


def health_message(
    t_s: float,
    inputs: Mapping[str, Health],
    *,
    vehicle_id: str,
    components: Mapping[str, Health | Mapping[str, Any]] | None = None,
    seq: int = 0,
    wall_time_unix_s: float | None = None,
) -> dict[str, Any]:
    """The ``guidance.health`` message: each input's and component's ``Health.as_dict()``
    (a component may also be a free-form mapping: the estimator, the loop); ``ok`` is true
    when every input is alive and valid."""
    comps = {
        name: h.as_dict() if isinstance(h, Health) else dict(h)
        for name, h in (components or {}).items()
    }
    msg = _envelope("health", vehicle_id, seq, t_s, wall_time_unix_s)
    msg.update(
        {
            "ok": all(h.ok for h in inputs.values()),
            "inputs": {name: h.as_dict() for name, h in inputs.items()},
            "components": comps,
        }
    )
    return msg


def encode(message: Mapping[str, Any]) -> bytes:
    """JSON bytes of a message (compact, strict: no NaN)."""
    return json.dumps(message, separators=(",", ":"), allow_nan=False).encode()


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

MESSAGE_SCHEMAS: dict[str, dict[str, Any]] = {
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
MESSAGE_SCHEMAS["state"]["allOf"] = _POINT_RULES  # the car's position: coordinates in pairs too
