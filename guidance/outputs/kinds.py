"""The one output table (cereal's ``services.py``, for outputs): every kind of message the car
publishes and records, with everything each sink needs to know about it.

``OUTPUTS`` is read by the app (which outputs of one input go where: ``items``), telemetry (the
zenoh key ``guidance/<id>/<name>`` and the queue policy), the recorder (the MCAP topic and
channel schema) and the monitor's check (the schema). Adding an output kind is one message type
(``guidance.core.messages``), one ``Outputs`` field, one encoder (``guidance.outputs.messages``,
its schema beside it in ``schemas``) and one row here.

Pure: no zenoh, no mcap, no numba (``tests/test_layers.py``).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Literal

from guidance.core.geo import LatLon
from guidance.core.messages import EstimateState, Health, LandmarkFix, Prompt, Target
from guidance.outputs import messages as m
from guidance.outputs.messages import LandmarkRejection
from guidance.outputs.schemas import SCHEMAS

if TYPE_CHECKING:
    from guidance.core.pipeline_config import Outputs


@dataclass(frozen=True, slots=True)
class OutputContext:
    """What a state message carries beyond the estimate (the app knows it, once per output)."""

    speed_mps: float | None = None
    target: Target | None = None
    goal: tuple[float, float] | None = None
    method: str | None = None
    mode: str | None = None
    origin_lat_lon_deg: LatLon | None = None
    """The sink's: the local frame's WGS-84 origin (state messages then carry lat/lon)."""
    chance: float | None = None
    """The chance of reaching the goal (``guidance.core.plan.chance``)."""


@dataclass(frozen=True, slots=True)
class LandmarkReport:
    """One recognition pass: the fixes it gave and what it rejected (the ``landmark`` kind)."""

    t_s: float
    matches: Sequence[LandmarkFix] = ()
    rejections: Sequence[LandmarkRejection] = ()
    gated: int | None = None


@dataclass(frozen=True, slots=True)
class HealthReport:
    """Every input's and component's health at one time (the ``health`` kind)."""

    t_s: float
    inputs: Mapping[str, Health]
    components: Mapping[str, Health | Mapping[str, Any]] = field(default_factory=dict)


Encoder = Callable[..., Mapping[str, Any]]
"""``encode(item, context, *, vehicle_id, seq, wall_time_unix_s)`` -> the message."""


@dataclass(frozen=True, slots=True)
class OutputKind:
    name: str
    """The zenoh key's last part (``guidance/<id>/<name>``) and schema (``guidance.<name>/1``)."""
    items: Callable[[Outputs], Iterable[Any]] | None
    """This kind's items among one input's ``Outputs`` (None: published on the app's clock)."""
    encode: Encoder
    policy: Literal["latest", "fifo"]
    """Telemetry's queue: a latest-value slot, or a short FIFO (nothing dropped unseen)."""
    topic: str
    """The recorder's MCAP topic."""

    @property
    def schema(self) -> dict[str, Any]:
        return SCHEMAS[self.name]

    def t_s(self, item: Any) -> float:
        """The message time of an item (a bad object fails where it is encoded)."""
        try:
            return float(getattr(item, "t_s", float("nan")))
        except (TypeError, ValueError):
            return float("nan")


def _state(s: EstimateState, c: OutputContext, **env: Any) -> Mapping[str, Any]:
    return m.state_message(s, speed_mps=c.speed_mps, target=c.target, goal=c.goal,
                           method=c.method, mode=c.mode, chance=c.chance,
                           origin_lat_lon_deg=c.origin_lat_lon_deg, **env)  # fmt: skip


def _prompt(p: Prompt, c: OutputContext, **env: Any) -> Mapping[str, Any]:
    return m.prompt_message(p.t_s, p.text, kind=p.kind, priority=int(p.priority), **env)


def _landmark(r: LandmarkReport, c: OutputContext, **env: Any) -> Mapping[str, Any]:
    return m.landmark_message(r.t_s, matches=tuple(r.matches), rejections=tuple(r.rejections),
                              gated=r.gated, **env)  # fmt: skip


def _health(r: HealthReport, c: OutputContext, **env: Any) -> Mapping[str, Any]:
    return m.health_message(r.t_s, dict(r.inputs), components=dict(r.components), **env)


def _plain(encode: Callable[..., Mapping[str, Any]]) -> Encoder:
    """An encoder that needs only its item."""

    def enc(item: Any, c: OutputContext, **env: Any) -> Mapping[str, Any]:
        return encode(item, **env)

    return enc


def _landmark_items(out: Outputs) -> tuple[LandmarkReport, ...]:
    if not (out.landmark_updates or out.landmark_rejections):
        return ()
    t = (out.landmark_updates or [f for f, _ in out.landmark_rejections])[0].t_s
    rejections = tuple(LandmarkRejection(r, fix.landmark_id) for fix, r in out.landmark_rejections)
    return (LandmarkReport(t, tuple(out.landmark_updates), rejections),)


STATE = OutputKind("state", lambda o: () if o.state is None else (o.state,), _state,
                   "latest", "/state")  # fmt: skip
DECISION = OutputKind("decision", lambda o: o.decisions, _plain(m.decision_message), "fifo",
                      "/decision")  # fmt: skip
PROMPT = OutputKind("prompt", lambda o: o.prompts, _prompt, "fifo", "/prompt")
LANDMARK = OutputKind("landmark", _landmark_items, _landmark, "latest", "/landmark")
HEALTH = OutputKind("health", None, _health, "latest", "/health")
TURN = OutputKind("turn", lambda o: o.turns, _plain(m.turn_message), "fifo", "/turn")
EXIT = OutputKind("exit", lambda o: o.exits_taken, _plain(m.exit_message), "fifo", "/exit")

OUTPUTS: tuple[OutputKind, ...] = (PROMPT, DECISION, TURN, EXIT, LANDMARK, STATE, HEALTH)
"""Every output kind, in the order one input's outputs are sent (what the driver hears first)."""
BY_NAME: dict[str, OutputKind] = {k.name: k for k in OUTPUTS}
