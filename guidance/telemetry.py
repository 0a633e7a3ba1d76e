"""Zenoh telemetry (SPEC section 6): the car's state for remote monitors, and the monitor's side.

zenoh is wrapped here and nowhere else (HOUSE_STYLE). One ``Telemetry`` per car
process owns one zenoh session and publishes, under ``guidance/<vehicle_id>/``:

* ``state`` (pose, covariance, 2-sigma ellipse, speed, target, method, lost),
* ``decision``, ``prompt``, ``landmark`` (matches and rejections with reasons),
* ``health`` (per input: alive, valid, rate_hz, age_s; plus telemetry itself),

as JSON objects carrying ``schema`` ("guidance.<kind>/<version>"), ``t_s`` (the
car's monotonic clock, the same time base as the estimator) and
``wall_time_unix_s`` (for logs only). The message schemas are in
docs/telemetry.md and in ``MESSAGE_SCHEMAS`` (JSON Schema, also used by the MCAP
recorder). The car also holds the liveliness token ``guidance/<vehicle_id>`` and
answers queries on ``guidance/<vehicle_id>/<kind>`` with the latest message, so
a monitor that joins late sees the current state at once.

Publishing never blocks the caller: ``publish_*`` stores the message in a
latest-value slot (state, health, landmark) or a short bounded FIFO (decision,
prompt), and a publisher thread encodes and sends it with zenoh's
``CongestionControl.DROP`` and ``express``. Everything overwritten or pushed
out before it was sent is counted as a drop, by reason, in ``health()``. The
session is opened by that thread too: if zenoh is unreachable (client mode with
no router, port taken, bad certificate) the car keeps running, telemetry health
reports ``down`` and the session is retried in the background. No zenoh error is
ever raised into the application after construction.

A remote goal (``guidance/<vehicle_id>/cmd/goal``, JSON ``{"x_m": .., "y_m": ..}``)
is subscribed to only when ``allow_remote_goal`` is set (off by default); who may
send one is then a matter for zenoh's access control (config/zenoh/). Malformed
or out-of-range goals are refused, counted and logged.

``MonitorClient`` is the receiving side used by ``guidance monitor``, the tests
and the latency benchmark.
"""

from __future__ import annotations

import json
import logging
import math
import queue
import re
import threading
import time
import weakref
from collections import deque
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field, fields
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING, Any

import zenoh

from guidance.errors import UserError
from guidance.messages import EstimateState, LandmarkFix

if TYPE_CHECKING:
    import asyncio

    from guidance.navigator import Decision

log = logging.getLogger(__name__)

KEY_PREFIX = "guidance"
SCHEMA_VERSION = 1
KINDS = ("state", "decision", "prompt", "landmark", "health")
"""Message kinds published under ``guidance/<vehicle_id>/<kind>``."""
LATEST_KINDS = frozenset({"state", "health", "landmark"})
"""Kinds held in a latest-value slot; the others go through a short FIFO."""
GOAL_SCHEMA = f"guidance.goal/{SCHEMA_VERSION}"
DEFAULT_PORT = 7447
DEFAULT_LISTEN = f"tcp/127.0.0.1:{DEFAULT_PORT}"
DEFAULT_CONNECT = DEFAULT_LISTEN

_VEHICLE_ID_RE = re.compile(r"^[A-Za-z0-9_.-]{1,64}$")
_ENDPOINT_RE = re.compile(r"^[a-z][a-z0-9-]*/\S+$")
_MODES = ("peer", "client")


# -- keys and schema tags ---------------------------------------------------------------------
def key_for(vehicle_id: str, kind: str) -> str:
    """The zenoh key of one message kind of one vehicle."""
    return f"{KEY_PREFIX}/{vehicle_id}/{kind}"


def goal_key(vehicle_id: str) -> str:
    return f"{KEY_PREFIX}/{vehicle_id}/cmd/goal"


def liveliness_key(vehicle_id: str) -> str:
    return f"{KEY_PREFIX}/{vehicle_id}"


def parse_key(key: str) -> tuple[str, str] | None:
    """``guidance/<vehicle_id>/<kind>`` -> (vehicle_id, kind); None for any other key."""
    parts = key.split("/")
    if len(parts) != 3 or parts[0] != KEY_PREFIX:
        return None
    return parts[1], parts[2]


def schema_tag(kind: str) -> str:
    return f"guidance.{kind}/{SCHEMA_VERSION}"


def parse_schema_tag(tag: object) -> tuple[str, int] | None:
    """Split a tag: "guidance.state/1" -> ("guidance.state", 1); None if it is not one."""
    if not isinstance(tag, str) or "/" not in tag:
        return None
    name, _, version = tag.rpartition("/")
    return (name, int(version)) if version.isdigit() else None


def validate_vehicle_id(vehicle_id: str) -> str:
    if not _VEHICLE_ID_RE.match(vehicle_id):
        raise UserError(
            f"vehicle id {vehicle_id!r} must be 1-64 characters from A-Z a-z 0-9 _ . - "
            "(it becomes one chunk of a zenoh key)"
        )
    return vehicle_id


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


@dataclass(frozen=True, slots=True)
class Target:
    """Where the navigator is heading: the goal or a landmark."""

    x_m: float
    y_m: float
    kind: str = "goal"
    id: int | None = None


TargetLike = Target | tuple[float, float, str, int | None] | tuple[float, float]


