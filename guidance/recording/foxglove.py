"""Foxglove-native views of what the recorder writes (writer thread; no zenoh).

Our own topics (``/state``, ``/prompt``...) stay as they are for replay; beside them the
recorder writes the same facts in the published Foxglove schemas, so Foxglove-compatible
viewers show them in their standard panels:

* ``/foxglove/location`` (``foxglove.LocationFix``, Map panel): each ``/state`` with an origin;
* ``/foxglove/pose`` (``foxglove.PoseInFrame``): each ``/state``, frame ``map`` (x east, y north);
* ``/foxglove/scene`` (``foxglove.SceneUpdate``, 3D panel): every 0.5 s the estimate, its
  2-sigma ellipse, goal and target; each second the growing piece of the track and of the true
  track; every 10 s the landmarks;
* ``/foxglove/log`` (``foxglove.Log``, Log panel): each ``/prompt``;
* ``/truth/pose``, ``/truth/location``: the true pose of simulated drives (``record_truth``).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

from guidance.core.geo import LatLon
from guidance.outputs.messages import lat_lon_deg

FRAME = "map"
"""The 3D panel's frame: the local frame, x east, y north metres, z up."""
SCHEMA_OF_TOPIC = {
    "/foxglove/location": "foxglove.LocationFix",
    "/foxglove/pose": "foxglove.PoseInFrame",
    "/foxglove/scene": "foxglove.SceneUpdate",
    "/foxglove/log": "foxglove.Log",
    "/truth/pose": "foxglove.PoseInFrame",
    "/truth/location": "foxglove.LocationFix",
    "/camera/thumbnail": "foxglove.CompressedImage",
}
"""Every Foxglove topic of a recording and its schema name."""

TRACK_EVERY_S = 1.0
"""A track gets a point this often; its current piece is redrawn then."""
TRACK_PIECE = 60
"""Points per track entity (``track/0``, ``track/1``...): only the growing piece is resent, so
a long drive's scene stays small; pieces share their end points."""
LANDMARKS_EVERY_S = 10.0
SCENE_EVERY_S = 0.5
"""The estimate's scene entities (ellipse, goal) at most this often; the pose and location
topics keep the state's full rate."""

_BLUE = (0.15, 0.45, 1.0, 1.0)
_ELLIPSE = (0.15, 0.45, 1.0, 0.9)
_GREEN = (0.1, 0.75, 0.25, 1.0)
_RED = (0.9, 0.1, 0.1, 1.0)
_ORANGE = (1.0, 0.6, 0.0, 1.0)
_PURPLE = (0.6, 0.3, 0.8, 1.0)
_WHITE = (1.0, 1.0, 1.0, 1.0)


def stamp(t_s: float) -> dict[str, int]:
    """A Foxglove time from seconds (negative or non-finite clamp to 0)."""
    if not math.isfinite(t_s) or t_s < 0:
        return {"sec": 0, "nsec": 0}
    sec = math.floor(t_s)
    nsec = min(999_999_999, round((t_s - sec) * 1e9))
    return {"sec": int(sec), "nsec": int(nsec)}


def _color(c: Sequence[float]) -> dict[str, float]:
    return {"r": c[0], "g": c[1], "b": c[2], "a": c[3]}


def _point(x: float, y: float, z: float = 0.0) -> dict[str, float]:
    return {"x": round(float(x), 3), "y": round(float(y), 3), "z": round(float(z), 3)}


def _yaw(heading_rad: float) -> dict[str, float]:
    h = heading_rad if math.isfinite(heading_rad) else 0.0
    return {"x": 0.0, "y": 0.0, "z": math.sin(h / 2.0), "w": math.cos(h / 2.0)}


def _pose(x: float, y: float, heading_rad: float = 0.0) -> dict[str, Any]:
    return {"position": _point(x, y), "orientation": _yaw(heading_rad)}


def pose_in_frame(t_s: float, x_m: float, y_m: float, heading_rad: float) -> dict[str, Any]:
    """``foxglove.PoseInFrame`` in the local frame (yaw = heading, CCW from east)."""
    return {"timestamp": stamp(t_s), "frame_id": FRAME, "pose": _pose(x_m, y_m, heading_rad)}


def location_fix(
    t_s: float,
    lat_lon: tuple[float, float],
    covariance_en_m2: Sequence[Sequence[float]] | None,
    *,
    frame_id: str,
    color: Sequence[float],
) -> dict[str, Any]:
    """``foxglove.LocationFix``; the covariance is east/north/up (ENU), row-major, m²."""
    cov = [0.0] * 9
    kind = 0  # UNKNOWN
    if covariance_en_m2 is not None:
        (xx, xy), (yx, yy) = covariance_en_m2[0][:2], covariance_en_m2[1][:2]
        if all(v is not None and math.isfinite(v) for v in (xx, xy, yx, yy)):
            cov = [xx, xy, 0.0, yx, yy, 0.0, 0.0, 0.0, 0.0]
            kind = 3  # KNOWN
    return {
        "timestamp": stamp(t_s),
        "frame_id": frame_id,
        "latitude": lat_lon[0],
        "longitude": lat_lon[1],
        "altitude": 0.0,
        "position_covariance": [float(v) for v in cov],
        "position_covariance_type": kind,
        "color": _color(color),
        "metadata": [],
    }


