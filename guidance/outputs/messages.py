"""The output encoders: one pure function per output kind, from the core's values to the JSON
message telemetry publishes and the recorder writes (no zenoh, no mcap, no numba; the kinds
themselves are listed once, in ``guidance.outputs.kinds``).
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, cast

from guidance.core import geo
from guidance.core.angles import heading_to_compass, wrap_angle
from guidance.core.messages import (
    EstimateState,
    ExitTaken,
    Health,
    LandmarkFix,
    Target,
    TurnCompleted,
)
from guidance.outputs.shapes import (
    DecisionMessage,
    Envelope,
    ExitMessage,
    GeoTargetShape,
    HealthMessage,
    HealthShape,
    LandmarkMessage,
    PointShape,
    PromptMessage,
    StateMessage,
    TargetShape,
    TurnMessage,
)

if TYPE_CHECKING:
    from guidance.core.plan.navigator import Decision


SCHEMA_VERSION = 1


def schema_tag(kind: str) -> str:
    """The ``schema`` field of a message: ``guidance.<kind>/<version>``."""
    return f"guidance.{kind}/{SCHEMA_VERSION}"


# -- message encoders (pure functions, shared by telemetry and the recorder) -------------------
def _num(value: float | None) -> float | None:
    """A JSON-safe float: non-finite values become null (strict JSON has no NaN)."""
    if value is None:
        return None
    f = float(value)
    return f if math.isfinite(f) else None


def _envelope(
    kind: str, vehicle_id: str, seq: int, t_s: float, wall_time_unix_s: float | None
) -> Envelope:
    return {
        "schema": schema_tag(kind),
        "vehicle_id": vehicle_id,
        "seq": seq,
        "t_s": _num(t_s),
        "wall_time_unix_s": _num(wall_time_unix_s),
    }


def _target_dict(target: Target | None) -> TargetShape | None:
    if target is None:
        return None
    tid = target.id
    return {"x_m": _num(target.x_m), "y_m": _num(target.y_m), "kind": target.kind,
            "id": None if tid is None else int(tid)}  # fmt: skip


def _wrap_deg(angle_rad: float) -> float | None:
    """Degrees in (-180, 180]; None for a non-finite angle (the field, not the message, is lost)."""
    return _num(math.degrees(wrap_angle(angle_rad))) if math.isfinite(angle_rad) else None


def heading_deg_true(heading_rad: float | None) -> float | None:
    """Compass heading: degrees clockwise from true north in [0, 360), from ``heading_rad``
    (counter-clockwise from east, the local frame's convention)."""
    if heading_rad is None or not math.isfinite(heading_rad):
        return None
    return float(heading_to_compass(heading_rad, 0.0))  # true: no declination


def lat_lon_deg(
    x_m: float | None, y_m: float | None, origin: geo.LatLon | None
) -> geo.LatLon | None:
    """WGS-84 latitude and longitude of a local point (east, north metres from ``origin``,
    ``guidance.core.geo``); None without an origin or a finite point."""
    if origin is None or x_m is None or y_m is None:
        return None
    if not (math.isfinite(x_m) and math.isfinite(y_m)):
        return None
    return geo.Origin.of(origin).to_geodetic(x_m, y_m)


def _geo(
    x_m: float | None, y_m: float | None, origin: geo.LatLon | None
) -> geo.LatLon | tuple[None, None]:
    """``lat_deg``/``lon_deg`` of a point (nulls without an origin)."""
    ll = lat_lon_deg(x_m, y_m, origin)
    return ll if ll is not None else (None, None)


def _geo_target(target: Target | None, origin: geo.LatLon | None) -> GeoTargetShape | None:
    """The target with ``lat_deg``/``lon_deg`` (null without an origin)."""
    t = _target_dict(target)
    if t is None:
        return None
    lat, lon = _geo(t["x_m"], t["y_m"], origin)
    return {**t, "lat_deg": lat, "lon_deg": lon}


def _geo_point(point: tuple[float, float] | None, origin: geo.LatLon | None) -> PointShape | None:
    """A point with ``lat_deg``/``lon_deg`` (null without an origin)."""
    if point is None:
        return None
    x, y = _num(point[0]), _num(point[1])
    lat, lon = _geo(x, y, origin)
    return {"x_m": x, "y_m": y, "lat_deg": lat, "lon_deg": lon}


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
    origin_lat_lon_deg: geo.LatLon | None = None,
    chance: float | None = None,
) -> StateMessage:
    """The ``guidance.state`` message (docs/telemetry.md).

    With ``origin_lat_lon_deg`` (the configured start), the position, target and goal also
    carry WGS-84 ``lat_deg``/``lon_deg``; without it those are null.
    """
    e = state.ellipse
    x, y = _num(state.x_m), _num(state.y_m)
    geo = lat_lon_deg(x, y, origin_lat_lon_deg)
    msg: StateMessage = {
        **_envelope("state", vehicle_id, seq, state.t_s, wall_time_unix_s),
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
        "target": _geo_target(target, origin_lat_lon_deg),
        "goal": _geo_point(goal, origin_lat_lon_deg),
        "method": None if method is None else str(method),
        "mode": mode,
        "chance": None if chance is None else min(1.0, max(0.0, _num(chance) or 0.0)),
        "lost": bool(state.lost),
        "healthy": bool(state.healthy),
    }
    return msg