def _target_dict(target: TargetLike | None) -> dict[str, Any] | None:
    if target is None:
        return None
    if isinstance(target, Target):
        x, y, kind, tid = target.x_m, target.y_m, target.kind, target.id
    else:
        x, y = target[0], target[1]
        kind = str(target[2]) if len(target) > 2 else "goal"
        tid = target[3] if len(target) > 3 else None
    return {"x_m": _num(x), "y_m": _num(y), "kind": kind, "id": None if tid is None else int(tid)}


def _wrap_deg(angle_rad: float) -> float | None:
    deg = math.degrees(math.atan2(math.sin(angle_rad), math.cos(angle_rad)))
    return _num(deg)


def state_message(
    state: EstimateState,
    *,
    vehicle_id: str,
    seq: int = 0,
    wall_time_unix_s: float | None = None,
    speed_mps: float | None = None,
    target: TargetLike | None = None,
    goal: tuple[float, float] | None = None,
    method: str | None = None,
    mode: str | None = None,
) -> dict[str, Any]:
    """The ``guidance.state`` message (docs/telemetry.md)."""
    e = state.ellipse
    msg = _envelope("state", vehicle_id, seq, state.t_s, wall_time_unix_s)
    msg.update(
        {
            "x_m": _num(state.x_m),
            "y_m": _num(state.y_m),
            "heading_rad": _num(state.heading_rad),
            "heading_deg": _wrap_deg(state.heading_rad),
            "covariance": [[_num(v) for v in row] for row in state.covariance],
            "ellipse": {
                "semi_major_m": _num(e.semi_major_m),
                "semi_minor_m": _num(e.semi_minor_m),
                "orientation_rad": _num(e.orientation_rad),
                "major_axis_m": _num(e.major_axis_m),
            },
            "speed_mps": _num(speed_mps),
            "target": _target_dict(target),
            "goal": None if goal is None else {"x_m": _num(goal[0]), "y_m": _num(goal[1])},
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
            "target": _target_dict((d.target_x_m, d.target_y_m, d.target_kind, d.target_id)),
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
class LandmarkMatch:
    """A camera match accepted as a position fix."""

    landmark_id: int
    x_m: float
    y_m: float
    sigma_m: float
    score: float | None = None
    name: str = ""


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
    matches: Sequence[LandmarkMatch | LandmarkFix] = (),
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
                    "score": _num(m.score) if isinstance(m, LandmarkMatch) else None,
                    "name": m.name if isinstance(m, LandmarkMatch) else "",
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


@dataclass(frozen=True, slots=True)
class InputHealth:
    """Health of one input (odometry, compass, camera, scene...)."""

    alive: bool
    valid: bool
    rate_hz: float
    age_s: float | None
    expected_rate_hz: float | None = None
    detail: str = ""


def _input_dict(h: InputHealth | Mapping[str, Any]) -> dict[str, Any]:
    if isinstance(h, InputHealth):
        return {
            "alive": h.alive,
            "valid": h.valid,
            "rate_hz": _num(h.rate_hz),
            "age_s": _num(h.age_s),
            "expected_rate_hz": _num(h.expected_rate_hz),
            "detail": h.detail,
        }
    return {
        "alive": bool(h.get("alive", False)),
        "valid": bool(h.get("valid", False)),
        "rate_hz": _num(h.get("rate_hz")),
        "age_s": _num(h.get("age_s")),
        "expected_rate_hz": _num(h.get("expected_rate_hz")),
        "detail": str(h.get("detail", "")),
    }


def health_message(
    t_s: float,
    inputs: Mapping[str, InputHealth | Mapping[str, Any]],
    *,
    vehicle_id: str,
    components: Mapping[str, Mapping[str, Any]] | None = None,
    seq: int = 0,
    wall_time_unix_s: float | None = None,
) -> dict[str, Any]:
    """The ``guidance.health`` message; ``ok`` is true when every input is alive and valid."""
    ins = {name: _input_dict(h) for name, h in inputs.items()}
    msg = _envelope("health", vehicle_id, seq, t_s, wall_time_unix_s)
    msg.update(
        {
            "ok": all(v["alive"] and v["valid"] for v in ins.values()),
            "inputs": ins,
            "components": {k: dict(v) for k, v in (components or {}).items()},
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
_TARGET = {
    "type": ["object", "null"],
    "properties": {
        "x_m": _NUM,
        "y_m": _NUM,
        "kind": {"type": "string", "enum": ["goal", "landmark"]},
        "id": {"type": ["integer", "null"]},
    },
}


def _obj(title: str, props: Mapping[str, Any]) -> dict[str, Any]:
    return {
        "$schema": "http://json-schema.org/draft-07/schema#",
        "title": title,
        "type": "object",
        "properties": {**_ENVELOPE_PROPS, **props},
        "required": ["schema", "vehicle_id", "seq", "t_s"],
    }


MESSAGE_SCHEMAS: dict[str, dict[str, Any]] = {
    "state": _obj(
        "guidance.state",
        {
            "x_m": _NUM,
            "y_m": _NUM,
            "heading_rad": _NUM,
            "heading_deg": _NUM,
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
            "target": _TARGET,
            "goal": {"type": ["object", "null"], "properties": {"x_m": _NUM, "y_m": _NUM}},
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
            "inputs": {
                "type": "object",
                "additionalProperties": {
                    "type": "object",
                    "properties": {
                        "alive": {"type": "boolean"},
                        "valid": {"type": "boolean"},
                        "rate_hz": _NUM,
                        "age_s": _NUM,
                        "expected_rate_hz": _NUM,
                        "detail": {"type": "string"},
                    },
                },
            },
            "components": {"type": "object"},
        },
    ),
}


# -- configuration --------------------------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class TlsConfig:
    """TLS for ``tls/`` endpoints: this node's certificate and the CA that signs its peers.

    ``certificate``/``private_key`` are presented when listening and, with
    ``mutual`` (mTLS), also when connecting; mTLS is what lets an access-control
    policy name peers by certificate common name.
    """

    root_ca_certificate: str
    certificate: str = ""
    private_key: str = ""
    mutual: bool = False
    verify_name_on_connect: bool = True

    def as_zenoh(self) -> dict[str, Any]:
        tls: dict[str, Any] = {
            "root_ca_certificate": self.root_ca_certificate,
            "enable_mtls": self.mutual,
            "verify_name_on_connect": self.verify_name_on_connect,
        }
        if self.certificate:
            tls["listen_certificate"] = self.certificate
            tls["listen_private_key"] = self.private_key
            if self.mutual:
                tls["connect_certificate"] = self.certificate
                tls["connect_private_key"] = self.private_key
        return tls


@dataclass(frozen=True, slots=True)
class TelemetryConfig:
    """The ``[telemetry]`` table of the car's TOML config (docs/telemetry.md).

    ``mode="peer"`` (default) listens on ``listen`` (loopback) and monitors
    connect to it; ``mode="client"`` connects to a zenoh router at ``connect``.
    ``zenoh_config`` names an optional zenoh JSON5 file loaded first, for what
    this table does not cover (``access_control``, ``transport/auth``); the keys
    of this table then override mode, endpoints, scouting and TLS.
    """

    enabled: bool = True
    vehicle_id: str = "car1"
    mode: str = "peer"
    listen: tuple[str, ...] = (DEFAULT_LISTEN,)
    connect: tuple[str, ...] = ()
    multicast_scouting: bool = False
    zenoh_config: str = ""
    tls: TlsConfig | None = None
    allow_remote_goal: bool = False
    max_goal_range_m: float = 50_000.0
    """Goals farther than this from the origin (the start) are refused."""
    retry_period_s: float = 2.0
    fifo_size: int = 32
    """Decisions and prompts waiting to be sent, per kind; the oldest is dropped beyond."""

    def __post_init__(self) -> None:
        validate_vehicle_id(self.vehicle_id)
        if self.mode not in _MODES:
            raise UserError(f"telemetry mode must be one of {_MODES}, not {self.mode!r}")
        for ep in (*self.listen, *self.connect):
            check_endpoint(ep)
        if self.mode == "client" and not self.connect:
            raise UserError("telemetry mode 'client' needs connect endpoints (the router)")
        if not (self.retry_period_s > 0 and self.max_goal_range_m > 0 and self.fifo_size > 0):
            raise UserError("telemetry retry_period_s, max_goal_range_m, fifo_size must be > 0")

    @classmethod
    def from_mapping(
        cls, table: Mapping[str, Any], base_dir: Path | None = None
    ) -> TelemetryConfig:
        """Build from a parsed ``[telemetry]`` TOML table; unknown keys and bad types are errors.

        Relative file paths are taken relative to ``base_dir`` (the TOML file's folder).
        """
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(table) - known)
        if unknown:
            raise UserError(f"[telemetry]: unknown key(s) {', '.join(unknown)}")

        def path(value: object, key: str) -> str:
            if not isinstance(value, str):
                raise UserError(f"[telemetry] {key} must be a string path")
            if value and base_dir is not None and not Path(value).is_absolute():
                return str(base_dir / value)
            return value

        kwargs: dict[str, Any] = {}
        for key, value in table.items():
            if key in ("listen", "connect"):
                if isinstance(value, str):
                    value = [value]
                if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
                    raise UserError(f"[telemetry] {key} must be a list of endpoint strings")
                kwargs[key] = tuple(value)
            elif key == "tls":
                if not isinstance(value, Mapping):
                    raise UserError("[telemetry.tls] must be a table")
                tls_known = {f.name for f in fields(TlsConfig)}
                bad = sorted(set(value) - tls_known)
                if bad or "root_ca_certificate" not in value:
                    raise UserError(
                        "[telemetry.tls] needs root_ca_certificate"
                        + (f"; unknown key(s) {', '.join(bad)}" if bad else "")
                    )
                verify = value.get("verify_name_on_connect", True)
                kwargs["tls"] = TlsConfig(
                    root_ca_certificate=path(
                        value["root_ca_certificate"], "tls.root_ca_certificate"
                    ),
                    certificate=path(value.get("certificate", ""), "tls.certificate"),
                    private_key=path(value.get("private_key", ""), "tls.private_key"),
                    mutual=_typed(value.get("mutual", False), bool, "tls.mutual"),
                    verify_name_on_connect=_typed(verify, bool, "tls.verify_name_on_connect"),
                )
            elif key == "zenoh_config":
                kwargs[key] = path(value, key)
            elif key in ("enabled", "multicast_scouting", "allow_remote_goal"):
                kwargs[key] = _typed(value, bool, key)
            elif key in ("retry_period_s", "max_goal_range_m"):
                kwargs[key] = float(_typed(value, (int, float), key))
            elif key == "fifo_size":
                kwargs[key] = _typed(value, int, key)
            else:
                kwargs[key] = _typed(value, str, key)
        return cls(**kwargs)


def _typed(value: Any, types: type | tuple[type, ...], key: str) -> Any:
    if not isinstance(value, types) or (types is not bool and isinstance(value, bool)):
        names = types.__name__ if isinstance(types, type) else "/".join(t.__name__ for t in types)
        raise UserError(f"[telemetry] {key} must be {names}, not {value!r}")
    return value


def check_endpoint(endpoint: str) -> str:
    """A zenoh endpoint looks like ``tcp/127.0.0.1:7447``; say so clearly if it does not."""
    if not _ENDPOINT_RE.match(endpoint):
        raise UserError(
            f"bad zenoh endpoint {endpoint!r}: expected <protocol>/<address>, "
            "e.g. tcp/127.0.0.1:7447 or tls/localhost:7447"
        )
    return endpoint


# -- secrets never reach a log ------------------------------------------------------------------
REDACTED = "***"
_SECRET_WORDS = ("password", "passwd", "passphrase", "pwd", "secret", "token", "credential")
_SECRET_NAME_RE = re.compile(
    r"(?:" + "|".join(_SECRET_WORDS) + r")|(?:^|[_.-])key$|^apikey$", re.IGNORECASE
)
_SECRET_ASSIGNMENT_RE = re.compile(
    r"""(?P<name>["']?[\w.-]*(?:"""
    + "|".join(_SECRET_WORDS)
    + r"""|(?<![\w])key|_key)["']?\s*[:=]\s*)"""
    r"""(?P<value>"(?:[^"\\]|\\.)*"|'[^']*'|[^\s,;{}\[\]]+)""",
    re.IGNORECASE,
)
_ERROR_VALUE_RE = re.compile(r"(invalid (?:type|value|length): [^`]*?)`[^`]*`")


def is_secret_name(name: str) -> bool:
    """Config names whose values are secrets: password, token, secret, ..._key, api key.

    ``key_exprs`` (zenoh access control) is not one: only a name *ending* in "key" is.
    """
    return bool(_SECRET_NAME_RE.search(name))


def redact_secrets(value: Any) -> Any:
    """A copy of a parsed config (mappings, lists) with every secret-named value replaced.

    A table under a secret-looking name (zenoh's ``usrpwd``) is searched, not hidden whole.

    Use it before logging any configuration (docs/reliability.md, "No secret in logs").
    """
    if isinstance(value, Mapping):
        return {
            k: (
                REDACTED
                if is_secret_name(str(k)) and not isinstance(v, Mapping | list | tuple)
                else redact_secrets(v)
            )
            for k, v in value.items()
        }
    if isinstance(value, list | tuple):
        return [redact_secrets(v) for v in value]
    return value


def redact_text(text: str) -> str:
    """Free text (an error message, a config excerpt) with secret-looking values replaced.

    zenoh quotes the offending source line of a bad JSON5 file and the offending value of a
    badly typed field in its errors; either may be a password.
    """
    text = _SECRET_ASSIGNMENT_RE.sub(lambda m: m.group("name") + REDACTED, text)
    return _ERROR_VALUE_RE.sub(lambda m: f"{m.group(1)}`{REDACTED}`", text)


def _zenoh_error_text(exc: BaseException) -> str:
    """zenoh errors carry Rust source locations; keep the sentence a user can act on.

    Values that may be secrets (see ``redact_text``) are replaced.
    """
    text = redact_text(str(exc))
    m = re.search(r'msg: "(.*?)"', text)
    if m:
        text = m.group(1)
    text = re.sub(r"\s+at /\S+?\.rs:\d+\.?", "", text)
    return " ".join(text.split())


def session_config(
    *,
    mode: str,
    listen: Sequence[str] = (),
    connect: Sequence[str] = (),
    multicast_scouting: bool = False,
    zenoh_config: str = "",
    tls: TlsConfig | None = None,
) -> zenoh.Config:
    """A zenoh config: optional JSON5 file first, then mode, endpoints, scouting and TLS."""
    try:
        if zenoh_config:
            if not Path(zenoh_config).is_file():
                raise UserError(f"zenoh config file not found: {zenoh_config}")
            conf = zenoh.Config.from_file(zenoh_config)
        else:
            conf = zenoh.Config()
        conf.insert_json5("mode", json.dumps(mode))
        conf.insert_json5("listen/endpoints", json.dumps(list(listen) if mode != "client" else []))
        conf.insert_json5("connect/endpoints", json.dumps(list(connect)))
        conf.insert_json5("scouting/multicast/enabled", json.dumps(multicast_scouting))
        if tls is not None:
            conf.insert_json5("transport/link/tls", json.dumps(tls.as_zenoh()))
    except zenoh.ZError as exc:
        raise UserError(f"bad zenoh configuration: {_zenoh_error_text(exc)}") from None
    return conf


def open_session(conf: zenoh.Config) -> zenoh.Session:
    """Open a zenoh session; zenoh's failure becomes a one-line ``UserError``."""
    try:
        return zenoh.open(conf)
    except zenoh.ZError as exc:
        raise UserError(f"cannot open zenoh session: {_zenoh_error_text(exc)}") from None


# -- the car side ---------------------------------------------------------------------------------
TELEMETRY_DOWN_WARNING = "Remote monitoring is offline."


@dataclass(frozen=True, slots=True)
class TelemetryHealth:
    """What ``Telemetry.health()`` reports (and the health message carries)."""

    status: str
    """"disabled", "starting", "up", "down" (no session, retrying) or "closed"."""
    connected: bool
    """Peer mode: the session is open. Client mode: a router is connected."""
    peers: int
    routers: int
    published: int
    dropped: Mapping[str, int]
    goals_accepted: int
    goals_refused: int
    last_error: str
    client_mode: bool = False

    @property
    def alive(self) -> bool:
        """The zenoh session is open."""
        return self.status == "up"

    @property
    def valid(self) -> bool:
        """Messages can leave the car: peer mode with a session, or client mode with a router."""
        return self.alive and (self.connected or not self.client_mode)

    @property
    def ok(self) -> bool:
        return self.alive and self.valid

    @property
    def warning(self) -> str:
        """Shown to the operator, not worth interrupting the driver for (telemetry is optional)."""
        if self.status == "down" or (self.status == "up" and not self.valid):
            return TELEMETRY_DOWN_WARNING
        return ""

    def as_dict(self) -> dict[str, Any]:
        return {
            "alive": self.alive,
            "valid": self.valid,
            "ok": self.ok,
            "warning": self.warning,
            "status": self.status,
            "connected": self.connected,
            "peers": self.peers,
            "routers": self.routers,
            "published": self.published,
            "dropped": dict(self.dropped),
            "goals_accepted": self.goals_accepted,
            "goals_refused": self.goals_refused,
            "last_error": self.last_error,
        }


@dataclass(slots=True)
class _Pending:
    kind: str
    build: Callable[[], dict[str, Any]]


@dataclass(slots=True)
class _Link:
    """Zenoh entities of one open session (replaced as a whole on reconnect)."""

    session: zenoh.Session
    publishers: dict[str, zenoh.Publisher] = field(default_factory=dict)
    others: list[Any] = field(default_factory=list)


GoalCallback = Callable[[float, float], None]


class Telemetry:
    """The car's telemetry: one zenoh session, non-blocking ``publish_*`` calls.

    ``on_goal(x_m, y_m)`` receives accepted remote goals (only with
    ``allow_remote_goal``); with ``loop`` it is called on that event loop via
    ``call_soon_threadsafe``, otherwise on a zenoh thread. ``clock`` gives
    wall-clock time for the ``wall_time_unix_s`` field only.
    """

    def __init__(
        self,
        config: TelemetryConfig,
        *,
        on_goal: GoalCallback | None = None,
        loop: asyncio.AbstractEventLoop | None = None,
        clock: Callable[[], float] = time.time,
    ) -> None:
        self.config = config
        self.vehicle_id = config.vehicle_id
        self._on_goal = on_goal
        self._loop = loop
        self._clock = clock
        self._lock = threading.Lock()
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._slots: dict[str, _Pending] = {}
        self._fifos: dict[str, deque[_Pending]] = {
            k: deque() for k in KINDS if k not in LATEST_KINDS
        }
        self._seq = dict.fromkeys(KINDS, 0)
        self._latest: dict[str, bytes] = {}
        self._dropped: dict[str, int] = {}
        self._published = 0
        self._goals_accepted = 0
        self._goals_refused = 0
        self._status = "disabled" if not config.enabled else "starting"
        self._connected = False
        self._peers = 0
        self._routers = 0
        self._last_error = ""
        self._link: _Link | None = None
        self._thread: threading.Thread | None = None

    # -- lifecycle ----------------------------------------------------------------------------
    def start(self) -> None:
        """Start the publisher thread, which opens the session; returns at once."""
        if not self.config.enabled or self._thread is not None:
            return
        self._thread = threading.Thread(
            target=self._run, name=f"telemetry-{self.vehicle_id}", daemon=True
        )
        self._thread.start()
        _close_at_exit(self)

    def close(self, timeout_s: float = 3.0) -> None:
        """Stop publishing, drop the liveliness token and close the session (idempotent)."""
        self._stop.set()
        self._wake.set()
        thread, self._thread = self._thread, None
        if thread is not None and thread is not threading.current_thread():
            thread.join(timeout_s)
            if thread.is_alive():
                log.warning("telemetry: publisher thread did not stop within %.1f s", timeout_s)
        self._close_link()
        if self.config.enabled:
            self._status = "closed"
            self._connected = False

    def __enter__(self) -> Telemetry:
        self.start()
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()

    # -- publishing (any thread, never blocks) -----------------------------------------------
    def publish_state(
        self,
        state: EstimateState,
        *,
        speed_mps: float | None = None,
        target: TargetLike | None = None,
        goal: tuple[float, float] | None = None,
        method: str | None = None,
        mode: str | None = None,
    ) -> None:
        self._put(
            "state",
            partial(
                state_message,
                state,
                vehicle_id=self.vehicle_id,
                speed_mps=speed_mps,
                target=target,
                goal=goal,
                method=method,
                mode=mode,
            ),
        )

    def publish_decision(self, decision: Decision) -> None:
        self._put("decision", partial(decision_message, decision, vehicle_id=self.vehicle_id))

    def publish_prompt(
        self, t_s: float, text: str, *, kind: str = "info", priority: int = 0
    ) -> None:
        self._put(
            "prompt",
            partial(
                prompt_message, t_s, text, vehicle_id=self.vehicle_id, kind=kind, priority=priority
            ),
        )

    def publish_landmark(
        self,
        t_s: float,
        *,
        matches: Sequence[LandmarkMatch | LandmarkFix] = (),
        rejections: Sequence[LandmarkRejection] = (),
        gated: int | None = None,
    ) -> None:
        self._put(
            "landmark",
            partial(
                landmark_message,
                t_s,
                vehicle_id=self.vehicle_id,
                matches=tuple(matches),
                rejections=tuple(rejections),
                gated=gated,
            ),
        )

    def publish_health(
        self,
        t_s: float,
        inputs: Mapping[str, InputHealth | Mapping[str, Any]],
        *,
        components: Mapping[str, Mapping[str, Any]] | None = None,
    ) -> None:
        """Publish input health; telemetry's own health is added under components.telemetry."""
        comps = {**(components or {}), "telemetry": self.health().as_dict()}
        self._put(
            "health",
            partial(
                health_message, t_s, dict(inputs), vehicle_id=self.vehicle_id, components=comps
            ),
        )

    def _put(self, kind: str, build: Callable[..., dict[str, Any]]) -> None:
        if not self.config.enabled or self._stop.is_set():
            return
        wall = self._clock()
        with self._lock:
            seq = self._seq[kind] + 1
            self._seq[kind] = seq
            item = _Pending(kind, partial(build, seq=seq, wall_time_unix_s=wall))
            if kind in LATEST_KINDS:
                if kind in self._slots:
                    self._count_drop_locked("superseded")
                self._slots[kind] = item
            else:
                fifo = self._fifos[kind]
                if len(fifo) >= self.config.fifo_size:
                    fifo.popleft()
                    self._count_drop_locked("fifo_full")
                fifo.append(item)
        self._wake.set()

    def _count_drop_locked(self, reason: str) -> None:
        self._dropped[reason] = self._dropped.get(reason, 0) + 1

    def _count_drop(self, reason: str) -> None:
        with self._lock:
            self._count_drop_locked(reason)

    # -- health -------------------------------------------------------------------------------
    def health(self) -> TelemetryHealth:
        with self._lock:
            dropped = dict(self._dropped)
        return TelemetryHealth(
            status=self._status,
            connected=self._connected,
            peers=self._peers,
            routers=self._routers,
            published=self._published,
            dropped=dropped,
            goals_accepted=self._goals_accepted,
            goals_refused=self._goals_refused,
            last_error=self._last_error,
            client_mode=self.config.mode == "client",
        )

    @property
    def up(self) -> bool:
        return self._status == "up"

    def has_subscribers(self, kind: str | None = None) -> bool:
        """True when a subscriber for ``kind`` (every kind when None) is known to the session.

        A monitor's liveliness can arrive before its subscription does; a message published in
        between reaches nobody. zenoh's matching status says when it would.
        """
        link = self._link
        if link is None:
            return False
        try:
            kinds = KINDS if kind is None else (kind,)
            # zenoh-python 1.10 returns a MatchingStatus (its stub says bool): accept both.
            statuses = (link.publishers[k].matching_status for k in kinds)
            return all(bool(getattr(st, "matching", st)) for st in statuses)
        except Exception:  # the session closed meanwhile
            return False

    # -- publisher thread ---------------------------------------------------------------------
    def _run(self) -> None:
        next_link_check = 0.0
        while not self._stop.is_set():
            try:
                if self._link is None:
                    if not self._try_open():
                        self._stop.wait(self.config.retry_period_s)
                        continue
                    next_link_check = 0.0
                now = time.monotonic()
                if now >= next_link_check:
                    self._check_link()
                    next_link_check = now + 1.0
                self._wake.wait(0.5)
                self._wake.clear()
                self._drain()
            except Exception:  # keep publishing whatever went wrong once
                log.exception("telemetry: publisher loop error")
                self._stop.wait(0.5)
        self._drain()

    def _try_open(self) -> bool:
        cfg = self.config
        try:
            conf = session_config(
                mode=cfg.mode,
                listen=cfg.listen,
                connect=cfg.connect,
                multicast_scouting=cfg.multicast_scouting,
                zenoh_config=cfg.zenoh_config,
                tls=cfg.tls,
            )
            session = open_session(conf)
        except UserError as exc:
            self._set_down(str(exc))
            return False
        except Exception as exc:  # zenoh may raise anything from its Rust side
            self._set_down(f"{type(exc).__name__}: {exc}")
            return False
        link = _Link(session)
        try:
            for kind in KINDS:
                link.publishers[kind] = session.declare_publisher(
                    key_for(self.vehicle_id, kind),
                    encoding=zenoh.Encoding.APPLICATION_JSON.with_schema(schema_tag(kind)),
                    congestion_control=zenoh.CongestionControl.DROP,
                    express=True,
                )
            link.others.append(session.liveliness().declare_token(liveliness_key(self.vehicle_id)))
            link.others.append(
                session.declare_queryable(
                    f"{KEY_PREFIX}/{self.vehicle_id}/*", self._on_query, complete=True
                )
            )
            if cfg.allow_remote_goal:
                link.others.append(
                    session.declare_subscriber(goal_key(self.vehicle_id), self._on_goal_sample)
                )
        except Exception as exc:
            self._set_down(f"declaring telemetry entities failed: {exc}")
            _quiet_close(session)
            return False
        self._link = link
        self._status = "up"
        self._last_error = ""
        where = ", ".join(cfg.listen if cfg.mode == "peer" else cfg.connect)
        log.info(
            "telemetry up: vehicle %s, %s mode on %s%s",
            self.vehicle_id,
            cfg.mode,
            where,
            ", remote goal ENABLED" if cfg.allow_remote_goal else "",
        )
        return True

    def _set_down(self, error: str) -> None:
        error = redact_text(error)
        if self._status != "down" or error != self._last_error:
            log.warning(
                "telemetry down (retrying every %.0f s): %s", self.config.retry_period_s, error
            )
        self._status = "down"
        self._connected = False
        self._last_error = error

    def _check_link(self) -> None:
        link = self._link
        if link is None:
            return
        try:
            info = link.session.info
            self._peers = len(info.peers_zid())
            self._routers = len(info.routers_zid())
        except Exception as exc:
            self._set_down(f"session lost: {exc}")
            self._close_link()
            return
        connected = self._routers > 0 if self.config.mode == "client" else True
        if connected != self._connected and self.config.mode == "client":
            if connected:
                log.info("telemetry: router connected")
            else:
                log.warning("telemetry: no router connected; zenoh keeps reconnecting")
        self._connected = connected

    def _drain(self) -> None:
        with self._lock:
            items = list(self._slots.values())
            self._slots.clear()
            for fifo in self._fifos.values():
                items.extend(fifo)
                fifo.clear()
        link = self._link
        for item in items:
            try:
                payload = encode(item.build())
            except Exception as exc:  # a malformed message must not stop the publisher
                log.error("telemetry: cannot encode a %s message: %r", item.kind, exc)
                self._count_drop("encode_error")
                continue
            self._latest[item.kind] = payload
            if link is None:
                self._count_drop("session_down")
                continue
            try:
                link.publishers[item.kind].put(payload)
            except Exception as exc:
                self._count_drop("put_error")
                self._last_error = redact_text(f"put failed: {exc}")
                continue
            self._published += 1

    def _close_link(self) -> None:
        link, self._link = self._link, None
        if link is not None:
            _quiet_close(link.session)

    # -- zenoh callbacks (zenoh threads) -------------------------------------------------------
    def _on_query(self, query: zenoh.Query) -> None:
        try:
            for kind, payload in list(self._latest.items()):
                key = key_for(self.vehicle_id, kind)
                if zenoh.KeyExpr(key).intersects(query.key_expr):
                    query.reply(
                        key,
                        payload,
                        encoding=zenoh.Encoding.APPLICATION_JSON.with_schema(schema_tag(kind)),
                    )
        except Exception:
            log.exception("telemetry: answering a query failed")

    def _on_goal_sample(self, sample: zenoh.Sample) -> None:
        try:
            goal = parse_goal(sample.payload.to_bytes(), self.config.max_goal_range_m)
        except ValueError as exc:
            self._goals_refused += 1
            if self._goals_refused <= 10 or self._goals_refused % 100 == 0:
                log.warning(
                    "telemetry: remote goal refused (%s); %d refused so far",
                    exc,
                    self._goals_refused,
                )
            return
        self._goals_accepted += 1
        log.info("telemetry: remote goal accepted: x %.1f m, y %.1f m", goal[0], goal[1])
        callback = self._on_goal
        if callback is None:
            return
        try:
            if self._loop is not None:
                self._loop.call_soon_threadsafe(callback, goal[0], goal[1])
            else:
                callback(goal[0], goal[1])
        except Exception:
            log.exception("telemetry: handing the remote goal to the application failed")


def parse_goal(payload: bytes, max_range_m: float) -> tuple[float, float]:
    """Validate a goal command: a JSON object with finite ``x_m``, ``y_m`` within range."""
    if len(payload) > 4096:
        raise ValueError("payload larger than 4 KiB")
    try:
        obj = json.loads(payload)
    except (UnicodeDecodeError, json.JSONDecodeError):
        raise ValueError("not JSON") from None
    if not isinstance(obj, dict):
        raise ValueError("not a JSON object")
    tag = obj.get("schema", GOAL_SCHEMA)
    if tag != GOAL_SCHEMA:
        raise ValueError(f"schema {tag!r} is not {GOAL_SCHEMA}")
    try:
        x, y = obj["x_m"], obj["y_m"]
    except KeyError:
        raise ValueError("x_m and y_m are required") from None
    if not all(isinstance(v, int | float) and not isinstance(v, bool) for v in (x, y)):
        raise ValueError("x_m and y_m must be numbers")
    x, y = float(x), float(y)
    if not (math.isfinite(x) and math.isfinite(y)):
        raise ValueError("x_m and y_m must be finite")
    if math.hypot(x, y) > max_range_m:
        dist = math.hypot(x, y)
        raise ValueError(f"goal {dist:.0f} m from the start exceeds {max_range_m:.0f} m")
    return x, y


def _quiet_close(session: zenoh.Session) -> None:
    try:
        session.close()
    except Exception as exc:
        log.debug("closing zenoh session: %s", exc)


_OPEN: weakref.WeakSet[Telemetry | MonitorClient] = weakref.WeakSet()
_EXIT_HOOK = threading.Lock()
_exit_hook_installed = False


def _close_all_at_exit() -> None:
    for obj in list(_OPEN):
        obj.close()


def _close_at_exit(obj: Telemetry | MonitorClient) -> None:
    """Close forgotten sessions before interpreter shutdown.

    A zenoh session with Python callbacks still declared makes the interpreter
    hang at exit (zenoh-python 1.10, measured here); ``atexit`` runs too late,
    so the hook goes where ``concurrent.futures`` puts its own: before threads
    are joined.
    """
    global _exit_hook_installed
    _OPEN.add(obj)
    with _EXIT_HOOK:
        if _exit_hook_installed:
            return
        register = getattr(threading, "_register_atexit", None)
        if register is not None:
            try:
                register(_close_all_at_exit)
            except RuntimeError:  # already shutting down
                return
        _exit_hook_installed = True


# -- the monitor side ------------------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class TelemetryEvent:
    """One thing a monitor saw: a message, or a car appearing ("alive") or vanishing ("gone")."""

    kind: str
    vehicle_id: str
    key: str
    message: Mapping[str, Any] | None
    received_s: float
    """Monitor's monotonic clock when it arrived."""
    late_join: bool = False
    """True when it came from the query of the latest values, not a live publication."""


class MonitorClient:
    """Subscribes to one vehicle or all (``vehicle="all"``): messages and liveliness.

    Events are queued from zenoh threads into a bounded queue read with
    ``get(timeout_s)``; when it is full, new events are dropped and counted.
    """

    def __init__(
        self,
        connect: Sequence[str] = (DEFAULT_CONNECT,),
        *,
        vehicle: str = "all",
        mode: str = "peer",
        zenoh_config: str = "",
        tls: TlsConfig | None = None,
        queue_size: int = 10_000,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        for ep in connect:
            check_endpoint(ep)
        if mode not in _MODES:
            raise UserError(f"mode must be one of {_MODES}, not {mode!r}")
        if vehicle != "all":
            validate_vehicle_id(vehicle)
        self.connect = tuple(connect)
        self.vehicle = vehicle
        self._mode = mode
        self._zenoh_config = zenoh_config
        self._tls = tls
        self._clock = clock
        self._queue: queue.Queue[TelemetryEvent] = queue.Queue(maxsize=queue_size)
        self._session: zenoh.Session | None = None
        self._entities: list[Any] = []
        self.received = 0
        self.dropped = 0
        self.undecodable = 0

    @property
    def _vehicle_chunk(self) -> str:
        return "*" if self.vehicle == "all" else self.vehicle

    def open(self) -> MonitorClient:
        """Open the session and subscribe; raises ``UserError`` on a bad endpoint or config.

        An endpoint that is valid but not (yet) reachable is not an error: zenoh
        keeps trying, and no events arrive until it connects.
        """
        conf = session_config(
            mode=self._mode,
            connect=self.connect,
            zenoh_config=self._zenoh_config,
            tls=self._tls,
        )
        session = open_session(conf)
        self._session = session
        _close_at_exit(self)
        v = self._vehicle_chunk
        self._entities.append(session.declare_subscriber(f"{KEY_PREFIX}/{v}/*", self._on_sample))
        self._entities.append(
            session.liveliness().declare_subscriber(
                f"{KEY_PREFIX}/{v}", self._on_liveliness, history=True
            )
        )
        return self

    def __enter__(self) -> MonitorClient:
        return self.open()

    def __exit__(self, *_exc: object) -> None:
        self.close()

    def close(self) -> None:
        session, self._session = self._session, None
        self._entities.clear()
        if session is not None:
            _quiet_close(session)

    def query_latest(self, vehicle_id: str | None = None, timeout_s: float = 2.0) -> None:
        """Ask the cars (or one) for their latest messages; replies arrive later as events.

        Non-blocking. The monitor asks once when it opens and again when a car
        appears, so a monitor joining late sees each car's state at once.
        """
        session = self._session
        if session is None:
            return
        chunk = self._vehicle_chunk if vehicle_id is None else validate_vehicle_id(vehicle_id)
        try:
            session.get(f"{KEY_PREFIX}/{chunk}/*", self._on_reply, timeout=timeout_s)
        except Exception as exc:
            log.warning("monitor: query for latest values failed: %s", _zenoh_error_text(exc))

    def _on_reply(self, reply: zenoh.Reply) -> None:
        sample = reply.ok
        if sample is not None:
            self._on_sample(sample, late_join=True)

    def get(self, timeout_s: float | None = None) -> TelemetryEvent | None:
        try:
            return self._queue.get(timeout=timeout_s)
        except queue.Empty:
            return None

    def send_goal(self, vehicle_id: str, x_m: float, y_m: float) -> None:
        """Ask a car to drive to a new goal (it obeys only if its config and ACL allow)."""
        session = self._session
        if session is None:
            raise UserError("monitor session is not open")
        validate_vehicle_id(vehicle_id)
        body = {"schema": GOAL_SCHEMA, "x_m": float(x_m), "y_m": float(y_m)}
        session.put(goal_key(vehicle_id), encode(body), encoding=zenoh.Encoding.APPLICATION_JSON)

    def peers(self) -> int:
        session = self._session
        if session is None:
            return 0
        info = session.info
        return len(info.peers_zid()) + len(info.routers_zid())

    def _push(self, event: TelemetryEvent) -> None:
        try:
            self._queue.put_nowait(event)
        except queue.Full:
            self.dropped += 1

    def _on_sample(self, sample: zenoh.Sample, late_join: bool = False) -> None:
        key = str(sample.key_expr)
        parsed = parse_key(key)
        if parsed is None:
            return
        vehicle_id, kind = parsed
        try:
            message = json.loads(sample.payload.to_bytes())
            if not isinstance(message, dict):
                raise ValueError("not an object")
        except ValueError:
            self.undecodable += 1
            return
        self.received += 1
        self._push(TelemetryEvent(kind, vehicle_id, key, message, self._clock(), late_join))

    def _on_liveliness(self, sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        parts = key.split("/")
        if len(parts) != 2 or parts[0] != KEY_PREFIX:
            return
        kind = "alive" if sample.kind == zenoh.SampleKind.PUT else "gone"
        self._push(TelemetryEvent(kind, parts[1], key, None, self._clock()))


def iter_events(client: MonitorClient, until_s: float | None) -> Iterable[TelemetryEvent]:
    """Events until the monotonic deadline ``until_s`` (None: forever)."""
    while True:
        wait = 0.2 if until_s is None else min(0.2, until_s - time.monotonic())
        if wait <= 0:
            return
        event = client.get(wait)
        if event is not None:
            yield event