def log_message(prompt: Mapping[str, Any]) -> dict[str, Any]:
    """``foxglove.Log`` of a ``guidance.prompt`` message: level WARNING for lost and sensor
    prompts, INFO otherwise; ``name`` is the car."""
    kind = str(prompt.get("kind", "info"))
    return {
        "timestamp": stamp(float(prompt.get("t_s") or 0.0)),
        "level": 3 if kind in ("lost", "sensor") else 2,
        "message": str(prompt.get("text", "")),
        "name": str(prompt.get("vehicle_id", "")),
        "file": f"prompt/{kind}",
        "line": 0,
    }


def ellipse_points(
    x: float, y: float, semi_major: float, semi_minor: float, orientation: float, n: int = 36
) -> list[dict[str, float]]:
    c, s = math.cos(orientation), math.sin(orientation)
    pts = []
    for i in range(n):
        a = 2.0 * math.pi * i / n
        u, v = semi_major * math.cos(a), semi_minor * math.sin(a)
        pts.append(_point(x + c * u - s * v, y + s * u + c * v, 0.05))
    return pts


def _entity(t_s: float, eid: str, **prims: list[dict[str, Any]]) -> dict[str, Any]:
    entity: dict[str, Any] = {
        "timestamp": stamp(t_s),
        "frame_id": FRAME,
        "id": eid,
        "lifetime": {"sec": 0, "nsec": 0},
        "frame_locked": False,
        "metadata": [],
    }
    for kind in ("arrows", "cubes", "spheres", "cylinders", "lines", "triangles", "texts"):
        entity[kind] = prims.get(kind, [])
    entity["models"] = []
    return entity


def _line(kind: int, points: list[dict[str, float]], color: Sequence[float], width: float) -> Any:
    return {
        "type": kind,  # 0 LINE_STRIP, 1 LINE_LOOP
        "pose": _pose(0.0, 0.0),
        "thickness": width,
        "scale_invariant": True,
        "points": points,
        "color": _color(color),
        "colors": [],
        "indices": [],
    }


def _sphere(x: float, y: float, size: float, color: Sequence[float]) -> dict[str, Any]:
    return {"pose": _pose(x, y), "size": _point(size, size, size), "color": _color(color)}


def _text(x: float, y: float, text: str, color: Sequence[float] = _WHITE) -> dict[str, Any]:
    return {
        "pose": _pose(x, y + 4.0),
        "billboard": True,
        "font_size": 14.0,
        "scale_invariant": True,
        "color": _color(color),
        "text": text,
    }


class _Track:
    """Points of a path, at most one per ``TRACK_EVERY_S``, drawn in pieces."""

    def __init__(self, name: str, color: Sequence[float]) -> None:
        self.name, self.color = name, color
        self.points: list[tuple[float, float]] = []
        self.next_t = -math.inf

    def add(self, t_s: float, x: float, y: float) -> bool:
        if t_s < self.next_t or not (math.isfinite(x) and math.isfinite(y)):
            return False
        self.next_t = t_s + TRACK_EVERY_S
        self.points.append((x, y))
        return True

    def piece(self, t_s: float) -> dict[str, Any]:
        """The entity of the piece the last point went into."""
        k = max(0, len(self.points) - 2) // TRACK_PIECE
        pts = [
            _point(px, py) for px, py in self.points[k * TRACK_PIECE : (k + 1) * TRACK_PIECE + 1]
        ]
        lines = [_line(0, pts, self.color, 2.0)] if len(pts) >= 2 else []
        return _entity(t_s, f"{self.name}/{k}", lines=lines)


