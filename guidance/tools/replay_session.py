"""What ``guidance replay`` reads from a recording, checked at the boundary (issue 14).

A recording is a file from outside: a valid MCAP may carry a ``/session`` record of another
schema, NaN or 1e308 in the pipeline settings, text where numbers belong, a million landmarks.
``pipeline_config_from_session`` rebuilds the ``PipelineConfig`` only from values that are the
right type, finite and within the range the pipeline needs, and otherwise raises one
``UserError`` line naming the setting. ``recording_sessions`` splits a folder into the recorded
sessions (``<prefix>-<YYYYmmdd-HHMMSS>-<NNNN>.mcap``, one per start of the recorder), so each is
replayed on its own instead of merging different drives.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from enum import Enum
from pathlib import Path
from typing import TYPE_CHECKING, Any

from guidance.errors import UserError

if TYPE_CHECKING:
    from guidance.core.pipeline import PipelineConfig

MAX_COORD_M = 1e8
MAX_LANDMARKS = 100_000
MAX_VALUE = 1e9
POSITIVE = frozenset(
    {
        "track_m",
        "initial_position_sigma_m",
        "initial_heading_sigma_deg",
        "max_wheel_step_m",
        "lost_major_axis_m",
        "compass_gate_chi2",
        "landmark_gate_chi2",
        "compass_two_sigma_deg",
        "state_period_s",
        "straight_after_m",
        "uncertain_warn_m",
    }
)
"""Settings that must be above zero (a zero track or period divides by zero)."""
INT_LIMITS = {"max_intersections": (1, 100_000), "max_exits": (1, 64)}
"""Integer settings that size the navigator's arrays."""
_SESSION_FILE = re.compile(r"^(?P<key>.+-\d{8}-\d{6})-\d{4}\.mcap$")


def _bad(where: str, why: str) -> UserError:
    return UserError(f"the recording's /session record: {where} {why}")


def _num(v: object, where: str, lo: float = 0.0, hi: float = MAX_VALUE) -> float:
    if isinstance(v, bool) or not isinstance(v, int | float):
        raise _bad(where, f"must be a number, not {type(v).__name__}")
    try:
        f = float(v)
    except OverflowError:
        raise _bad(where, "is out of range") from None
    if not math.isfinite(f):
        raise _bad(where, f"must be finite, not {f}")
    if not lo <= f <= hi:
        raise _bad(where, f"= {f:.6g} is outside [{lo:.6g}, {hi:.6g}]")
    if where.rsplit(".", 1)[-1] in POSITIVE and f <= 0:
        raise _bad(where, "must be > 0")
    return f


def _table(v: object, where: str) -> Mapping[str, Any]:
    if not isinstance(v, Mapping):
        raise _bad(where, f"must be a table, not {type(v).__name__}")
    return v


def _settings(d: Mapping[str, Any], cls: type, where: str) -> dict[str, Any]:
    """The fields of a config dataclass from ``d``: known names only, numbers checked."""
    import dataclasses

    fields = {f.name: f for f in dataclasses.fields(cls)}
    out: dict[str, Any] = {}
    for key, value in d.items():
        name = f"{where}.{str(key)[:40]}"
        if key not in fields:
            raise _bad(name, "is not a setting of this version")
        default = fields[key].default
        if key in INT_LIMITS:
            lo, hi = INT_LIMITS[key]
            if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
                raise _bad(name, f"must be an integer in [{lo}, {hi}]")
            out[key] = value
        elif isinstance(default, bool):
            if not isinstance(value, bool):
                raise _bad(name, "must be true or false")
            out[key] = value
        elif isinstance(default, str | Enum):
            if not isinstance(value, str) or len(value) > 100:
                raise _bad(name, "must be a short text")
            out[key] = value
        elif value is None and default is None:
            out[key] = None
        else:
            out[key] = _num(value, name)
    return out