def decision_message(
    decision: Decision,
    *,
    vehicle_id: str,
    seq: int = 0,
    wall_time_unix_s: float | None = None,
) -> DecisionMessage:
    """The ``guidance.decision`` message from a ``guidance.navigator.Decision``."""
    d = decision
    msg: DecisionMessage = {
        **_envelope("decision", vehicle_id, seq, d.t_s, wall_time_unix_s),
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
) -> PromptMessage:
    """The ``guidance.prompt`` message: what the driver was told."""
    env = _envelope("prompt", vehicle_id, seq, t_s, wall_time_unix_s)
    return {**env, "text": text, "kind": kind, "priority": int(priority)}


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
) -> LandmarkMessage:
    """The ``guidance.landmark`` message: matches and rejections of one recognition pass."""
    msg: LandmarkMessage = {
        **_envelope("landmark", vehicle_id, seq, t_s, wall_time_unix_s),
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
    return msg


def health_message(
    t_s: float,
    inputs: Mapping[str, Health],
    *,
    vehicle_id: str,
    components: Mapping[str, Health | Mapping[str, Any]] | None = None,
    seq: int = 0,
    wall_time_unix_s: float | None = None,
) -> HealthMessage:
    """The ``guidance.health`` message: each input's and component's ``Health.as_dict()``
    (a component may also be a free-form mapping: the estimator, the loop); ``ok`` is true
    when every input is alive and valid."""
    comps = {
        name: h.as_dict() if isinstance(h, Health) else dict(h)
        for name, h in (components or {}).items()
    }
    msg: HealthMessage = {
        **_envelope("health", vehicle_id, seq, t_s, wall_time_unix_s),
        "ok": all(h.ok for h in inputs.values()),
        "inputs": {name: cast(HealthShape, h.as_dict()) for name, h in inputs.items()},
        "components": comps,
    }
    return msg


def turn_message(
    turn: TurnCompleted, *, vehicle_id: str, seq: int = 0, wall_time_unix_s: float | None = None
) -> TurnMessage:
    """The ``guidance.turn`` message: a turn the driver completed (typed or detected)."""
    msg: TurnMessage = {
        **_envelope("turn", vehicle_id, seq, turn.t_s, wall_time_unix_s),
        "heading_change_rad": _num(turn.heading_change_rad),
        "heading_change_deg": _num(math.degrees(turn.heading_change_rad)),
        "source": turn.source,
    }
    return msg


def exit_message(
    taken: ExitTaken, *, vehicle_id: str, seq: int = 0, wall_time_unix_s: float | None = None
) -> ExitMessage:
    """The ``guidance.exit`` message: which exit the driver took at a decided intersection,
    and whether it was the advised one (a monitor sees "advice not followed")."""
    d = taken.decision
    msg: ExitMessage = {
        **_envelope("exit", vehicle_id, seq, taken.t_s, wall_time_unix_s),
        "intersection_id": int(d.intersection_id),
        "decision_t_s": _num(d.t_s),
        "advised_exit": int(d.exit_index),
        "taken_exit": int(taken.exit_index),
        "followed": bool(taken.followed),
        "source": taken.source,
    }
    return msg


def encode(message: Mapping[str, Any]) -> bytes:
    """JSON bytes of a message (compact, strict: no NaN)."""
    return json.dumps(message, separators=(",", ":"), allow_nan=False).encode()