class FoxgloveView:
    """Turns recorded messages into Foxglove messages; one per recorder (writer thread)."""

    def __init__(self, origin: LatLon | None) -> None:
        self.origin = origin
        self._track = _Track("track", _BLUE)
        self._truth = _Track("truth", _GREEN)
        self._landmarks: list[dict[str, Any]] = []
        self._next_landmarks_t = -math.inf
        self._next_scene_t = -math.inf

    def derive(self, topic: str, body: Mapping[str, Any]) -> list[tuple[str, dict[str, Any]]]:
        """The Foxglove messages (topic, message) that go with one recorded message."""
        if topic == "/state":
            return self._state(body)
        if topic == "/prompt":
            return [("/foxglove/log", log_message(body))]
        if topic == "/truth":
            return self._truth_pose(body)
        if topic == "/session":
            pipeline = body.get("pipeline")
            lms = pipeline.get("landmarks", []) if isinstance(pipeline, Mapping) else []
            self._landmarks = [dict(lm) for lm in lms if isinstance(lm, Mapping)]
        return []

    def _state(self, s: Mapping[str, Any]) -> list[tuple[str, dict[str, Any]]]:
        t = float(s.get("t_s") or 0.0)
        x, y, h = s.get("x_m"), s.get("y_m"), s.get("heading_rad")
        if x is None or y is None:
            return []
        heading = float(h) if h is not None else 0.0
        out: list[tuple[str, dict[str, Any]]] = [
            ("/foxglove/pose", pose_in_frame(t, x, y, heading))
        ]
        lat, lon = s.get("lat_deg"), s.get("lon_deg")
        if lat is not None and lon is not None:
            cov = s.get("covariance")
            out.append(
                (
                    "/foxglove/location",
                    location_fix(t, (lat, lon), cov, frame_id="estimate", color=_BLUE),
                )
            )
        entities = []
        if t >= self._next_scene_t:
            self._next_scene_t = t + SCENE_EVERY_S
            entities += [self._estimate_entity(t, s, x, y, heading), self._goal_entity(t, s)]
        if self._track.add(t, x, y):
            entities.append(self._track.piece(t))
        if t >= self._next_landmarks_t:
            self._next_landmarks_t = t + LANDMARKS_EVERY_S
            entities.append(self._landmark_entity(t))
        if entities:
            out.append(("/foxglove/scene", {"deletions": [], "entities": entities}))
        return out

    def _estimate_entity(
        self, t: float, s: Mapping[str, Any], x: float, y: float, heading: float
    ) -> dict[str, Any]:
        e = s.get("ellipse") or {}
        a, b, o = e.get("semi_major_m"), e.get("semi_minor_m"), e.get("orientation_rad")
        lines = []
        if a is not None and b is not None and o is not None:
            lines.append(_line(1, ellipse_points(x, y, a, b, o), _ELLIPSE, 2.0))
        arrow = {
            "pose": _pose(x, y, heading),
            "shaft_length": 6.0,
            "shaft_diameter": 1.0,
            "head_length": 3.0,
            "head_diameter": 2.5,
            "color": _color(_BLUE),
        }
        major = e.get("major_axis_m")
        label = f"{s.get('vehicle_id', '')} 2σ {major:.0f} m" if major is not None else ""
        return _entity(t, "estimate", arrows=[arrow], lines=lines, texts=[_text(x, y, label)])

    def _goal_entity(self, t: float, s: Mapping[str, Any]) -> dict[str, Any]:
        spheres, texts = [], []
        goal, target = s.get("goal"), s.get("target")
        if isinstance(goal, Mapping) and goal.get("x_m") is not None:
            spheres.append(_sphere(goal["x_m"], goal["y_m"], 6.0, _RED))
            texts.append(_text(goal["x_m"], goal["y_m"], "goal", _RED))
        is_target = isinstance(target, Mapping) and target.get("x_m") is not None
        if is_target and isinstance(target, Mapping) and target.get("kind") != "goal":
            spheres.append(_sphere(target["x_m"], target["y_m"], 4.0, _ORANGE))
            texts.append(_text(target["x_m"], target["y_m"], "target", _ORANGE))
        return _entity(t, "goal", spheres=spheres, texts=texts)

    def _landmark_entity(self, t: float) -> dict[str, Any]:
        spheres, texts = [], []
        for lm in self._landmarks:
            lx, ly = lm.get("x_m"), lm.get("y_m")
            if isinstance(lx, int | float) and isinstance(ly, int | float):
                spheres.append(_sphere(lx, ly, 3.0, _PURPLE))
                texts.append(_text(lx, ly, str(lm.get("name") or f"landmark {lm.get('id')}")))
        return _entity(t, "landmarks", spheres=spheres, texts=texts)

    def _truth_pose(self, b: Mapping[str, Any]) -> list[tuple[str, dict[str, Any]]]:
        t, x, y, h = (float(b[k]) for k in ("t_s", "x_m", "y_m", "heading_rad"))
        out: list[tuple[str, dict[str, Any]]] = [("/truth/pose", pose_in_frame(t, x, y, h))]
        geo = lat_lon_deg(x, y, self.origin)
        if geo is not None:
            out.append(("/truth/location", location_fix(t, geo, None, frame_id="truth",
                                                        color=_GREEN)))  # fmt: skip
        if self._truth.add(t, x, y):  # the growing piece only, like the estimated track
            out.append(("/foxglove/scene", {"deletions": [], "entities": [self._truth.piece(t)]}))
        return out