def pipeline_config_from_session(session: Mapping[str, Any]) -> PipelineConfig:
    """Rebuild the pipeline configuration from a recording's ``/session`` record (checked)."""
    from guidance.core.estimator import EstimatorConfig
    from guidance.core.health import HealthConfig
    from guidance.core.navigator import Landmark, Method, NavigatorConfig
    from guidance.core.pipeline import PipelineConfig
    from guidance.core.prompts import Units

    d = session.get("pipeline") if isinstance(session, Mapping) else None
    if not isinstance(d, Mapping):
        raise UserError("the recording's /session record has no pipeline configuration")
    est = _settings(_table(d.get("estimator", {}), "estimator"), EstimatorConfig, "estimator")
    nav = _settings(_table(d.get("navigator", {}), "navigator"), NavigatorConfig, "navigator")
    try:
        nav["method"] = Method(nav.get("method", Method.STRAIGHT_TO_GOAL.value))
        units = Units(d.get("units", "metric"))
    except ValueError as exc:
        raise _bad("method or units", str(exc)) from None

    def xy(key: str) -> tuple[float, float]:
        v = d.get(key)
        if not isinstance(v, list | tuple) or len(v) != 2:
            raise _bad(key, "must be [x, y]")
        return (
            _num(v[0], key, -MAX_COORD_M, MAX_COORD_M),
            _num(v[1], key, -MAX_COORD_M, MAX_COORD_M),
        )

    landmarks = d.get("landmarks", [])
    if not isinstance(landmarks, list) or len(landmarks) > MAX_LANDMARKS:
        raise _bad("landmarks", f"must be a list of at most {MAX_LANDMARKS}")
    lms = []
    for i, lm in enumerate(landmarks):
        t = _table(lm, f"landmarks[{i}]")
        lm_id = t.get("id")
        if isinstance(lm_id, bool) or not isinstance(lm_id, int) or abs(lm_id) >= 2**63:
            raise _bad(f"landmarks[{i}].id", "must be an integer")
        name = t.get("name", "")
        if not isinstance(name, str) or set(t) - {"id", "x_m", "y_m", "name"}:
            raise _bad(f"landmarks[{i}]", "must hold id, x_m, y_m and a name")
        x = _num(t.get("x_m"), f"landmarks[{i}].x_m", -MAX_COORD_M, MAX_COORD_M)
        y = _num(t.get("y_m"), f"landmarks[{i}].y_m", -MAX_COORD_M, MAX_COORD_M)
        lms.append(Landmark(lm_id, x, y, name[:200]))
    heading = d.get("start_heading_rad")
    rates = _table(d.get("expected_rates_hz", {}), "expected_rates_hz")
    if len(rates) > 16:
        raise _bad("expected_rates_hz", "has too many inputs")
    deviation = d.get("compass_deviation_deg", [])
    if not isinstance(deviation, list) or len(deviation) > 16:
        raise _bad("compass_deviation_deg", "must be a short list")
    stop = d.get("stop_at_arrival", True)
    if not isinstance(stop, bool):
        raise _bad("stop_at_arrival", "must be true or false")
    try:
        return PipelineConfig(
            estimator=EstimatorConfig(**est),
            navigator=NavigatorConfig(**nav),
            start_xy_m=xy("start_xy_m"),
            goal_xy_m=xy("goal_xy_m"),
            start_heading_rad=None
            if heading is None
            else _num(heading, "start_heading_rad", -7, 7),
            landmarks=tuple(lms),
            declination_deg=_num(d.get("declination_deg", 0.0), "declination_deg", -180, 180),
            mounting_offset_deg=_num(
                d.get("mounting_offset_deg", 0.0), "mounting_offset_deg", -360, 360
            ),
            compass_deviation_deg=tuple(
                _num(v, "compass_deviation_deg", -90, 90) for v in deviation
            ),
            compass_unusable_after_s=_num(
                d.get("compass_unusable_after_s", 20.0), "compass_unusable_after_s", 0.1, 1e6
            ),
            units=units,
            state_period_s=_num(d.get("state_period_s", 0.1), "state_period_s", 1e-3, 60),
            expected_rates_hz={
                str(k)[:40]: None if v is None else _num(v, f"expected_rates_hz.{k}", 1e-3, 1e4)
                for k, v in rates.items()
            },
            health=HealthConfig(),
            straight_after_m=_num(d.get("straight_after_m", 25.0), "straight_after_m"),
            uncertain_warn_m=_num(d.get("uncertain_warn_m", 50.0), "uncertain_warn_m"),
            stop_at_arrival=stop,
        )
    except (TypeError, ValueError) as exc:  # a setting the dataclasses themselves refuse
        raise _bad("pipeline", f"cannot be used: {str(exc)[:120]}") from None


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
